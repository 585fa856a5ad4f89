r"""The posterior of a capture's material, and sampling it with emcee (``strauss-fit sample
--fit CAPTURE_RESULT.json``).

A capture's fit (`strauss_fit.fitting.capture_result.fit_capture`) minimises
`\mathrm{RSS}(\theta) = \sum_i r_i(\theta)^2` over the N usable values i (image ×
sphere pixel × channel; saturated and under-exposed ones left out), θ the physical values
of its parameters in the order of the result's labels (``color_r``, …, ``smoothness``,
``metalness``, ``exposure``, then per-image exposures, white balance, ambient as fitted).

Likelihood. Independent Gaussian noise of one standard deviation σ on every usable value:
`\log L(\theta) = -\mathrm{RSS}(\theta)/(2\sigma^2)` (the constant left out). σ is
given (``sigma``, ``--sigma``), else estimated at the fit's optimum θ̂ as
`\hat\sigma = \sqrt{\mathrm{RSS}(\hat\theta)/(N-P)}`, and the chain states which
(``sigma_source``).

Prior: uniform over a box — [0, 1] for values in [0, 1] (colour, s, m); [0, 10·max(θ̂, 0.1)]
for a positive scale (the exposure, per-image exposures, white balance, and the albedo,
diffuse, specular and exponent of the other models: no natural upper end, so a generous one);
[−A, A] with A = 10·max(|θ̂|, 0.1) for the ambient light (it may be negative). ``priors``
(``--prior NAME=LOW,HIGH``) narrows any of them within the parameter's natural range. Outside
the box the log-posterior is −∞ (the model is evaluated at the point clipped into the box).

Speed: a subsample with a control variate. A full DiLiGenT capture has 4.4 M values, one
prediction over all of them costs tens of milliseconds, and emcee needs tens of thousands
of them. So, when the capture has more than ``values`` values (default
`DEFAULT_VALUES`), the likelihood sees a fixed random subsample of sphere pixels
(the same pixels in every image, drawn once with the chain's seed and stored with it; n
usable values of the N) through the *difference estimator* (Quiroz, Kohn, Villani & Tran,
JASA 2019). With `\delta = \theta - \hat\theta`, the full data's
`g = J^\top r(\hat\theta)` and `H = J^\top J + M`, the Hessian of ½RSS at θ̂
(J the Jacobian of r, `M = \sum_i r_i \nabla^2 r_i` the misfit's curvature; all
computed once, over every value, in chunks), and `q_i(\theta)` the second-order
Taylor expansion of `r_i(\theta)^2` about θ̂,

```text
\widetilde{\mathrm{RSS}}(\theta) = \mathrm{RSS}(\hat\theta) + 2 g^\top\delta
    + \delta^\top H\,\delta
    + \frac{N}{n}\sum_{i \in \text{subsample}} \big[r_i(\theta)^2 - q_i(\theta)\big].
```

The first three terms are the exact second-order expansion of the full RSS about θ̂; the
sum estimates, from the subsample, only what that expansion misses (third order and up:
how the model bends over the posterior's width), which is small. So the posterior keeps the
full data's centre and curvature — near θ̂ it is the full data's, exactly — which a plain
subsample with its likelihood scaled by N/n would not: that one centres on the
*subsample's* optimum, about `\sqrt{N/n - 1}` standard deviations away, and its width
varies with the draw. The approximation left is the subsample's estimate of the
higher-order remainder; log p(θ̂) = −RSS(θ̂)/(2σ²) whatever the subsample. On a synthetic
capture (88 k usable values) a subsample of 18 k values gave log-posteriors within 0.007 of
the exact ones at points where they had dropped by 230 to 1 500 from θ̂. ``values=None`` (``--values all``) evaluates
the exact likelihood over every value, and a capture with at most ``values`` values is
always evaluated exactly.

One evaluation is one jitted, ``vmap``-ed JAX call over a batch of walkers (compiled once
per batch size), as for single images (`strauss_fit.inference.posterior.LogPosterior`).

Adjustment (``adjust``, as `strauss_fit.inference.adjustment`): the capture's ± is the
image-cluster sandwich V, the spread of the fitted values over other photographs of this
kind, which on a capture the model cannot reproduce is wider than the Gaussian likelihood's
posterior (a misfit is correlated over each image). ``"auto"`` is ``"affine"`` when the
fit's verdict is ``mismatch`` (the draws are mapped so that their covariance is V; the raw
chain is kept) or when the circle's share of some value's ± exceeds `CIRCLE_SHARE` of
the likelihood's own, else ``"none"``; ``"temperature"`` samples with σ√T,
T = max(1, the largest generalised eigenvalue of (σ²H⁻¹, V)), H the Hessian of ½ of the
likelihood's RSS above at θ̂, over the entries V does not hold at a bound.

The sphere's circle. The fit's ± (both kinds) add the share of the uncertainty of where
the sphere is (``uncertainty_circle`` in the result); the likelihood takes the circle as
detected, so an unadjusted chain is conditional on it and is set against the Laplace ±
σ²(JᵀJ)⁻¹ of its own likelihood; the summary warns when the circle's share exceeds
`CIRCLE_SHARE` of it. The affine adjustment maps the draws to the image-cluster
sandwich, circle included.

Running, the chain file, diagnostics, progress, Ctrl-C and ``resume`` are the single-image
sampler's (`strauss_fit.inference.sampler.run_sampler`, same file format). The
chain's metadata says ``kind: "capture"`` and holds the capture's fit result (``fit``),
where it was read from (``fit_path``, and ``fit_base``, the folder its recorded capture
paths are relative to), σ and its source, the prior, the likelihood (``likelihood``:
``method``, the values N and n, the subsample's pixel indices) and a digest of the
capture's usable values (``data_sha256``): `reload_chain_capture` reads the capture
again from it.
"""

from __future__ import annotations

import copy
import functools
import hashlib
import json
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ..capture._manifest import Capture
from ..capture._samples import CaptureSamples
from ..errors import CaptureError, StraussFitError
from ..fitting.capture import POSITIVE, UNIT, _compiled, _Param, _terms, _weighted_residual
from ..fitting.capture_result import is_capture_result, reload_capture_fit
from ..fitting.options import DEFAULT_QUALITY
from ..io.files import check_writable, read_json
from ..precision import uses_float64
from ..stats import laplace as _laplace
from .adjustment import METHODS as ADJUST_METHODS
from .adjustment import AdjustmentError, adjusted_entries, temperature
from .posterior import EXACT_FIT, Prior, check_sigma
from .sampler import (
    ChainError,
    Progress,
    SampleResult,
    SampleSettings,
    autocorrelation_times,
    burn_in,
    default_walkers,
    initial_walkers,
    load_chain,
    run_and_summarise,
)
from .summaries import (
    LAPLACE,
    Laplace,
    adjustment_summary,
    chain_posterior,
    degeneracy_warnings,
    describe,
    posterior_summary,
)

#: The chain's ``kind`` in its metadata.
KIND = "capture"
#: Values (image × pixel × channel) the likelihood evaluates by default; more are subsampled.
DEFAULT_VALUES = 100_000
#: Values per chunk of the full data's Jacobian pass.
CHUNK_VALUES = 200_000
#: Fewest sphere pixels a subsample has.
MIN_PIXELS = 50
#: Upper end of the prior of a positive scale, as a multiple of max(θ̂, 0.1).
POSITIVE_PRIOR_FACTOR = 10.0
#: Half-width of the prior of the ambient light, as a multiple of max(|θ̂|, 0.1).
AMBIENT_PRIOR_FACTOR = 10.0
#: What the capture's ± is called (the fit result's ``uncertainty_method.name``).
CLUSTER = "image-cluster sandwich"


def _owners(params: Sequence[_Param]) -> list[str]:
    return [p.name for p in params for _ in range(p.size)]


def _kinds(params: Sequence[_Param]) -> list[str]:
    return [p.kind for p in params for _ in range(p.size)]


def natural_range(params: Sequence[_Param]) -> tuple[np.ndarray, np.ndarray]:
    """Each entry's natural range: [0, 1] for unit values, [0, ∞) for scales, ℝ for the ambient."""
    kinds = _kinds(params)
    lower = np.array([0.0 if k in (UNIT, POSITIVE) else -np.inf for k in kinds])
    upper = np.array([1.0 if k == UNIT else np.inf for k in kinds])
    return lower, upper


def capture_prior(
    params: Sequence[_Param],
    labels: Sequence[str],
    x_hat: np.ndarray,
    overrides: dict[str, tuple[float, float]] | None = None,
) -> Prior:
    """The uniform prior box of the module docstring, with user ``overrides`` (``{name or
    label: (low, high)}``; a name such as ``color`` sets all its entries), each inside the
    parameter's natural range."""
    x_hat = np.asarray(x_hat, dtype=np.float64)
    lower, upper = natural_range(params)
    natural_lower, natural_upper = lower.copy(), upper.copy()
    owners, kinds = _owners(params), _kinds(params)
    for k, kind in enumerate(kinds):
        if kind == POSITIVE:
            upper[k] = POSITIVE_PRIOR_FACTOR * max(float(x_hat[k]), 0.1)
        elif kind != UNIT:
            half = AMBIENT_PRIOR_FACTOR * max(abs(float(x_hat[k])), 0.1)
            lower[k], upper[k] = -half, half
    for key, (low, high) in (overrides or {}).items():
        entries = [k for k in range(len(labels)) if labels[k] == key or owners[k] == key]
        if not entries:
            raise StraussFitError(f"--prior {key}: not a parameter of this capture's fit (free: {', '.join(labels)})")
        if not (np.isfinite(low) and np.isfinite(high) and low < high):
            raise StraussFitError(f"--prior {key}={low},{high}: need finite LOW < HIGH")
        for k in entries:
            if low < natural_lower[k] or high > natural_upper[k]:
                raise StraussFitError(
                    f"--prior {key}={low},{high} leaves the range of {labels[k]} "
                    f"[{natural_lower[k]:g}, {natural_upper[k]:g}]"
                )
            lower[k], upper[k] = low, high
    return Prior(tuple(labels), lower, upper)


def data_digest(samples: CaptureSamples) -> str:
    """SHA-256 of the capture's usable values (what the likelihood sees): a chain is tied to it."""
    usable = np.ascontiguousarray(np.asarray(samples.usable, dtype=bool))
    values = np.ascontiguousarray(np.where(usable, np.asarray(samples.values, dtype=np.float64), 0.0))
    return hashlib.sha256(values.tobytes() + usable.tobytes()).hexdigest()


def _data(model: str, samples: CaptureSamples, index: np.ndarray, real: np.ndarray | None = None) -> tuple:
    """The residual's data (``model``'s terms, observed, weight) at the sphere pixels
    ``index``; pixels where ``real`` is False (padding) get weight 0."""
    sub = samples.pixels(index)
    weight = np.asarray(sub.usable, dtype=np.float64)
    if real is not None:
        weight = weight * np.asarray(real, dtype=np.float64)[None, :, None]
    return _terms(sub, model), jnp.asarray(sub.values, dtype=jnp.float64), jnp.asarray(weight)


@functools.lru_cache(maxsize=32)
def _half_rss_hessian(model: str, params: tuple[_Param, ...]) -> Callable:
    """The Hessian of ½Σr² in the physical values, ``(x, data) -> (P, P)``, jitted."""

    def half_rss(x, data):
        r = _weighted_residual(model, params, x, data)
        return 0.5 * jnp.sum(r * r)

    return jax.jit(jax.hessian(half_rss))


def _expansion(
    model: str, params: tuple[_Param, ...], x: jax.Array, data: tuple
) -> tuple[jax.Array, jax.Array, float, np.ndarray, np.ndarray, np.ndarray]:
    """At ``x`` over ``data``: the residual r, its Jacobian J, and Σr², g = Jᵀr, B = JᵀJ and
    M = Σ rᵢ∇²rᵢ (the misfit's curvature: the Hessian of ½Σr² less JᵀJ)."""
    residual_fn, jacobian_fn = _compiled(model, params)
    r, jac = residual_fn(x, data), jacobian_fn(x, data)
    r_np, jac_np = np.asarray(r), np.asarray(jac)
    b = jac_np.T @ jac_np
    m = np.asarray(_half_rss_hessian(model, params)(x, data)) - b
    return r, jac, float(r_np @ r_np), jac_np.T @ r_np, b, m


def _full_pass(
    model: str, params: tuple[_Param, ...], samples: CaptureSamples, x_hat: np.ndarray
) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """RSS, g = Jᵀr, B = JᵀJ and M = Σ rᵢ∇²rᵢ at ``x_hat`` over every usable value, in
    chunks of about `CHUNK_VALUES` values (all of one size: the last is padded with
    weight 0, so that each function compiles once)."""
    images, pixels = np.asarray(samples.values).shape[:2]
    per_chunk = max(1, min(pixels, CHUNK_VALUES // max(3 * images, 1)))
    size = len(x_hat)
    x = jnp.asarray(x_hat, dtype=jnp.float64)
    rss, g, b, m = 0.0, np.zeros(size), np.zeros((size, size)), np.zeros((size, size))
    for start in range(0, pixels, per_chunk):
        index = np.arange(start, start + per_chunk)
        real = index < pixels
        _, _, part_rss, part_g, part_b, part_m = _expansion(
            model, params, x, _data(model, samples, np.where(real, index, 0), real)
        )
        rss, g, b, m = rss + part_rss, g + part_g, b + part_b, m + part_m
    return rss, g, b, m


@functools.lru_cache(maxsize=32)
def _functions(model: str, params: tuple[_Param, ...], subsampled: bool) -> tuple[Callable, Callable]:
    """The log-likelihood of one θ, ``value(args, x)``, and the jitted, ``vmap``-ed
    log-posterior of a batch, ``batch(args, lower, upper, xs) -> (W,)``; one pair per model,
    parameter set and kind of likelihood (exact, or the subsample's difference estimator)."""

    def value(args, x):
        if not subsampled:
            data, neg = args
            r = _weighted_residual(model, params, x, data)
            return neg * jnp.sum(r * r)
        data, neg, x_hat, rss, g, c, r_hat, jac, factor = args
        r = _weighted_residual(model, params, x, data)
        d = x - x_hat
        linear = r_hat + jac @ d
        quadratic = rss + 2 * (g @ d) + d @ (c @ d)
        return neg * (quadratic + factor * jnp.sum((r - linear) * (r + linear)))

    def one(args, lower, upper, x):
        inside = jnp.all((x >= lower) & (x <= upper))
        return jnp.where(inside, value(args, jnp.clip(x, lower, upper)), -jnp.inf)

    return value, jax.jit(jax.vmap(one, in_axes=(None, None, None, 0)))


class CapturePosterior:
    """log p(θ | capture) up to a constant, for a batch of walkers: ``(W, P) -> (W,)`` (the
    module docstring's likelihood and prior). Built by `build`; ``prior`` and
    ``sigma`` as `strauss_fit.inference.posterior.LogPosterior` has them, so that
    `strauss_fit.inference.sampler.run_sampler` runs it as it runs a single image's."""

    prior: Prior
    sigma: float

    @classmethod
    @uses_float64
    def build(
        cls,
        samples: CaptureSamples,
        model: str,
        params: tuple[_Param, ...],
        x_hat: np.ndarray,
        prior: Prior,
        sigma: float | None = None,
        *,
        values: int | None = DEFAULT_VALUES,
        seed: int = 0,
        pixels: Sequence[int] | None = None,
    ) -> CapturePosterior:
        """The posterior of ``samples`` (the images the fit was made on) for the fit's
        ``model``, ``params`` and optimum ``x_hat``. ``sigma`` None: estimated,
        sqrt(RSS/(N − P)) (an error for a capture the model reproduces exactly). ``values``:
        the subsample's size in values (None: every value); ``pixels``: the subsample's sphere
        pixel indices (a resumed chain's; ``None`` with ``values`` None or covering the
        capture: exact); ``seed`` draws the subsample otherwise."""
        self = cls()
        self.model, self.params = model, params
        self.x_hat = np.asarray(x_hat, dtype=np.float64)
        self.prior = prior
        usable = np.asarray(samples.usable, dtype=bool)
        self.count = int(usable.sum())
        if self.count == 0:
            raise CaptureError("the capture has no usable values")
        self.rss, self.gradient, self.information, self.curvature = _full_pass(model, params, samples, self.x_hat)
        images, total_pixels = usable.shape[:2]
        size = len(self.x_hat)
        if sigma is None:
            sigma = math.sqrt(self.rss / max(self.count - size, 1))
            scale = float(np.max(np.abs(np.asarray(samples.values)[usable])))
            if not np.isfinite(sigma) or sigma <= EXACT_FIT * scale:
                raise StraussFitError(
                    f"the capture fits exactly (residual RMS {sigma:.2g}), so its noise cannot be estimated "
                    "from it; give the noise level with --sigma"
                )
            self.sigma_source = "estimated from the fit's residual over every usable value, sqrt(RSS/(N-P))"
        else:
            self.sigma_source = "given (--sigma)"
        self.sigma = check_sigma(float(sigma), "--sigma")
        if pixels is None and values is not None and 3 * images * total_pixels > values:
            chosen = max(MIN_PIXELS, int(values) // max(3 * images, 1))
            if chosen < total_pixels:
                rng = np.random.default_rng(seed)
                pixels = np.sort(rng.choice(total_pixels, chosen, replace=False))
        if pixels is not None:
            pixels = np.asarray(pixels, dtype=np.int64)
            if pixels.ndim != 1 or pixels.size == 0 or pixels.min() < 0 or pixels.max() >= total_pixels:
                raise ChainError("the chain's subsample names sphere pixels this capture does not have")
        self.pixels = pixels
        if pixels is None:
            self.used, self.factor = self.count, 1.0
            self._args: tuple = (_data(model, samples, np.arange(total_pixels)), None)
        else:
            data = _data(model, samples, pixels)
            self.used = int(np.asarray(data[2]).sum())
            if self.used == 0:
                raise CaptureError("the likelihood's subsample has no usable value: sample with --values all")
            self.factor = self.count / self.used
            x = jnp.asarray(self.x_hat)
            r_hat, jac, _, _, _, curvature = _expansion(model, params, x, data)
            # the full data's second-order expansion, less the subsample's estimate of its
            # misfit-curvature part (which the subsample's own r² brings back)
            matrix = self.information + self.curvature - self.factor * curvature
            self._args = (
                data,
                None,
                x,
                jnp.asarray(self.rss),
                jnp.asarray(self.gradient),
                jnp.asarray(matrix),
                r_hat,
                jac,
                jnp.asarray(self.factor),
            )
        self._value, self._batch = _functions(model, params, pixels is not None)
        self._set_sigma(self.sigma)
        return self

    def _set_sigma(self, sigma: float) -> None:
        self.sigma = check_sigma(float(sigma), "--sigma")
        self._args = (self._args[0], jnp.asarray(-0.5 / self.sigma**2), *self._args[2:])
        self._bounds = (jnp.asarray(self.prior.lower), jnp.asarray(self.prior.upper))

    def tempered(self, factor: float) -> CapturePosterior:
        """The same posterior with σ√``factor`` (``--adjust temperature``)."""
        out = copy.copy(self)
        out._set_sigma(self.sigma * math.sqrt(factor))
        return out

    @property
    def labels(self) -> list[str]:
        return list(self.prior.labels)

    @property
    def subsampled(self) -> bool:
        return self.pixels is not None

    @uses_float64
    def __call__(self, xs: np.ndarray) -> np.ndarray:
        xs = np.asarray(xs, dtype=np.float64)
        if xs.ndim == 1:
            return self(xs[None])[0]
        return np.asarray(self._batch(self._args, *self._bounds, xs), dtype=np.float64)

    def laplace_covariance(self) -> np.ndarray:
        """σ² B⁺, B = JᵀJ of the full data, over every entry (those the fit put on a bound
        too: the walkers need a scale for them): the fit's Laplace covariance."""
        return _laplace.covariance(self.information, self.sigma**2)

    @uses_float64
    def curvature_covariance(self, free: np.ndarray) -> np.ndarray:
        """(−∇² log L)⁺ at θ̂ over the ``free`` entries (0 rows and columns elsewhere): the
        covariance this posterior has near θ̂ with the others held, σ²H⁻¹ with H the
        Hessian of ½ the likelihood's RSS (the misfit's curvature included)."""
        free = np.asarray(free, dtype=bool)
        out = np.zeros((free.size, free.size))
        if free.any():
            hessian = np.asarray(jax.hessian(lambda x: self._value(self._args, x))(jnp.asarray(self.x_hat)))
            out[np.ix_(free, free)] = _laplace.covariance(-hessian[np.ix_(free, free)])
        return out

    def describe(self) -> dict[str, Any]:
        """The likelihood as the chain's metadata records it."""
        if self.subsampled:
            method = (
                f"a fixed random subsample of {self.pixels.size} sphere pixels in every image ({self.used} of the "
                f"{self.count} usable values), through the difference estimator: the full data's second-order "
                f"expansion about the fit plus N/n = {self.factor:.4g} times the subsample's remainder"
            )
        else:
            method = f"every usable value ({self.count}), exact"
        return {
            "method": method,
            "subsampled": self.subsampled,
            "values": self.count,
            "values_used": self.used,
            "scale": self.factor,
            "pixels": None if self.pixels is None else [int(p) for p in self.pixels],
            "rss": self.rss,
        }


# --- the chain and its summary -----------------------------------------------------------------


def is_capture_chain(meta: dict[str, Any]) -> bool:
    """Whether a chain's metadata is a capture's (`sample_capture`)."""
    return isinstance(meta, dict) and meta.get("kind") == KIND


def check_capture_chain(meta: dict[str, Any], path: str | Path) -> dict[str, Any]:
    """``meta``, a capture's chain's metadata (of the chain file ``path``), or a one-line
    `ChainError` when what only a capture's chain holds
    (beside what `strauss_fit.inference.sampler.read_metadata` checks) is damaged."""

    def damaged(what: str) -> ChainError:
        return ChainError(f"chain file {path}: its strauss-fit metadata is damaged ({what})")

    size = len(meta.get("labels") or [])
    x_hat = meta.get("x_hat")
    if not (
        isinstance(x_hat, list)
        and len(x_hat) == size
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in x_hat)
    ):
        raise damaged(f"'x_hat' must be {size} finite numbers, one per label")
    for key, kind, what in (
        ("adjustment", dict, "an object"),
        ("likelihood", dict, "an object"),
        ("fit_base", str, "text"),
        ("fit_path", str, "text"),
        ("at_bound", list, "a list"),
        ("laplace_covariance", list, "a list"),
    ):
        if meta.get(key) is not None and not isinstance(meta[key], kind):
            raise damaged(f"'{key}' must be {what}")
    try:
        np.asarray(meta.get("laplace_covariance") or [], dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise damaged("'laplace_covariance' must be a matrix of numbers") from None
    return meta


def reload_chain_capture(meta: dict[str, Any], capture: Capture | None = None) -> tuple[CaptureSamples, Any]:
    """The capture's samples and fit (`strauss_fit.fitting.capture_result.reload_capture_fit`)
    that a capture's chain was sampled from, from its metadata (the fit result it holds, the
    capture paths relative to ``fit_base``), unless ``capture`` is given."""
    if not is_capture_chain(meta):
        raise ChainError("not a capture's chain (its metadata has no kind 'capture')")
    return reload_capture_fit(meta["fit"], base=meta.get("fit_base"), capture=capture)


def _at_bound(params: Sequence[_Param], labels: Sequence[str], x: np.ndarray) -> list[str]:
    lower, upper = natural_range(params)
    return [label for label, v, lo, hi in zip(labels, x, lower, upper) if v <= lo or v >= hi]


def _flat(result: dict[str, Any], values: dict[str, Any] | None, size: int) -> np.ndarray | None:
    """A result's per-name values (``uncertainty`` and the like) as one vector in label order."""
    if not isinstance(values, dict):
        return None
    out = []
    for name in result.get("free", []):
        v = values.get(name, 0.0)
        out += [float(x) for x in v] if isinstance(v, list) else [float(v)]
    return np.asarray(out, dtype=np.float64) if len(out) == size else None


def _fit_laplace(meta: dict[str, Any], labels: list[str]) -> Laplace:
    """The ± the chain is set against: the fit's image-cluster sandwich when the chain is
    adjusted to it; otherwise the Laplace covariance σ²(JᵀJ)⁻¹ at the chain's σ, which the
    chain's Gaussian likelihood has near θ̂ — the fit's Laplace ± without the share of the
    sphere's circle, which the fit adds to it and the chain, conditional on the circle,
    does not have (0 for values the fit put on a bound, as the fit's ±)."""
    result = meta["fit"]
    size = len(labels)
    x_hat = np.asarray(meta["x_hat"], dtype=np.float64)
    at_bound = list(meta.get("at_bound", []))
    method = (meta.get("adjustment") or {}).get("method", "none")
    if method in ("affine", "temperature"):
        sd = _flat(result, result.get("uncertainty"), size)
        corr = np.asarray((result.get("correlation") or {}).get("matrix", np.eye(size)), dtype=np.float64)
        name = CLUSTER
    else:
        cov = np.asarray(meta.get("laplace_covariance", np.zeros((size, size))), dtype=np.float64)
        sd = np.where(np.isin(labels, at_bound), 0.0, _laplace.deviations(cov)) if cov.shape == (size, size) else None
        corr = _laplace.correlation(cov, fallback=np.eye(size)) if cov.shape == (size, size) else np.eye(size)
        name = LAPLACE
    if sd is None or corr.shape != (size, size):
        sd, corr = np.zeros(size), np.eye(size)
    return Laplace(labels, x_hat, sd, corr, at_bound, name)


#: The circle's share of the fit's ± is worth a warning above this fraction of the chain's ±
#: (it then widens the ± by more than 5 % in quadrature).
CIRCLE_SHARE = 0.3


def _circle_warning(meta: dict[str, Any], laplace: Laplace) -> str | None:
    """A warning when the fit's ± hold a sizeable share from the sphere's circle, which an
    unadjusted chain (conditional on the circle) leaves out."""
    if laplace.method != LAPLACE:
        return None  # adjusted to the image-cluster sandwich, which includes it
    result = meta["fit"]
    circle = _flat(result, result.get("uncertainty_circle"), len(laplace.labels))
    if circle is None:
        return None
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(laplace.sd > 0, circle / laplace.sd, 0.0)
    worst = int(np.argmax(ratio))
    if not ratio[worst] > CIRCLE_SHARE:
        return None
    where = describe(laplace.labels[worst])
    return (
        "the chain is conditional on where the sphere is (its circle as detected), but the fit's ± add the "
        f"circle's uncertainty, up to {ratio[worst]:.2g} times the chain's Laplace ± (in {where}, "
        f"±{circle[worst]:.2g} against ±{laplace.sd[worst]:.2g}): the posterior's intervals leave it out; the "
        "fit's ± carry it, and so do the draws of --adjust affine (mapped to the image-cluster sandwich)"
    )


def summarise_capture_chain(chain: Any) -> dict[str, Any]:
    """The summary JSON of a capture's chain, in the layout of
    `strauss_fit.inference.summaries.summarise_chain` (diagnostics, percentiles, the
    ± the chain is set against — the fit's image-cluster sandwich when the chain is adjusted
    to it, else the Laplace ± of the chain's likelihood (`_fit_laplace`) — their
    comparison, warnings), with ``kind``, ``likelihood``, the capture's paths and the fit's
    own ± (``fit_uncertainty``: image-cluster sandwich, Laplace, the circle's share) added."""
    meta = chain.meta
    result = meta["fit"]
    laplace = _fit_laplace(meta, chain.labels)
    posterior = chain_posterior(chain, laplace)
    diagnostics = posterior.diagnostics
    warnings = degeneracy_warnings(chain.labels, posterior.covariance, result.get("held") or {}, values=laplace.x_hat)
    circle = _circle_warning(meta, laplace)
    if circle:
        warnings.insert(0, circle)
    residual = result.get("residual") or {}
    return {
        "kind": KIND,
        "uncertainty_method": laplace.method,
        "fit_verdict": residual.get("verdict"),
        "fit_warnings": [dict(w) for w in result.get("warnings", []) if isinstance(w, dict)],
        "adjustment": adjustment_summary(chain, laplace, diagnostics.burn_in),
        "chain": chain.path,
        "fit_path": meta.get("fit_path"),
        "capture": result.get("capture"),
        "model": result.get("model"),
        "labels": chain.labels,
        "sigma": meta["sigma"],
        "sigma_source": meta.get("sigma_source"),
        "likelihood": {k: v for k, v in (meta.get("likelihood") or {}).items() if k != "pixels"},
        "prior": meta["prior"],
        "walkers": diagnostics.walkers,
        "steps": diagnostics.steps,
        "diagnostics": diagnostics.as_dict(),
        "posterior": posterior.summary,
        "laplace": {
            "labels": laplace.labels,
            "x_hat": laplace.x_hat.tolist(),
            "sd": laplace.sd.tolist(),
            "correlation": laplace.correlation.tolist(),
        },
        "fit_uncertainty": {
            CLUSTER: result.get("uncertainty"),
            "laplace": result.get("uncertainty_laplace"),
            "circle": result.get("uncertainty_circle"),
        },
        "comparison": {"rows": [r.as_dict() for r in posterior.rows], "notes": posterior.notes},
        "warnings": warnings,
    }


def capture_chain_summary(chain: Any) -> dict[str, Any]:
    """Per label of a capture's chain (a `strauss_fit.inference.sampler.Chain`):
    the posterior ``mean``, ``sd``, ``median`` and the 16/84 % (``p16``, ``p84``) and
    2.5/97.5 % (``p2.5``, ``p97.5``) percentiles of the draws after burn-in (mapped by the
    chain's adjustment, if any), under ``parameters``; with ``labels``, ``count`` (draws),
    ``burn_in``, ``adjustment`` (the method), σ and the likelihood (for a report)."""
    discard = burn_in(autocorrelation_times(chain.chain), chain.chain.shape[0])
    out = posterior_summary(chain.samples(discard), chain.labels)
    out["burn_in"] = int(discard)
    out["adjustment"] = chain.adjustment.get("method", "none")
    out["sigma"] = chain.meta.get("sigma")
    out["likelihood"] = (chain.meta.get("likelihood") or {}).get("method")
    return out


# --- the whole workflow -----------------------------------------------------------------------


def _adjustment(
    adjust: str, result: dict[str, Any], labels: list[str], clustered: np.ndarray
) -> tuple[str, str, np.ndarray]:
    """The adjustment to make, why, and the capture's image-cluster sandwich V."""
    verdict = (result.get("residual") or {}).get("verdict")
    circle_led = _circle_dominated(result)
    if adjust == "auto":
        if verdict == "mismatch":
            method = "affine"
            reason = (
                "the model cannot reproduce the capture (verdict 'mismatch'): the chain is mapped to the fit's "
                "image-cluster sandwich, the spread of the fitted values over other photographs of this kind"
            )
        elif circle_led:
            method = "affine"
            reason = (
                f"where the sphere is, is uncertain enough to matter ({circle_led}): the chain, which takes the circle "
                "as detected, is mapped to the fit's image-cluster sandwich, which includes the circle's share"
            )
        else:
            method = "none"
            reason = (
                f"the fit's verdict is '{verdict}': the chain is the Gaussian likelihood's posterior, set against "
                "its Laplace ± sigma^2 (J^T J)^-1"
            )
    elif adjust == "none":
        method, reason = "none", "--adjust none"
    else:
        method, reason = adjust, f"--adjust {adjust}: to the fit's image-cluster sandwich"
    if method != "none" and not (np.all(np.isfinite(clustered)) and np.any(np.diag(clustered) > 0)):
        raise ChainError("the fit's image-cluster sandwich has no finite, positive variance to adjust the chain to")
    if method == "affine":  # the map needs V positive definite: found out now, not after sampling
        use = adjusted_entries(clustered)
        part = clustered[np.ix_(use, use)]
        try:
            np.linalg.cholesky((part + part.T) / 2)
        except np.linalg.LinAlgError:
            raise ChainError(
                "the fit's image-cluster sandwich is singular (values that trade off exactly, correlation ±1): the "
                "affine adjustment cannot map the chain to it; give --adjust temperature or --adjust none"
            ) from None
    return method, reason, clustered


def _circle_dominated(result: dict[str, Any]) -> str:
    """The values whose circle share exceeds `CIRCLE_SHARE` of the likelihood's own
    Laplace ± (the result's Laplace ± without the circle's share), as text; "" if none."""
    circle, laplace = result.get("uncertainty_circle"), result.get("uncertainty_laplace")
    if not isinstance(circle, dict) or not isinstance(laplace, dict):
        return ""
    named = []
    for name, share in circle.items():
        total = laplace.get(name)
        if share is None or total is None:
            continue
        try:
            share_a, total_a = np.atleast_1d(np.asarray(share, float)), np.atleast_1d(np.asarray(total, float))
        except (TypeError, ValueError, OverflowError):  # a damaged result: no share to name
            continue
        if share_a.shape != total_a.shape:
            continue
        own = np.sqrt(np.maximum(total_a**2 - share_a**2, 0.0))
        if np.any(share_a > CIRCLE_SHARE * np.maximum(own, 1e-300)):
            named.append(name)
    return ", ".join(named)


def _read_result(fit: str | Path | dict[str, Any]) -> tuple[dict[str, Any], str | None, str | None]:
    if isinstance(fit, dict):
        return fit, None, None
    result = read_json(fit, "fit result")
    if not is_capture_result(result):
        raise ChainError(f"{fit} is not a capture's fit result (strauss-fit fit --capture)")
    path = Path(fit).resolve()
    return result, str(path), str(path.parent)


def _check_request(out: Path, adjust: str, values: int | None) -> Path:
    """Where the summary of the chain file ``out`` goes (beside it, with the suffix
    ``.json``), after checking the requested adjustment and subsample."""
    summary_path = out.with_suffix(".json")
    if summary_path == out:
        raise ChainError(f"the chain file needs an extension other than .json (the summary goes to {summary_path})")
    if adjust not in ADJUST_METHODS:
        raise ChainError(f"unknown adjustment {adjust!r}; expected one of {', '.join(ADJUST_METHODS)}")
    if values is not None and values < 1:
        raise ChainError(f"the likelihood's subsample needs at least one value, got {values}")
    return summary_path


def _resumed_capture(
    out: Path, summary_path: Path, adjust: str, capture: Capture | None, log: Callable[[str], None]
) -> tuple[CapturePosterior, dict[str, Any]]:
    """The likelihood and the metadata of the capture's chain in ``out`` to continue, once
    the chain, the photographs (read again from what it records, unless ``capture``) and
    the adjustment are checked to be the ones it was started with; its σ, prior and
    subsample are kept."""
    existing = load_chain(out, required=True)
    meta = existing.meta
    if not is_capture_chain(meta):
        raise ChainError(f"{out} is a chain of a single image's fit, not of a capture's")
    check_capture_chain(meta, out)
    check_writable(summary_path, True)
    kept = (meta.get("adjustment") or {}).get("method", "none")
    if adjust != "auto" and adjust != kept:
        raise ChainError(f"--adjust cannot change when resuming: {out} was started with --adjust {kept}")
    log("reading the capture again")
    samples, fitted = reload_chain_capture(meta, capture)
    if data_digest(samples) != meta.get("data_sha256"):
        raise ChainError(f"{out} was sampled for other photographs (the capture's usable values differ)")
    if fitted.labels != meta["labels"]:
        raise ChainError(f"{out} samples {', '.join(meta['labels'])}, not {', '.join(fitted.labels)}")
    labels = meta["labels"]
    prior = Prior(
        tuple(labels),
        np.array([meta["prior"][k][0] for k in labels]),
        np.array([meta["prior"][k][1] for k in labels]),
    )
    likelihood = meta.get("likelihood") or {}
    log("setting up the likelihood")
    posterior = CapturePosterior.build(
        samples,
        fitted.model,
        fitted.params,
        np.asarray(meta["x_hat"], dtype=np.float64),
        prior,
        float(meta["sigma"]),
        values=None,
        pixels=likelihood.get("pixels"),
    )
    log(f"resuming {out} at step {len(existing.chain)}")
    return posterior, meta


def _fit_to_start_from(
    fit: str | Path | dict[str, Any] | None, base: str | Path | None
) -> tuple[dict[str, Any], str | None, str | None]:
    """The capture's fit result a new chain starts from (refused unless it is one, and
    JSON-clean: the chain's metadata keeps it), where it was read from, and the folder its
    capture paths are relative to (``base`` when given)."""
    result, fit_path, fit_base = _read_result(fit) if fit is not None else (None, None, None)
    if result is None or not is_capture_result(result):
        raise ChainError("not a capture's fit result (strauss-fit fit --capture)")
    try:  # the chain's metadata keeps it, as JSON
        json.dumps(result, allow_nan=False)
    except (TypeError, ValueError):
        named = f" {fit_path}" if fit_path else ""
        raise ChainError(
            f"the fit result{named} is damaged: it holds NaN or infinity, which JSON does not allow"
        ) from None
    if base is not None:
        fit_base = str(Path(base).resolve())
    return result, fit_path, fit_base


def _tempered(
    posterior: CapturePosterior,
    target_covariance: np.ndarray,
    labels: list[str],
    at_bound: list[str],
    log: Callable[[str], None],
) -> tuple[CapturePosterior, float]:
    """The likelihood widened to the fit's sandwich (σ√T) and T, computed over the entries
    V covers that are not at a bound."""
    use = adjusted_entries(target_covariance) & ~np.isin(labels, at_bound)
    post = posterior.curvature_covariance(use)
    try:
        factor = temperature(post[np.ix_(use, use)], target_covariance[np.ix_(use, use)])
    except AdjustmentError as exc:
        raise ChainError(f"cannot temper the likelihood: {exc}") from None
    untempered = posterior.sigma
    root = float(np.sqrt(factor))
    log(f"tempering the likelihood: sigma x sqrt(T) = {untempered:.3g} x {root:.3g} (T = {factor:.3g})")
    return posterior.tempered(factor), factor


def _new_capture_chain(
    result: dict[str, Any],
    fit_path: str | None,
    fit_base: str | None,
    *,
    capture: Capture | None,
    sigma: float | None,
    priors: dict[str, tuple[float, float]] | None,
    settings: SampleSettings,
    values: int | None,
    adjust: str,
    quality: str,
    log: Callable[[str], None],
) -> tuple[CapturePosterior, np.ndarray, dict[str, Any]]:
    """A new chain's likelihood, its walkers' starting points and its metadata, from the
    capture's fit result (the capture read again from what it records, unless
    ``capture``)."""
    log("reading the capture")
    samples, fitted = reload_capture_fit(result, base=fit_base, capture=capture)
    x_hat = np.asarray(fitted.physical, dtype=np.float64)
    labels = list(fitted.labels)
    method, reason, target_covariance = _adjustment(adjust, result, labels, fitted.clustered)
    prior = capture_prior(fitted.params, labels, x_hat, priors)
    ndim = len(labels)
    walkers = settings.walkers or default_walkers(ndim)
    if walkers < 2 * ndim:
        raise ChainError(f"--walkers must be at least twice the number of parameters ({2 * ndim}), got {walkers}")
    log("setting up the likelihood (the full data's Jacobian at the fit)")
    posterior = CapturePosterior.build(
        samples, fitted.model, fitted.params, x_hat, prior, sigma, values=values, seed=settings.seed
    )
    sigma_source = posterior.sigma_source
    covariance = posterior.laplace_covariance()
    at_bound = _at_bound(fitted.params, labels, x_hat)
    adjustment: dict[str, Any] = {"method": method, "reason": reason}
    if method != "none":
        adjustment.update(target_covariance=target_covariance.tolist(), center=[float(v) for v in x_hat])
    if method == "temperature":
        untempered = posterior.sigma
        posterior, factor = _tempered(posterior, target_covariance, labels, at_bound, log)
        adjustment.update(temperature=factor, sigma_untempered=untempered)
        covariance = covariance * factor
        sigma_source += f", tempered by sqrt(T) = {np.sqrt(factor):.3g} (--adjust temperature)"
    description = posterior.describe()
    log(f"likelihood: {description['method']}")
    log("compiling the log-probability and placing the walkers")
    start = initial_walkers(x_hat, covariance, prior, walkers, np.random.default_rng(settings.seed), posterior)
    meta = {
        "kind": KIND,
        "fit": result,
        "fit_path": fit_path,
        "fit_base": fit_base,
        "data_sha256": data_digest(samples),
        "sigma": posterior.sigma,
        "sigma_source": sigma_source,
        "prior": prior.as_dict(),
        "x_hat": [float(v) for v in x_hat],
        "at_bound": at_bound,
        "seed": settings.seed,
        "laplace_covariance": covariance.tolist(),
        "likelihood": description,
        "values_used": posterior.count,
        "quality": quality,
        "adjustment": adjustment,
    }
    return posterior, start, meta


@uses_float64
def sample_capture(
    fit: str | Path | dict[str, Any] | None,
    output: str | Path,
    *,
    sigma: float | None = None,
    priors: dict[str, tuple[float, float]] | None = None,
    settings: SampleSettings = SampleSettings(),
    values: int | None = DEFAULT_VALUES,
    adjust: str = "auto",
    quality: str = DEFAULT_QUALITY,
    capture: Capture | None = None,
    base: str | Path | None = None,
    force: bool = False,
    resume: bool = False,
    log: Callable[[str], None] | None = None,
    progress: Callable[[Progress], None] | None = None,
) -> SampleResult:
    """Sample the posterior of a capture's material (the module docstring) into the chain
    file ``output``, and write its summary (`summarise_capture_chain`) beside it
    (``output`` with the suffix ``.json``), as `strauss_fit.inference.sampler.sample`
    does for a single image.

    ``fit``: the capture's fit result (``strauss-fit fit --capture``'s JSON, its path or the
    parsed dict; it must be a least-squares fit, which a capture's always is). The capture
    is read again from the paths it records (as written, else relative to the result's
    folder, or to ``base`` for a dict), unless ``capture`` is given. ``sigma``: the noise
    level (None: estimated from the fit's residual). ``priors`` narrows the prior box.
    ``values``: the likelihood's subsample in values (None: every value). ``adjust``:
    ``"auto"``, ``"affine"``, ``"temperature"`` or ``"none"`` (module docstring).
    ``resume`` continues the chain in ``output`` (``fit`` is then ignored: the chain's
    own is used, with its σ, prior, subsample and adjustment); otherwise an existing
    ``output`` is refused unless ``force``. ``log`` receives status lines, ``progress``
    a `strauss_fit.inference.sampler.Progress` after every check; Ctrl-C raises
    `strauss_fit.inference.sampler.SamplingInterrupted` after every step so far is
    written."""
    log = log or (lambda message: None)
    out = Path(output)
    summary_path = _check_request(out, adjust, values)
    if resume:
        posterior, meta = _resumed_capture(out, summary_path, adjust, capture, log)
        start = None
    else:
        check_writable(out, force)
        check_writable(summary_path, force)
        result, fit_path, fit_base = _fit_to_start_from(fit, base)
        posterior, start, meta = _new_capture_chain(
            result,
            fit_path,
            fit_base,
            capture=capture,
            sigma=sigma,
            priors=priors,
            settings=settings,
            values=values,
            adjust=adjust,
            quality=quality,
            log=log,
        )
    return run_and_summarise(
        posterior, out, summary_path, summarise_capture_chain, start=start, settings=settings, metadata=meta,
        resume=resume, progress=progress,
    )  # fmt: skip
