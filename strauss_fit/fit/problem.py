r"""A fit's problem: the prepared scene at the usable pixels, the target, and the residual.

The fit minimises :math:`\tfrac12\sum_p \lVert I_\text{model}(p;\theta) - I_\text{target}(p)\rVert^2`
over the usable sphere pixels p (linear RGB), with θ the unconstrained parameters of
:mod:`strauss_fit.fit.parameters`.

Speed: everything that does not depend on the material (pixel geometry, the angular terms
F, G and j of every light, backgrounds seen along mirror directions) is computed once
(:func:`strauss_fit.render.strauss.prepare`, with every light at unit intensity) and
restricted to the usable pixels (:func:`build_problem`); the solver then evaluates only
the material-dependent part, with the intensities applied (:func:`scaled`). On a large
image the starts run on an evenly strided subsample (:func:`coarse_problem`).

The jitted helpers here (:func:`costs`, :func:`render_at`, :func:`to_physical`, ...) are
internal API shared by the fit's modules, the conversions and the study: compiled once per
problem structure, called inside :func:`strauss_fit.precision.float64`.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..errors import StraussFitError
from ..io.targets import Target
from ..models.material import Material
from ..precision import uses_float64
from ..render.strauss import Prepared, RenderPlan, prepare, shade_prepared, take_pixels
from ..scene.lights import Lights
from ..scene.loading import Scene
from .parameters import Layout, intensity_vector, lights_with, material_with

if TYPE_CHECKING:
    from .options import FitOptions

#: Above twice this many usable pixels, the starts run on an evenly strided subsample of
#: about this size and only the best start is continued on every pixel
#: (:func:`strauss_fit.fit.solvers.solve`).
COARSE_PIXELS = 8192


class Problem(eqx.Module):
    """A fit's data: prepared (material-independent) terms at the usable pixels, the
    target there, the scene, the material and lights that held parameters come from."""

    prepared: Prepared
    target: Array
    scene: Scene
    material: Material
    lights: Lights
    pinned: Array
    pinned_values: Array
    residual_scale: Array
    layout: Layout = eqx.field(static=True)
    plan: RenderPlan = eqx.field(static=True)

    def physical(self, theta: Array) -> Array:
        """Physical values of θ, with pinned entries (at a bound, see
        :func:`strauss_fit.fit.solvers.polish`) replaced."""
        return jnp.where(self.pinned, self.pinned_values, self.layout.to_physical(theta))

    def pin(self, mask: np.ndarray, values: np.ndarray) -> Problem:
        return dataclasses.replace(self, pinned=jnp.asarray(mask), pinned_values=jnp.asarray(values))

    def render_physical(self, x: Array) -> Array:
        """Model radiance (N, 3) at the usable pixels for physical parameters ``x``."""
        values = self.layout.split(x)
        material = material_with(self.material, values)
        prepared = scaled(self.prepared, lights_with(self.lights, values))
        return shade_prepared(material, prepared, self.scene, self.plan)

    def residual_physical(self, x: Array) -> Array:
        return (self.render_physical(x) - self.target).ravel()

    def residual(self, theta: Array, _args: Any = None) -> Array:
        """What the solver minimises: residuals divided by ``residual_scale`` (the
        reference noise times sqrt(N)), so that tolerances do not depend on image size
        or brightness."""
        return self.residual_physical(self.physical(theta)) / self.residual_scale


def scaled(prepared: Prepared, lights: Lights) -> Prepared:
    """A unit-intensity :class:`~strauss_fit.render.strauss.Prepared` with the lights'
    intensities applied."""
    changes = {}
    if prepared.irradiance is not None:
        changes["irradiance"] = prepared.irradiance * intensity_vector(lights)
    if lights.ambient is not None:
        changes["ambient"] = lights.ambient
    return dataclasses.replace(prepared, **changes)


def unit_intensity_scene(scene: Scene) -> Scene:
    """The scene with every light's intensity 1, so that prepared irradiance holds only
    the geometric attenuation and intensities can be applied (or fitted) later."""
    ones = {k: jnp.ones_like(v) for k, v in scene.lights.intensities().items()}
    return eqx.tree_at(lambda s: s.lights, scene, scene.lights.with_intensities(ones))


# Jitted once per shape: run eagerly, these would compile dozens of small XLA programs.
@eqx.filter_jit
def prepare_float64(scene: Scene, plan: RenderPlan, mode: str, table_size: int) -> Prepared:
    """:func:`strauss_fit.render.strauss.prepare` in float64, jitted."""
    return prepare(scene, plan, mode, table_size, jnp.float64)


#: :func:`strauss_fit.render.strauss.take_pixels`, jitted.
take_pixels_jit = eqx.filter_jit(take_pixels)


@eqx.filter_jit
def shade_full(material: Material, prepared: Prepared, lights: Lights, scene: Scene, plan: RenderPlan) -> Array:
    """The whole image of a unit-intensity prepared scene for ``material`` and ``lights``."""
    return shade_prepared(material, scaled(prepared, lights), scene, plan)


@eqx.filter_jit
def to_physical(layout: Layout, theta: Array) -> Array:
    """``layout.to_physical``, jitted."""
    return layout.to_physical(theta)


@eqx.filter_jit
def render_at(problem: Any, x: Array) -> Array:
    """A problem's model radiance (N, 3) at physical parameters ``x`` (any problem with
    ``render_physical``, a Phong one too)."""
    return problem.render_physical(x)


@eqx.filter_jit
def costs(problem: Problem, xs: Array) -> Array:
    """The normalised cost Σ(r/scale)² at each row of physical points ``xs`` (K, P)."""
    return jax.vmap(lambda x: jnp.sum((problem.residual_physical(x) / problem.residual_scale) ** 2))(xs)


@uses_float64
def build_problem(
    scene: Scene,
    target: Target,
    names: list[str],
    material: Material,
    plan: RenderPlan,
    options: FitOptions,
    reference_noise: float = 1.0,
    cache: dict | None = None,
) -> tuple[Problem, Prepared, np.ndarray]:
    """The :class:`Problem` for the free ``names``, the full prepared image and the
    flat indices of the pixels used.

    Of ``options`` only ``mode`` and ``table_size`` matter. ``cache`` (a dict owned by one
    :func:`strauss_fit.fit.api.fit` call) keeps the prepared scene per render plan:
    preparing depends only on the camera, the background, where the lights are and the
    plan — not on the material or the lights' intensities, which is all that changes
    between the problems of one fit."""
    key = (plan, options.mode, options.table_size)
    if cache is not None and key in cache:
        prepared_full, index, prepared, pixels = cache[key]
    else:
        prepared_full = prepare_float64(unit_intensity_scene(scene), plan, options.mode, options.table_size)
        hit = np.asarray(prepared_full.hit)
        used = hit & target.usable
        if not used.any():
            raise StraussFitError(
                f"target {target.path} has no usable sphere pixels (all masked, clipped or outside the sphere)"
            )
        index = np.flatnonzero(used.ravel())
        pixels = jnp.asarray(target.pixels.reshape(-1, 3)[index])
        if float(jnp.max(pixels)) <= 0:
            raise StraussFitError(f"target {target.path} is black on every usable sphere pixel: nothing to fit")
        prepared = take_pixels_jit(prepared_full, jnp.asarray(index))
        if cache is not None:
            cache[key] = prepared_full, index, prepared, pixels
    problem = Problem(
        prepared=prepared,
        target=pixels,
        scene=scene,
        material=material.astype(jnp.float64),
        lights=scene.lights,
        pinned=jnp.zeros(Layout(tuple(names)).size, dtype=bool),
        pinned_values=jnp.zeros(Layout(tuple(names)).size),
        residual_scale=jnp.asarray(reference_noise * np.sqrt(pixels.size)),
        layout=Layout(tuple(names)),
        plan=plan,
    )
    return problem, prepared_full, index


def coarse_problem(problem: Problem, prepared_full: Prepared, index: np.ndarray) -> Problem | None:
    """``problem`` restricted to every k-th of its pixels (k = N // :data:`COARSE_PIXELS`),
    or None when it is small enough. The residual scale shrinks with the pixel count, so
    costs (χ² per value at the reference noise) stay comparable."""
    stride = index.size // COARSE_PIXELS
    if stride < 2:
        return None
    subset = np.arange(0, index.size, stride)
    return dataclasses.replace(
        problem,
        prepared=take_pixels_jit(prepared_full, jnp.asarray(index[subset])),
        target=problem.target[subset],
        residual_scale=problem.residual_scale * np.sqrt(subset.size / index.size),
    )
