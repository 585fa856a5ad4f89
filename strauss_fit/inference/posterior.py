r"""The posterior of a fit: likelihood, priors and noise level, shared by the sampler
(`strauss_fit.inference.sampler`) and the report.

Model. The target's usable pixels (the same pixels as `strauss_fit.fitting.api.fit`: on
the sphere, finite, not clipped, inside the mask) are the rendered image plus independent
Gaussian noise of one standard deviation σ on every RGB value:

```text
\log p(\theta \mid D) = -\frac{1}{2\sigma^2}\sum_{k=1}^{N} r_k(\theta)^2 + \log\pi(\theta) + \text{const},
\qquad r(\theta) = I_\text{model}(\theta) - I_\text{target},
```

with N = 3 × (usable pixels) and θ the physical values of the free parameters (in
``problem.layout`` order). σ is either given (a known sensor noise) or estimated at the
least-squares optimum `\hat\theta` as `\hat\sigma^2 = \mathrm{RSS}(\hat\theta)/(N - P)`
(P free entries), the same estimate the fit's Laplace deviations use. Plugging in
`\hat\sigma` instead of marginalising over σ changes the intervals by a factor of
order `1 + 1/N`, negligible for images.

Prior `\pi`: uniform (a box) over each parameter's range — [0, 1] for the colour
channels, smoothness, metalness and transparency; n ∈ [1, max(3, 1.5 n̂)] for the index of
refraction; a light intensity I ∈ [0, 10 max(Î, 0.1)]. The last two have no natural upper
bound, so a generous one is chosen (and recorded with the chain); the user may narrow any
range (``--prior``). Outside the box `\log p = -\infty`.

Laplace (Gauss–Newton) estimate: at `\hat\theta`,
`\Sigma \approx \sigma^2 (J^\top J)^{-1}`, J the Jacobian of r
(`strauss_fit.stats.laplace.laplace_covariance`). It is exact for a linear model
with a flat prior and an optimum away from the bounds.
"""

from __future__ import annotations

import functools
import hashlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..errors import StraussFitError
from ..fitting.options import FitOptions
from ..fitting.parameters import Layout, lights_with
from ..fitting.problem import Problem, build_problem
from ..fitting.result import FitResult
from ..io.targets import Target
from ..precision import uses_float64
from ..rendering.strauss import plan_render
from ..scene.loading import Scene

#: Upper end of the prior on the index of refraction (unless the fit lies beyond 2/3 of it).
IOR_PRIOR_MAX = 3.0
#: A residual RMS below this fraction of the target's largest value counts as an exact fit.
EXACT_FIT = 1e-6
#: Upper end of the prior on a light intensity, as a multiple of max(fitted value, 0.1).
INTENSITY_PRIOR_FACTOR = 10.0


class PosteriorError(StraussFitError):
    """A posterior cannot be set up as asked (bad σ, bad prior, a fit that does not match)."""


@dataclass(frozen=True)
class Prior:
    """A uniform prior: a box ``lower`` ≤ θ ≤ ``upper`` (one entry per label)."""

    labels: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray

    def contains(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x)
        return np.all((x >= self.lower) & (x <= self.upper), axis=-1)

    def as_dict(self) -> dict[str, list[float]]:
        return {label: [float(lo), float(hi)] for label, lo, hi in zip(self.labels, self.lower, self.upper)}


def default_prior(layout: Layout, x_hat: np.ndarray, overrides: dict[str, tuple[float, float]] | None = None) -> Prior:
    """The uniform prior of the module docstring, with user ``overrides`` (``{name or
    label: (low, high)}``; a group name such as ``color`` sets all its entries), each of
    which must lie inside the parameter's natural range."""
    x_hat = np.asarray(x_hat, dtype=np.float64)
    lower = layout.lower_bounds().astype(np.float64)
    upper = layout.upper_bounds().astype(np.float64)
    labels = layout.labels()
    owners = [name for name, size in zip(layout.names, layout.sizes) for _ in range(size)]
    for k, owner in enumerate(owners):
        if np.isinf(upper[k]):
            if owner == "ior":
                upper[k] = max(IOR_PRIOR_MAX, 1.5 * x_hat[k])
            else:  # a light intensity
                upper[k] = INTENSITY_PRIOR_FACTOR * max(x_hat[k], 0.1)
    natural_lower, natural_upper = layout.lower_bounds(), layout.upper_bounds()
    for key, (low, high) in (overrides or {}).items():
        entries = [k for k in range(len(labels)) if labels[k] == key or owners[k] == key]
        if not entries:
            raise PosteriorError(f"--prior {key}: not a free parameter of this fit (free: {', '.join(labels)})")
        if not (np.isfinite(low) and np.isfinite(high) and low < high):
            raise PosteriorError(f"--prior {key}={low},{high}: need finite LOW < HIGH")
        for k in entries:
            if low < natural_lower[k] or high > natural_upper[k]:
                raise PosteriorError(
                    f"--prior {key}={low},{high} leaves the range of {labels[k]} "
                    f"[{natural_lower[k]:g}, {natural_upper[k]:g}]"
                )
            lower[k], upper[k] = low, high
    return Prior(tuple(labels), lower, upper)


def parse_priors(items: list[str]) -> dict[str, tuple[float, float]]:
    """Prior ranges written as ``NAME=LOW,HIGH`` (the command line's ``--prior``), for
    `default_prior`'s ``overrides``."""
    priors = {}
    for item in items:
        name, sep, text = item.partition("=")
        parts = text.split(",")
        if not sep or not name or len(parts) != 2:
            raise StraussFitError(f"--prior expects NAME=LOW,HIGH, got {item!r}")
        try:
            priors[name] = (float(parts[0]), float(parts[1]))
        except ValueError:
            raise StraussFitError(f"--prior {name}: {text!r} is not LOW,HIGH numbers") from None
    return priors


def check_sigma(sigma: float, what: str = "the noise level sigma") -> float:
    """σ must be a finite positive number, within
    `NOISE_RANGE` (σ² and 1/σ² stay in float64's range);
    ``what`` names it in the error (``--sigma`` on the command line)."""
    from ..stats.noise import check_noise_level

    if not np.isfinite(sigma) or sigma <= 0:
        raise PosteriorError(f"the noise level sigma must be a finite number > 0, got {sigma:g}")
    check_noise_level(sigma, what)
    return float(sigma)


@eqx.filter_jit
def _sum_of_squares(problem: Problem, x: Array) -> Array:
    r = problem.residual_physical(x)
    return jnp.sum(r * r)


@uses_float64
def sum_of_squares(problem: Problem, x: np.ndarray) -> float:
    """RSS(θ) = Σ r_k(θ)², unnormalised."""
    return float(_sum_of_squares(problem, jnp.asarray(x, dtype=jnp.float64)))


@uses_float64
def estimate_sigma(problem: Problem, x_hat: np.ndarray) -> float:
    """σ̂ = sqrt(RSS(θ̂) / (N − P)). An error if σ̂ is below `EXACT_FIT` times the
    target's largest value: such a target is noise-free (a rendering, up to float
    rounding), its noise cannot be estimated and ``--sigma`` must be given."""
    n, p = int(problem.target.size), problem.layout.size
    sigma = float(np.sqrt(sum_of_squares(problem, x_hat) / max(n - p, 1)))
    scale = float(np.max(np.abs(np.asarray(problem.target))))
    if not np.isfinite(sigma) or sigma <= EXACT_FIT * scale:
        raise PosteriorError(
            f"the target fits exactly (residual RMS {sigma:.2g}), so its noise cannot be estimated "
            "from it; give the noise level with --sigma"
        )
    return sigma


#: (shape, dtype name) of every array leaf packed into the flat argument.
_Spec = tuple[tuple[tuple[int, ...], str], ...]


def _pack(tree: Any) -> tuple[np.ndarray, Any, _Spec]:
    """All array leaves of ``tree`` as one float64 vector, with what `_unpack` needs."""
    leaves, treedef = jax.tree_util.tree_flatten(tree)
    spec = tuple((tuple(np.shape(leaf)), np.asarray(leaf).dtype.name) for leaf in leaves)
    flat = np.concatenate([np.asarray(leaf, dtype=np.float64).ravel() for leaf in leaves]) if leaves else np.zeros(0)
    return flat, treedef, spec


def _unpack(flat: Array, treedef: Any, spec: _Spec) -> Any:
    leaves, offset = [], 0
    for shape, dtype in spec:
        size = int(np.prod(shape, dtype=np.int64))
        leaves.append(flat[offset : offset + size].reshape(shape).astype(dtype))
        offset += size
    return jax.tree_util.tree_unflatten(treedef, leaves)


def _batch_function(static: Any, treedef: Any, spec: _Spec) -> Callable:
    """The jitted, ``vmap``-ed log-posterior ``(flat, xs) -> (W,)`` for problems with this
    static part and these array shapes (``flat`` packs the problem's arrays, the bounds
    and −1/(2σ²))."""

    def one(flat, x):
        dynamic, lower, upper, scale = _unpack(flat, treedef, spec)
        problem = eqx.combine(dynamic, static)
        inside = jnp.all((x >= lower) & (x <= upper))
        r = problem.residual_physical(jnp.clip(x, lower, upper))
        return jnp.where(inside, scale * jnp.sum(r * r), -jnp.inf)

    return jax.jit(jax.vmap(one, in_axes=(None, 0)))


_cached_batch_function = functools.lru_cache(maxsize=32)(_batch_function)


class LogPosterior:
    """log p(θ | D) up to a constant, for a batch of walkers: ``(W, P) -> (W,)``.

    One jitted, ``vmap``-ed JAX function, compiled once per batch size and per problem
    *structure*: the problem's arrays, the bounds and 1/σ² are an argument, not constants
    baked into the program, so a new target of the same shape (the noise draws of a
    coverage study, a resumed chain) reuses the compiled code. They are packed into one
    float64 vector because a jitted call costs about 1.5 µs per array argument, which with
    the ~50 arrays of a problem was as much as evaluating 16 walkers on a 32 × 32 image.
    Outside the prior box the value is −∞; the model is evaluated at the point clipped
    into the box so that no out-of-range value (s > 1, say) reaches it.
    """

    @uses_float64
    def __init__(self, problem: Problem, prior: Prior, sigma: float):
        self.problem = problem
        self.prior = prior
        self.sigma = check_sigma(sigma)
        dynamic, static = eqx.partition(problem, eqx.is_array)
        flat, treedef, spec = _pack((dynamic, prior.lower, prior.upper, np.float64(-0.5 / self.sigma**2)))
        try:
            self._batch = _cached_batch_function(static, treedef, spec)
        except (TypeError, ValueError):  # an unhashable static part: compile for this instance only
            self._batch = _batch_function(static, treedef, spec)
        self._flat = jax.device_put(flat)

    @uses_float64
    def jax_batch(self, xs: Array) -> Array:
        """The jitted function itself, on a JAX array."""
        return self._batch(self._flat, xs)

    @uses_float64
    def __call__(self, xs: np.ndarray) -> np.ndarray:
        xs = np.asarray(xs, dtype=np.float64)
        if xs.ndim == 1:
            return self(xs[None])[0]
        # NumPy straight in: jnp.asarray first would cost more than the call's dispatch
        return np.asarray(self._batch(self._flat, xs), dtype=np.float64)


# --- rebuilding a fit's problem from its JSON result ------------------------------------


def target_digest(problem: Problem) -> str:
    """SHA-256 of the usable target values (what the likelihood sees): a chain is tied to it."""
    return hashlib.sha256(np.ascontiguousarray(np.asarray(problem.target, dtype=np.float64)).tobytes()).hexdigest()


@uses_float64
def problem_from_fit(scene: Scene, target: Target, fit: FitResult | dict[str, Any]) -> tuple[Problem, np.ndarray]:
    """The fit's `Problem` and optimum θ̂, rebuilt from a
    fit result (a `FitResult`, or ``strauss-fit fit``'s JSON,
    read with `from_json`) for ``scene`` (already
    matched to ``target``'s size).

    Held parameters take the result's values; free ones are the layout. The pixels used
    must be as many as the fit used, else the result belongs to another target or mask.
    """
    fit = FitResult.from_json(fit)
    free = list(fit.free)
    if not free:
        raise PosteriorError("the fit result has no free parameter: nothing to sample")
    material_values = fit.material.to_dict()
    lights = dict(fit.lights)
    settings = fit.settings
    material = fit.material
    scene = eqx.tree_at(
        lambda s: s.lights, scene, lights_with(scene.lights, {k: jnp.asarray(v) for k, v in lights.items()})
    )
    scene = eqx.tree_at(lambda s: s.material, scene, material)
    transparent = "transparency" in free or float(material_values["transparency"]) > 0
    plan = plan_render(scene, material, transparent=transparent)
    # results written before edge pixels were left out (no "edge_pixels" setting) used them
    options = FitOptions(
        mode=settings.get("mode", "exact"),
        table_size=int(settings.get("table_size", FitOptions.table_size)),
        edge_pixels=settings.get("edge_pixels", "include"),
    )
    exposure = 1.0 if fit.exposure is None else float(fit.exposure)
    for name in free:
        if name not in material_values and name not in lights and name != "exposure":
            raise PosteriorError(f"the fit result frees {name!r}, which this scene does not have")
    problem, _, index = build_problem(
        scene, target, free, material, plan, options, exposure=None if "exposure" in free else exposure
    )
    used = fit.pixels_used
    if used is not None and int(used) != index.size:
        raise PosteriorError(
            f"the fit result used {used} pixels but {target.path} has {index.size} usable sphere "
            "pixels: it was made for another target, mask or scene"
        )
    values = {**material_values, **lights, "exposure": exposure}
    x_hat = problem.layout.join(values)
    labels = problem.layout.labels()
    pinned = np.array([label in fit.at_bound for label in labels])
    problem = problem.pin(pinned, np.where(pinned, x_hat, 0.0))
    return problem, x_hat
