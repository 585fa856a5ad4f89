"""The Strauss least-squares problems of a conversion scene.

Built once per `Converter` and shared by both
directions: Phong → Strauss fits them (`strauss_fit.convert._to_strauss`), and
Strauss → Phong renders its targets with the full one (`strauss_fit.convert._to_phong`).
Every material of a conversion has the same geometry, so one problem per set of free
parameters serves all of them, with only the target, its residual scale and (for the
held parameters) the material swapped in.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import jax.numpy as jnp
import numpy as np

from ..fitting.options import FitOptions
from ..fitting.problem import build_problem, take_pixels_jit
from ..io.targets import Target
from ..models.material import OPAQUE_NAMES, Material
from ..rendering.strauss import plan_render
from ..scene.loading import Scene

#: Strauss parameters the conversion fits (t and n are carried over, see
#: `strauss_fit.convert.converter`).
STRAUSS_FREE = OPAQUE_NAMES
#: The starts run on every COARSE_STRIDE-th pixel of the conversion image, the polish on all.
COARSE_STRIDE = 4


class StraussProblems:
    """The Strauss problems on ``scene`` (depth 1) with the fit ``options``: `full`
    frees every fitted parameter (C, s, m), `template` any subset (built once per
    set of names); `index` holds the flat pixels used, `coarse` the subsample
    of them the starts run on (None for a small image)."""

    def __init__(self, scene: Scene, options: FitOptions):
        self.scene = scene
        self.options = options
        self.base = Material(transparency=0.0)
        height, width = scene.shape
        self._dummy = Target(
            np.ones((height, width, 3)), np.ones((height, width), dtype=bool), "<conversion>", "linear", 0, 0
        )
        self._plan = plan_render(scene, self.base, transparent=False)
        self._cache: dict = {}
        self.full, prepared_full, self.index = build_problem(
            scene, self._dummy, list(STRAUSS_FREE), self.base, self._plan, options, cache=self._cache
        )
        self._templates: dict[tuple[str, ...], Any] = {STRAUSS_FREE: self.full}
        # the starts run on every COARSE_STRIDE-th pixel (the polish on all of them): the
        # same optimum, a quarter of the work (benchmarks/convert_speed.py)
        self.coarse = np.arange(0, self.index.size, COARSE_STRIDE) if self.index.size >= 4 * COARSE_STRIDE else None
        self._coarse_prepared = None if self.coarse is None else take_pixels_jit(prepared_full, self.index[self.coarse])

    def vector(self, material: Material) -> np.ndarray:
        """The full problem's parameter vector (C, s, m) of ``material``."""
        return self.full.layout.join(material.to_dict())

    def template(self, free: tuple[str, ...]) -> Any:
        """The Strauss problem freeing ``free`` (built once per set of names)."""
        if free not in self._templates:
            self._templates[free], _, _ = build_problem(
                self.scene, self._dummy, list(free), self.base, self._plan, self.options, cache=self._cache
            )
        return self._templates[free]

    def problem(self, template: Any, target: np.ndarray, scale: float, material: Material | None = None) -> Any:
        """``template`` fitted to ``target`` with the residual ``scale``, and the parameters it
        does not free taken from ``material`` (None: the template's own)."""
        changes: dict[str, Any] = {"target": np.asarray(target), "residual_scale": np.asarray(scale)}
        if material is not None:
            changes["material"] = material.astype(jnp.float64)
        return dataclasses.replace(template, **changes)

    def screen(self, problem: Any, target: np.ndarray, scale: float) -> Any:
        """``problem`` on the coarse subsample of pixels (the residual scale shrinks with
        the pixel count, so costs stay comparable), or itself when the image is small."""
        if self.coarse is None:
            return problem
        return dataclasses.replace(
            problem,
            prepared=self._coarse_prepared,
            target=np.asarray(target)[self.coarse],
            residual_scale=np.asarray(scale * math.sqrt(self.coarse.size / self.index.size)),
        )
