r"""Fitting one material to a whole capture: joint least squares over every image.

For image l, sphere pixel p and channel c the model predicts

```text
\hat I_{lpc} = e_l\, W_c \Big[\sum_k I_{lkc}\, f_c(n_p, \omega_{lk}, v_p; \theta)
               + A_c\, a_c(\theta)\Big]
```

with `I_{lkc}` the k-th light's intensity in channel c, f the reflectance model's
radiance per unit white light (`MODELS`), `e_l` the exposure (one global value
for Strauss, whose C ≤ 1 cannot absorb the scale of the photographs; per image with
``exposure="per-image"``, the first image's fixed at the global one), `W_c` an optional
white balance (`W_g = 1`) and `A_c` an optional ambient (room) light reaching
every point (its reflectance `a_c`: `r_d C_c` for Strauss, the diffuse albedo
otherwise). The fit minimises `\tfrac12 \sum (\hat I - I)^2` over the usable values
(saturated and under-exposed channels left out), first from a global search (the linear
parameters solved exactly on a grid of the non-linear ones, on a subsample), then by
Levenberg–Marquardt on every value.

Speed: the angular terms of every (image, light, pixel) do not depend on the material and
are computed once; one evaluation is then a few element-wise passes.
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ..capture._samples import CaptureSamples
from ..color import delta_e_2000
from ..errors import CaptureError
from ..models.reflectance import REFLECTANCE_MODELS, reflectance_model
from ..precision import float64
from ..runtime import keep_freed_memory
from ..stats.laplace import sandwich
from .solvers import STRICT_REJECT_RATIO, _result_code, levenberg_marquardt, status_name

#: The reflectance models a capture can be fitted with: every registered one.
MODELS = tuple(REFLECTANCE_MODELS)
#: Parameters a capture holds, at these values: a capture shows an opaque sample against a
#: dark background, where transparency only dims the surface (and trades off with C) and
#: refraction has no effect.
HELD = {"transparency": 0.0, "ior": 1.5}
EXPOSURES = ("global", "per-image", "fixed")
#: Values (image × pixel × channel) the global search and the starts use.
SEARCH_VALUES = 60_000
#: A residual whose RMS exceeds this many times the noise bound is a mismatch whatever the
#: noise is (a factor of 2 leaves room for noise correlated between neighbouring pixels,
#: which lowers the bound: demosaicing correlates them).
BOUND_FACTOR = 2.0

#: With fewer images than this, the cluster sandwich sums over tiles of each image instead.
MIN_IMAGE_CLUSTERS = 8
#: The tiles' side, in pixels (a misfit is correlated over a few pixels at least).
TILE_PX = 8

#: Levenberg–Marquardt steps per start on the subsample, before the projected steps.
START_STEPS = 40
#: `projected_lm` stops once this many accepted steps in a row have together lowered
#: the cost by less than `STALL_FRACTION` of it: the steps are then creeping along a
#: valley the data hardly constrain (Cook–Torrance's kd·E and F0·E with a free exposure,
#: anchored only by the Fresnel rise at grazing angles), where hundreds of damped steps would
#: move the values along the valley without changing the fit. A converging fit ends earlier,
#: on the 1e-9 rule.
STALL_STEPS = 5
STALL_FRACTION = 1e-6

UNIT, POSITIVE, FREE = "unit", "positive", "free"


@dataclass(frozen=True)
class CaptureFitOptions:
    """How a capture is fitted (see the module docstring)."""

    model: str = "strauss"
    exposure: str = "global"
    white_balance: bool = False
    ambient: bool = False
    max_steps: int = 200
    rtol: float = 1e-6
    atol: float = 1e-9
    seed: int = 0

    def __post_init__(self):
        if self.model not in MODELS:
            raise CaptureError(f"unknown model {self.model!r}; expected one of {', '.join(MODELS)}")
        if self.exposure not in EXPOSURES:
            raise CaptureError(f"unknown exposure {self.exposure!r}; expected one of {', '.join(EXPOSURES)}")


@dataclass(frozen=True)
class _Param:
    name: str
    size: int
    kind: str


def _parameters(options: CaptureFitOptions, images: int) -> tuple[_Param, ...]:
    """The model's parameters (`strauss_fit.models.reflectance`) less those a capture
    holds (`HELD`), an exposure when the model's coefficients are bounded (C ≤ 1
    cannot absorb the photographs' scale), and the capture's own: per-image exposures, white
    balance, ambient light."""
    model = reflectance_model(options.model)
    params = [_Param(p.name, p.size, p.kind) for p in model.parameters if p.name not in HELD]
    if model.bounded_scale and options.exposure != "fixed":
        params.append(_Param("exposure", 1, POSITIVE))
    if options.exposure == "per-image" and images > 1:
        params.append(_Param("image_exposure", images - 1, POSITIVE))
    if options.white_balance:
        params.append(_Param("white_balance", 2, POSITIVE))
    if options.ambient:
        params.append(_Param("ambient", 3, FREE))
    return tuple(params)


def _offsets(params: Sequence[_Param]) -> list[int]:
    return [int(v) for v in np.cumsum([0] + [p.size for p in params])]


def _to_physical(params: Sequence[_Param], theta: jax.Array) -> jax.Array:
    """θ → physical values: (1 + sin θ)/2 on [0, 1] (reaches the bounds, and can leave them
    again), exp θ for scales, θ itself for the ambient light."""
    parts = []
    for p, start in zip(params, _offsets(params)):
        t = theta[start : start + p.size]
        parts.append((1 + jnp.sin(t)) / 2 if p.kind == UNIT else jnp.exp(t) if p.kind == POSITIVE else t)
    return jnp.concatenate(parts)


def _to_unconstrained(params: Sequence[_Param], physical: np.ndarray) -> np.ndarray:
    out = []
    for p, start in zip(params, _offsets(params)):
        x = np.asarray(physical[start : start + p.size], dtype=np.float64)
        if p.kind == UNIT:
            out.append(np.arcsin(np.clip(2 * np.clip(x, 1e-3, 1 - 1e-3) - 1, -1, 1)))
        elif p.kind == POSITIVE:
            out.append(np.log(np.maximum(x, 1e-12)))
        else:
            out.append(x)
    return np.concatenate(out)


def _split(params: Sequence[_Param], vector: jax.Array) -> dict[str, jax.Array]:
    return {p.name: vector[start : start + p.size] for p, start in zip(params, _offsets(params))}


def _terms(samples: CaptureSamples, model: str = "strauss") -> dict[str, jax.Array]:
    """The material-independent terms of every (image, light, pixel) for ``model``
    (`strauss_fit.models.reflectance.ReflectanceModel.terms`), shapes (L, K, P), with
    the lights' intensities and any known ambient light."""
    normal = jnp.asarray(samples.normals)[None, None]
    view = jnp.asarray(samples.views)[None, None]
    terms = dict(reflectance_model(model).terms(normal, jnp.asarray(samples.light_dirs), view))
    terms["light_rgb"] = jnp.asarray(samples.light_rgb)
    if samples.ambient_light is not None:
        terms["ambient_light"] = jnp.asarray(samples.ambient_light)
    return terms


def _with_held(x: dict[str, jax.Array]) -> dict[str, jax.Array]:
    """``x`` with the held parameters (`HELD`) at their values."""
    like = next(iter(x.values()))
    return {name: jnp.full((1,), value, dtype=like.dtype) for name, value in HELD.items()} | x


def _reflected(model: str, x: dict[str, jax.Array], terms: dict[str, jax.Array]) -> tuple[jax.Array, jax.Array]:
    """Σ_k I_lkc f_c (L, P, 3) and the ambient reflectance a_c (3,) of the registered model."""
    reflectance = reflectance_model(model)
    values = _with_held(x)
    per_light = reflectance.radiance(values, terms)
    return jnp.sum(per_light * terms["light_rgb"], axis=1), reflectance.ambient(values)


def _predict(model: str, params: tuple[_Param, ...], physical: jax.Array, terms: dict[str, jax.Array]) -> jax.Array:
    x = _split(params, physical)
    reflected, ambient_reflectance = _reflected(model, x, terms)
    if "ambient" in x:
        reflected = reflected + x["ambient"] * ambient_reflectance
    if "ambient_light" in terms:  # a known ambient light, per image (a scene's)
        reflected = reflected + terms["ambient_light"][:, None, :] * ambient_reflectance
    images = reflected.shape[0]
    scale = x["exposure"][0] if "exposure" in x else jnp.ones((), reflected.dtype)
    per_image = jnp.full((images,), scale)
    if "image_exposure" in x:
        per_image = per_image * jnp.concatenate([jnp.ones(1, reflected.dtype), x["image_exposure"]])
    balance = jnp.ones(3, reflected.dtype)
    if "white_balance" in x:
        balance = jnp.stack([x["white_balance"][0], jnp.ones((), reflected.dtype), x["white_balance"][1]])
    return reflected * per_image[:, None, None] * balance


@dataclass
class _Problem:
    model: str
    params: tuple[_Param, ...]
    terms: dict[str, jax.Array]
    observed: jax.Array
    weight: jax.Array

    @property
    def data(self) -> tuple[dict[str, jax.Array], jax.Array, jax.Array]:
        return self.terms, self.observed, self.weight

    def residual(self, physical: jax.Array) -> jax.Array:
        return _weighted_residual(self.model, self.params, physical, self.data)


def _weighted_residual(model: str, params: tuple[_Param, ...], physical: jax.Array, data: tuple) -> jax.Array:
    """The one home of the residual: (Î − I) at the usable values (weight 1), 0 elsewhere."""
    terms, observed, weight = data
    return ((_predict(model, params, physical, terms) - observed) * weight).ravel()


def _problem(samples: CaptureSamples, options: CaptureFitOptions) -> _Problem:
    return _Problem(
        options.model,
        _parameters(options, samples.count),
        _terms(samples, options.model),
        jnp.asarray(samples.values),
        jnp.asarray(samples.usable, dtype=jnp.float64),
    )


@functools.lru_cache(maxsize=64)
def _residual_function(model: str, params: tuple[_Param, ...]) -> Callable:
    """The residual in θ for one model and parameter set: one function object per set, so
    that optimistix compiles it once per data shape."""

    def residuals(theta, data):
        return _weighted_residual(model, params, _to_physical(params, theta), data)

    return residuals


def _solve(
    problem: _Problem, theta0: np.ndarray, max_steps: int, rtol: float, atol: float
) -> tuple[np.ndarray, int, str]:
    """Levenberg–Marquardt from θ0; returns θ, the steps and the status."""
    import optimistix as optx

    residuals = _residual_function(problem.model, problem.params)
    solver = levenberg_marquardt(rtol, atol, normal_equations=True, reject_ratio=STRICT_REJECT_RATIO)
    solution = optx.least_squares(
        residuals, solver, jnp.asarray(theta0), args=problem.data, max_steps=max_steps, throw=False
    )
    status = status_name(int(_result_code(solution.result)))
    return np.asarray(solution.value), int(solution.stats["num_steps"]), status


def _subsample(samples: CaptureSamples, values: int, seed: int) -> CaptureSamples:
    pixels = max(50, values // max(1, 3 * samples.count))
    if pixels >= len(samples.rows):
        return samples
    rng = np.random.default_rng(seed)
    return samples.pixels(np.sort(rng.choice(len(samples.rows), pixels, replace=False)))


# --- starts: the linear parameters solved exactly on a grid of the non-linear ones ---------


def _model_starts(problem: _Problem, keep: int = 3) -> list[dict[str, np.ndarray]]:
    """For each point of the model's grid of non-linear values
    (`start_grid`), the linear unknowns
    (a per-channel one and a shared one, `linear_parts`)
    solved exactly by linear least squares over the subsample; the ``keep`` best (the
    earlier grid point first among equal costs)."""
    model = reflectance_model(problem.model)
    grid = model.start_grid() or [{}]
    stacked = {name: jnp.asarray([point[name] for point in grid], dtype=jnp.float64) for name in grid[0]}
    costs, values = _grid_starts(problem.model, stacked, len(grid), problem.terms, problem.observed, problem.weight)
    costs = np.asarray(costs)
    best = np.argsort(costs, kind="stable")[:keep]
    values = {name: np.asarray(v) for name, v in values.items()}
    return [{name: np.atleast_1d(v[i]) for name, v in values.items()} for i in best]


@functools.partial(jax.jit, static_argnums=(0, 2))
def _grid_starts(
    name: str,
    grid: dict[str, jax.Array],
    points: int,
    terms: dict[str, jax.Array],
    observed: jax.Array,
    weight: jax.Array,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """Every start of `_model_starts` in one compiled call (vmapped over the ``points``
    grid points; an eager loop spent more time dispatching than computing): per point the
    cost and the values (for a model whose scale is an exposure, the exposure re-solved for
    the clipped values: one linear unknown)."""
    model = reflectance_model(name)
    rgb = terms["light_rgb"]
    target = (observed * weight).ravel()

    def one(index):
        nonlinear = {key: values[index] for key, values in grid.items()}
        per_channel, shared = model.linear_parts(nonlinear, terms)
        per_channel = jnp.sum(per_channel * rgb, axis=1)  # (L, P, 3)
        shared = jnp.sum(shared * rgb, axis=1)
        # Î_c = X_c · per_channel_c + Y · shared_c over the usable values of all three
        # channels: unknowns X_r, X_g, X_b, Y
        design = jnp.zeros((3,) + per_channel.shape[:2] + (4,), dtype=per_channel.dtype)
        for c in range(3):
            design = design.at[c, ..., c].set(per_channel[..., c] * weight[..., c])
            design = design.at[c, ..., 3].set(shared[..., c] * weight[..., c])
        rhs = jnp.stack([observed[..., c] * weight[..., c] for c in range(3)])
        solution = jnp.linalg.lstsq(design.reshape(-1, 4), rhs.reshape(-1))[0]
        found, scale = model.from_linear(nonlinear, solution[:3], solution[3])
        found = {k: jnp.atleast_1d(v).astype(jnp.float64) for k, v in found.items() if k not in HELD}
        reflected, ambient = _reflected(name, found, terms)
        if "ambient_light" in terms:
            reflected = reflected + terms["ambient_light"][:, None, :] * ambient
        column = (reflected * weight).ravel()
        if not model.bounded_scale or scale is None:
            return jnp.sum((column - target) ** 2), found
        exposure = jnp.maximum(column @ target / jnp.maximum(column @ column, 1e-300), 1e-6)
        return jnp.sum((exposure * column - target) ** 2), found | {"exposure": exposure[None]}

    return jax.vmap(one)(jnp.arange(points))


def _starts(problem: _Problem) -> list[np.ndarray]:
    out = []
    for values in _model_starts(problem):
        full = []
        for p in problem.params:
            if p.name in values:
                full.append(np.asarray(values[p.name], dtype=np.float64))
            elif p.name == "ambient":
                full.append(np.zeros(3))
            else:  # image exposures, white balance: 1
                full.append(np.ones(p.size))
        out.append(np.concatenate(full))
    return out


# --- statistics ----------------------------------------------------------------------------


def _labels(params: Sequence[_Param]) -> list[str]:
    labels = []
    for p in params:
        if p.name in ("color", "albedo", "diffuse", "ambient", "kd", "f0"):  # RGB
            labels += [f"{p.name}_{c}" for c in "rgb"]
        elif p.name == "white_balance":
            labels += ["white_balance_r", "white_balance_b"]
        elif p.name == "image_exposure":
            labels += [f"image_exposure_{i + 2}" for i in range(p.size)]
        else:
            labels.append(p.name)
    return labels


def _jacobian(problem: _Problem, physical: np.ndarray) -> np.ndarray:
    """d residual / d physical values, (L·P·3, N), forward mode (N is small)."""
    return np.asarray(jax.jacfwd(problem.residual)(jnp.asarray(physical)))


def _by_name(params: Sequence[_Param], vector: np.ndarray) -> dict[str, Any]:
    out = {}
    for p, start in zip(params, _offsets(params)):
        part = [float(v) for v in vector[start : start + p.size]]
        out[p.name] = part if p.size > 1 or p.name in ("color",) else part[0]
    return out


def relative_rms(predicted: np.ndarray, observed: np.ndarray, usable: np.ndarray) -> float:
    """`\\sqrt{\\sum (\\hat I - I)^2 / \\sum I^2}` over the usable values."""
    num = float(np.sum(((predicted - observed) * usable) ** 2))
    den = float(np.sum((observed * usable) ** 2))
    return math.sqrt(num / den) if den > 0 else float("nan")


def delta_e_mean(predicted: np.ndarray, observed: np.ndarray, usable: np.ndarray) -> float:
    """Mean CIEDE2000 over the pixels whose three channels are usable, image by image (each
    image scaled by its own 99th percentile, see `strauss_fit.color.delta_e_2000`)."""
    values = []
    for pred, obs, ok in zip(predicted, observed, usable):
        keep = ok.all(axis=-1)
        if keep.any():
            values.append(delta_e_2000(np.maximum(pred[keep], 0.0), np.maximum(obs[keep], 0.0)))
    return float(np.mean(np.concatenate(values))) if values else float("nan")


@dataclass
class CaptureFit:
    """A capture's fit: the values, their two kinds of covariance, and the prediction."""

    model: str
    params: tuple[_Param, ...]
    physical: np.ndarray
    labels: list[str]
    laplace: np.ndarray
    clustered: np.ndarray
    predicted: np.ndarray
    steps: int
    status: str
    starts: list[dict[str, Any]] = field(default_factory=list)
    timing: dict[str, float] = field(default_factory=dict)
    #: Per value, the standard deviation the circle's uncertainty alone adds (included in
    #: both covariances); None when not computed.
    circle_sd: np.ndarray | None = None
    #: What the cluster sandwich summed over: "image" or "tile" (see `_clusters`).
    cluster_kind: str = "image"

    def values(self) -> dict[str, Any]:
        return _by_name(self.params, self.physical)

    def deviations(self, which: str = "clustered") -> dict[str, Any]:
        cov = self.clustered if which == "clustered" else self.laplace
        return _by_name(self.params, np.sqrt(np.maximum(np.diag(cov), 0.0)))


def fit_capture_samples(samples: CaptureSamples, options: CaptureFitOptions | None = None) -> CaptureFit:
    """Fit one material to every usable value of ``samples`` (see the module docstring)."""
    options = options or CaptureFitOptions()
    keep_freed_memory()
    with float64():
        return _fit(samples, options)


@functools.lru_cache(maxsize=64)
def _compiled(model: str, params: tuple[_Param, ...]) -> tuple[Callable, Callable]:
    """The residual and its Jacobian in the physical values, compiled once per model,
    parameter set and data shape."""

    def residual(physical, data):
        return _weighted_residual(model, params, physical, data)

    return jax.jit(residual), jax.jit(jax.jacfwd(residual))


def _bounds(params: Sequence[_Param]) -> tuple[np.ndarray, np.ndarray]:
    low, high = [], []
    for p in params:
        low += [0.0 if p.kind in (UNIT, POSITIVE) else -np.inf] * p.size
        high += [1.0 if p.kind == UNIT else np.inf] * p.size
    return np.array(low), np.array(high)


def _projected_step(
    x: np.ndarray,
    low: np.ndarray,
    high: np.ndarray,
    gradient: np.ndarray,
    bread: np.ndarray,
    damping: float,
    fixed: np.ndarray | None = None,
) -> np.ndarray:
    """A damped Gauss–Newton (Marquardt) step, (JᵀJ + λ diag JᵀJ) δ = −Jᵀr, with the values
    that would cross a bound held on it: the step is solved for the free values, any value it
    would carry across its bound is put on the bound and held, and the step is solved again
    for the rest (at most one pass per value). ``fixed`` values never move."""
    span = np.where(np.isfinite(high - low), high - low, 1.0)
    on_low = x <= low + 1e-9 * span
    on_high = x >= high - 1e-9 * span
    held = (on_low & (gradient > 0)) | (on_high & (gradient < 0))
    if fixed is not None:
        held = held | fixed
    step = np.zeros_like(x)
    for _ in range(len(x) + 1):
        free = ~held
        step = np.where(on_low & held, low - x, np.where(on_high & held, high - x, 0.0))
        step = np.where(held & ~on_low & ~on_high, np.clip(step, low - x, high - x), step)
        if fixed is not None:
            step = np.where(fixed, 0.0, step)
        if free.any():
            sub = bread[np.ix_(free, free)]
            sub = sub + np.diag(damping * np.diag(sub) + 1e-12 * np.trace(sub) / max(int(free.sum()), 1))
            rhs = gradient[free] + bread[np.ix_(free, held)] @ step[held]
            step[free] = -np.linalg.lstsq(sub, rhs, rcond=None)[0]
        crossing = free & ((x + step < low) | (x + step > high))
        if not crossing.any():
            break
        on_low = on_low | (crossing & (x + step < low))
        on_high = on_high | (crossing & (x + step > high))
        held = held | crossing
    return step


def projected_lm(
    residual_fn: Callable,
    jacobian_fn: Callable,
    data: Any,
    physical: np.ndarray,
    low: np.ndarray,
    high: np.ndarray,
    *,
    fixed: np.ndarray | None = None,
    max_steps: int = 8,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Projected Levenberg–Marquardt steps (`_projected_step`) on ``residual_fn(x,
    data)`` within [low, high], the ``fixed`` values held where they are.

    Why not optimistix's solver here: on every value each step is dominated by the
    Jacobian, which these steps compute once per accepted step and which then also serves
    the covariances; from the subsample's optimum they converge in a few steps. And in the
    physical values a value can sit exactly on its bound (an active set), where the θ
    transform only creeps toward it. A step that does not lower the cost is retried with
    10× the damping. The steps stop at ``max_steps``, when a step lowers the cost by less than
    1e-9 of it, or when `STALL_STEPS` steps together lowered it by less than
    `STALL_FRACTION` of it (a flat valley). Returns the values, the Jacobian and the residual at them, and
    the steps taken."""
    x = np.clip(physical, low, high)
    r = np.asarray(residual_fn(jnp.asarray(x), data))
    cost = float(r @ r)
    jac = np.asarray(jacobian_fn(jnp.asarray(x), data))
    steps, damping = 0, 1e-4
    recent: list[float] = []  # the cost decreases of the last STALL_STEPS accepted steps
    for _ in range(max_steps):
        steps += 1
        gradient = jac.T @ r
        bread = jac.T @ jac
        improved = False
        for _ in range(12):
            step = _projected_step(x, low, high, gradient, bread, damping, fixed)
            trial = np.clip(x + step, low, high)
            r_trial = np.asarray(residual_fn(jnp.asarray(trial), data))
            cost_trial = float(r_trial @ r_trial)
            if cost_trial <= cost:
                improved = True
                damping = max(damping / 10, 1e-9)
                break
            damping *= 10
        if not improved:
            break
        change = cost - cost_trial
        x, r, cost = trial, r_trial, cost_trial
        jac = np.asarray(jacobian_fn(jnp.asarray(x), data))
        if change <= 1e-9 * max(cost, 1e-300):
            break
        recent = [*recent[1 - STALL_STEPS :], change]
        if len(recent) == STALL_STEPS and sum(recent) <= STALL_FRACTION * max(cost, 1e-300):
            break
    return x, jac, r, steps


def _polish(
    problem: _Problem, physical: np.ndarray, max_steps: int = 8
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """`projected_lm` on a capture's residual, within the parameters' bounds."""
    residual_fn, jacobian_fn = _compiled(problem.model, problem.params)
    low, high = _bounds(problem.params)
    return projected_lm(residual_fn, jacobian_fn, problem.data, physical, low, high, max_steps=max_steps)


def _clusters(samples: CaptureSamples) -> tuple[np.ndarray, str]:
    """Per residual value (image, pixel, channel, raveled), its cluster: its image when the
    capture has at least `MIN_IMAGE_CLUSTERS` images, else its image's tile of
    `TILE_PX` × `TILE_PX` pixels."""
    images, pixels = samples.count, len(samples.rows)
    if images >= MIN_IMAGE_CLUSTERS:
        return np.repeat(np.arange(images), pixels * 3), "image"
    rows, cols = np.asarray(samples.rows) // TILE_PX, np.asarray(samples.cols) // TILE_PX
    _, tile = np.unique(rows * (int(cols.max()) + 1) + cols, return_inverse=True)
    tiles = int(tile.max()) + 1
    per_value = (np.arange(images)[:, None] * tiles + tile[None, :])[..., None]
    return np.broadcast_to(per_value, (images, pixels, 3)).ravel(), "tile"


def _circle_covariance(coarse: _Problem, samples: CaptureSamples, physical: np.ndarray, free: np.ndarray) -> np.ndarray:
    r"""The covariance the circle's uncertainty adds to the fitted values.

    Each of the circle's uncertain parameters k moved by ± one standard deviation
    (`strauss_fit.capture._sphere.circle_perturbations`) changes every pixel's normal
    and so the residual by `\Delta r_k`; to first order the optimum moves by
    `\Delta\theta_k = -(J^\top J)^{-1} J^\top \Delta r_k`, and independent parameters
    add `\sum_k \Delta\theta_k \Delta\theta_k^\top`. Computed on the search's
    subsample (a ratio of sums over the pixels: the subsample estimates it closely). Values on
    a bound (not ``free``) get none."""
    from ..capture._sphere import circle_perturbations, surface_at

    size = len(physical)
    pairs = circle_perturbations(samples.circle, samples.camera)
    if not pairs or not free.any():
        return np.zeros((size, size))
    sub = _subsample(samples, SEARCH_VALUES, 0)
    x = sub.cols + 0.5
    y = sub.rows + 0.5
    residual_fn, jacobian_fn = _compiled(coarse.model, coarse.params)
    at = jnp.asarray(physical)
    base = _Problem(
        coarse.model,
        coarse.params,
        _terms(sub, coarse.model),
        jnp.asarray(sub.values),
        jnp.asarray(sub.usable, dtype=jnp.float64),
    )
    jac = np.asarray(jacobian_fn(at, base.data))[:, free]
    bread = jac.T @ jac
    out = np.zeros((size, size))
    for pair in pairs:
        residuals = []
        for moved in pair:
            normals, views = surface_at(x, y, moved, samples.camera, samples.shape)
            shifted = _Problem(
                base.model,
                base.params,
                _terms(replace(sub, normals=normals, views=views), base.model),
                base.observed,
                base.weight,
            )
            residuals.append(np.asarray(residual_fn(at, shifted.data)))
        change = 0.5 * (residuals[1] - residuals[0])
        step = np.zeros(size)
        step[free] = -np.linalg.lstsq(bread, jac.T @ change, rcond=None)[0]
        out += np.outer(step, step)
    return out


def _fit(samples: CaptureSamples, options: CaptureFitOptions) -> CaptureFit:
    t0 = time.perf_counter()
    if not np.asarray(samples.usable).any():
        raise CaptureError("no usable values: every sphere pixel is saturated or under-exposed in every image")
    coarse = _problem(_subsample(samples, SEARCH_VALUES, options.seed), options)
    starts = _starts(coarse)
    t_search = time.perf_counter()
    ends = []
    for start in starts:
        theta, steps, status = _solve(
            coarse, _to_unconstrained(coarse.params, start), START_STEPS, options.rtol, options.atol
        )
        physical = np.asarray(_to_physical(coarse.params, jnp.asarray(theta)))
        cost = float(np.sum(np.asarray(coarse.residual(jnp.asarray(physical))) ** 2))
        ends.append(
            (
                cost,
                physical,
                {
                    "start": _by_name(coarse.params, start),
                    "end": _by_name(coarse.params, physical),
                    "cost": cost,
                    "steps": steps,
                    "status": status,
                },
            )
        )
    ends.sort(key=lambda item: item[0])
    t_starts = time.perf_counter()
    # the bounds: LM in θ creeps toward a value on its bound (the transform's slope vanishes
    # there); the projected steps put it there, first on the subsample, then on every value
    physical, _, _, coarse_steps = _polish(coarse, ends[0][1], max_steps=options.max_steps)
    problem = _problem(samples, options)
    physical, jac, residual, polish_steps = _polish(problem, physical)
    t_solve = time.perf_counter()
    bread = jac.T @ jac
    count = int(np.asarray(samples.usable).sum())
    size = len(physical)
    low, high = _bounds(problem.params)
    # a value on its bound is held there: no symmetric interval (0, as in single fits)
    free = (physical > low) & (physical < high)
    sigma2 = float(residual @ residual) / max(count - int(free.sum()), 1)
    laplace = sandwich(bread, sigma2 * bread, free)
    # The cluster sandwich: residuals of one image are correlated (a misfit is smooth over
    # the sphere), so their scores are summed per cluster before the outer product: per
    # image when there are enough images, else per tile of TILE_PX × TILE_PX pixels of each
    # image (one image is one cluster, whose scores sum to zero at the optimum).
    clusters, cluster_kind = _clusters(samples)
    scores = np.zeros((int(clusters.max()) + 1, size))
    np.add.at(scores, clusters, jac * residual[:, None])
    count_clusters = int(np.count_nonzero(np.any(scores != 0, axis=1)))
    meat = scores.T @ scores * (count_clusters / max(count_clusters - 1, 1))
    clustered = sandwich(bread, meat, free)
    # where the sphere is, is itself uncertain: its share is added to both covariances
    from_circle = _circle_covariance(coarse, samples, physical, free)
    laplace, clustered = laplace + from_circle, clustered + from_circle
    predicted = np.asarray(_predict(problem.model, problem.params, jnp.asarray(physical), problem.terms))
    t_end = time.perf_counter()
    return CaptureFit(
        cluster_kind=cluster_kind,
        circle_sd=np.sqrt(np.maximum(np.diag(from_circle), 0.0)),
        model=options.model,
        params=problem.params,
        physical=physical,
        labels=_labels(problem.params),
        laplace=laplace,
        clustered=clustered,
        predicted=predicted,
        steps=ends[0][2]["steps"] + coarse_steps + polish_steps,
        status=ends[0][2]["status"],
        starts=[info for _, _, info in ends],
        timing={
            "search_s": t_search - t0,
            "starts_s": t_starts - t_search,
            "solve_s": t_solve - t_starts,
            "statistics_s": t_end - t_solve,
        },
    )
