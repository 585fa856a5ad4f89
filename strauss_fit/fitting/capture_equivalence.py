r"""Perceptual equivalence ranges of a capture's fit: which materials look the same under
every light of the capture?

The same question as for one image (`strauss_fit.fitting.equivalence`), asked of the
whole capture. For a material parameter p (each channel of a colour separately) with best
value p̂, and the best fit's prediction `\hat I_l` of every image l,

```text
D(v) = \min_{\theta_{-p}} \frac1L \sum_l
          \overline{\Delta E_{2000}}\big(I_l(p = v, \theta_{-p}), \hat I_l\big),
```

the mean CIEDE2000 difference over the capture's pixels after re-fitting every other value
(the other material parameters, the exposures, the white balance, the ambient light) with p
held at v. The range is the set of v around p̂ where `D(v) \le \Delta E^*`. Each side
is found by doubling a step away from p̂ until D exceeds `\Delta E^*` (or the bound is
reached: the range then ends at the bound), then by bisection. The inner fit is least
squares in the cube-root (perceptual) space, a smooth stand-in for CIEDE2000, by projected
Levenberg–Marquardt (`strauss_fit.fitting.capture.projected_lm`) warm-started at the
previous point, on a fixed subsample of the pixels (`EQUIVALENCE_VALUES` values).

Only the material's parameters get a range: the exposures and the white balance describe the
camera, not the material, and are re-fitted at every point.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ..capture._samples import CaptureSamples
from ..engine import Steps, run
from ..errors import CaptureError
from ..models.reflectance import REFLECTANCE_MODELS
from ..precision import float64
from .capture import (
    HELD,
    CaptureFit,
    _bounds,
    _labels,
    _offsets,
    _Param,
    _predict,
    _subsample,
    _terms,
    delta_e_mean,
    projected_lm,
)
from .equivalence import range_end_steps

#: The default threshold: one just-noticeable difference in mean CIEDE2000.
DEFAULT_DELTA_E = 1.0
#: Values (image × pixel × channel) the ranges are computed on.
EQUIVALENCE_VALUES = 60_000
#: Bisection steps per side (the ends are then known to 2⁻⁸ of the last step).
BISECTIONS = 8
#: Upper end for a positive parameter without one, as a multiple of its fitted value.
SCALE_MAX = 10.0
#: The material's parameters the capture fitter fits, per model: the model's own less those
#: it holds (`HELD`); the others describe the camera and the room.
MATERIAL = {
    name: tuple(p.name for p in model.parameters if p.name not in HELD) for name, model in REFLECTANCE_MODELS.items()
}
#: Offset of the cube root, as a fraction of the best prediction's 98th percentile (as for
#: single images, `strauss_fit.fitting.problem.PERCEPTUAL_OFFSET`).
PERCEPTUAL_OFFSET = 1e-3


@functools.lru_cache(maxsize=16)
def _perceptual(model: str, params: tuple[_Param, ...]) -> tuple[Callable, Callable]:
    """The residual ∛(Î(x) + o) − ∛(Î* + o) at the usable values, and its Jacobian."""

    def residual(physical, data):
        terms, reference, weight, offset = data
        predicted = jnp.maximum(_predict(model, params, physical, terms), 0.0)
        return ((jnp.cbrt(predicted + offset) - reference) * weight).ravel()

    return jax.jit(residual), jax.jit(jax.jacfwd(residual))


def capture_equivalence(
    samples: CaptureSamples,
    fit: CaptureFit,
    *,
    delta_e: float = DEFAULT_DELTA_E,
    values: int = EQUIVALENCE_VALUES,
    seed: int = 0,
    max_steps: int = 20,
) -> dict[str, Any]:
    """The perceptual equivalence range of each material parameter of ``fit`` (fitted to
    ``samples``): a map from name to ``[low, high]`` (a colour: three pairs, R, G, B), see
    the module docstring."""
    if not np.isfinite(delta_e) or delta_e <= 0:
        raise CaptureError(f"the equivalence threshold must be a positive CIEDE2000, got {delta_e}")
    with float64():
        return _ranges(samples, fit, float(delta_e), values, seed, max_steps)


def _ranges(
    samples: CaptureSamples, fit: CaptureFit, delta_e: float, values: int, seed: int, max_steps: int
) -> dict[str, Any]:
    sub = _subsample(samples, values, seed)
    terms = _terms(sub, fit.model)
    x_best = np.asarray(fit.physical, dtype=np.float64)
    best = np.maximum(np.asarray(_predict(fit.model, fit.params, jnp.asarray(x_best), terms)), 0.0)
    # ΔE is judged where the photograph's three channels are all usable (as delta_e_mean)
    usable = np.repeat(np.asarray(sub.usable).all(axis=-1, keepdims=True), 3, axis=-1)
    if not usable.any():
        raise CaptureError("no pixel with all three channels usable: no equivalence ranges")
    offset = PERCEPTUAL_OFFSET * max(float(np.percentile(best[usable], 98)), 1e-12)
    data = (terms, jnp.asarray(np.cbrt(best + offset)), jnp.asarray(usable, dtype=jnp.float64), offset)
    residual_fn, jacobian_fn = _perceptual(fit.model, fit.params)
    low0, high0 = _bounds(fit.params)
    labels = _labels(fit.params)
    material = MATERIAL[fit.model]

    def distance(k: int, v: float, warm: np.ndarray) -> tuple[float, np.ndarray]:
        low, high = low0.copy(), high0.copy()
        low[k] = high[k] = v
        start = warm.copy()
        start[k] = v
        fixed = np.zeros(len(start), dtype=bool)
        fixed[k] = True
        x, _, _, _ = projected_lm(residual_fn, jacobian_fn, data, start, low, high, fixed=fixed, max_steps=max_steps)
        image = np.asarray(_predict(fit.model, fit.params, jnp.asarray(x), terms))
        return delta_e_mean(image, best, usable), x

    def distance_steps(k: int) -> Callable[[float, np.ndarray], Steps]:
        """`distance` for parameter ``k`` as `range_end_steps` takes it: steps that run no
        `Call` (the capture's inner fit is its own compiled loop) and return at once."""

        def steps(v: float, warm: np.ndarray) -> Steps:
            return distance(k, v, warm)
            yield  # unreachable: makes this function a generator

        return steps

    ranges: dict[str, list[float]] = {}
    for p, start in zip(fit.params, _offsets(fit.params)):
        if p.name not in material:
            continue
        for k in range(start, start + p.size):
            centre = float(x_best[k])
            top = high0[k] if np.isfinite(high0[k]) else max(SCALE_MAX * centre, centre + 1.0)
            step = 0.02 if p.kind == "unit" else 0.02 * max(abs(centre), 1e-6)
            ends = [
                run(range_end_steps(distance_steps(k), centre, bound, direction, step, delta_e, BISECTIONS, x_best))
                for direction, bound in ((-1.0, float(low0[k])), (1.0, float(top)))
            ]
            ranges[labels[k]] = [float(min(ends)), float(max(ends))]
    out: dict[str, Any] = {}
    for p, start in zip(fit.params, _offsets(fit.params)):
        if p.name in material:
            pairs = [ranges[labels[start + i]] for i in range(p.size)]
            out[p.name] = pairs if p.size > 1 else pairs[0]
    return out


def within(value: float, bounds: list[float], slack: float = 0.0) -> bool:
    """Whether ``value`` lies in the range ``bounds`` (widened by ``slack`` each side)."""
    return bounds[0] - slack <= value <= bounds[1] + slack
