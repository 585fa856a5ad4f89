"""Additive white noise per channel, from the image itself: `estimate_noise` (the
method is in its docstring) and its result, `NoiseEstimate`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from ._calibration import _CALIBRATION, _CHECK_SD_FACTOR, _SE_FACTOR
from ._errors import NoiseEstimationError
from ._highpass import KERNELS, _box_levels, _correlate_valid, _flat_channels, _valid_positions, kernel_kappa
from ._inputs import MIN_PIXELS, Inputs, prepare
from ._robust import _channel_correlation, _Robust, _robust_scale, _truncated_variance_factor


@dataclass
class NoiseEstimate:
    """Per-channel standard deviation of additive white noise, estimated from the image.

    ``sigma`` (C,): the estimate (image content leaking through the kernel included).
    ``stderr`` (C,): its standard error from the noise alone (not the content bias).
    ``n_pixels``: residual positions used (after erosion, clipping and dilation).
    ``n_candidates``: positions whose footprint lay inside the eroded usable mask.
    ``sigma_check`` (C,): the same estimate through the third-difference kernel.
    ``resolved`` (C,): True when both kernels agree, i.e. the noise and not the image
    content sets ``sigma``; False means ``sigma`` is only an upper bound on the noise
    (e.g. a noise-free rendering: the value is the content floor).
    """

    sigma: np.ndarray
    stderr: np.ndarray
    n_pixels: int
    n_candidates: int
    sigma_check: np.ndarray
    resolved: np.ndarray
    method: str
    details: dict = field(default_factory=dict)
    #: (h, w) residual positions used (top-left of the kernel footprint), for diagnostics
    used_positions: np.ndarray | None = field(default=None, repr=False)

    @property
    def relative_stderr(self) -> np.ndarray:
        return self.stderr / np.where(self.sigma > 0, self.sigma, np.nan)

    def to_dict(self) -> dict:
        return {
            "sigma": self.sigma.tolist(),
            "stderr": self.stderr.tolist(),
            "n_pixels": self.n_pixels,
            "n_candidates": self.n_candidates,
            "sigma_check": self.sigma_check.tolist(),
            "resolved": self.resolved.tolist(),
            "method": self.method,
            "details": self.details,
        }


@dataclass(frozen=True)
class _Cleaning:
    """How `estimate_noise` cleans a residual of content before it takes its scale
    (its arguments of the same names): the robust scale, the clip level in σ, the dilation
    of the clipped positions, the window test's half-width, and the censored code range
    with its margin in σ."""

    robust: str
    clip: float
    dilate: int
    window: int
    censor: tuple[float, float] | None = None
    censor_margin: float = 2.0


def _kernel_estimate(
    img: np.ndarray,
    usable: np.ndarray,
    kernel: str,
    cleaning: _Cleaning,
    sigma_hint: np.ndarray | None = None,
) -> tuple[np.ndarray | None, _Robust | None, np.ndarray | None]:
    """Calibrated scale through one kernel. ``cleaning.censor`` = (low, high): values are
    clipped to this range by the encoding (8-bit: (0, 1)); positions whose local level lies
    within ``censor_margin``·σ of either end are left out (the noise there is truncated: at
    2σ 2.3 % of the values are clipped), σ iterated twice, from ``sigma_hint`` when given."""
    robust, clip, dilate, window = cleaning.robust, cleaning.clip, cleaning.dilate, cleaning.window
    censor, censor_margin = cleaning.censor, cleaning.censor_margin
    k = KERNELS[kernel]
    valid = _valid_positions(usable, k.shape)
    if valid.size == 0 or valid.sum() == 0:
        return None, None, None
    res = _correlate_valid(img, k)
    kappa = kernel_kappa(k)
    calib = _CALIBRATION.get((kernel, robust, window), 1.0)
    rob = _robust_scale(res, valid, robust, clip, dilate, window=window, kappa=kappa)
    sigma = rob.sigma * calib if sigma_hint is None else sigma_hint
    if censor is not None:
        lo, hi = censor
        level = _box_levels(img, k.shape)
        for _ in range(2):
            near = np.any((level < lo + censor_margin * sigma) | (level > hi - censor_margin * sigma), axis=-1)
            v = valid & ~near
            if v.sum() < 10:
                break
            rob = _robust_scale(res, v, robust, clip, dilate, window=window, kappa=kappa)
            rob.n_valid = int(valid.sum())
            sigma = rob.sigma * calib
    return rob.sigma * calib, rob, res


def _rank1_noise(cov: np.ndarray) -> np.ndarray:
    """Noise variances of a one-factor model cov = λλᵀ + diag(ψ) (3 channels, closed form):
    λ_i² = c_ij c_ik / c_jk. Content that has the same spatial pattern in every channel
    (a refracted or reflected pattern of two colours, a white highlight) is one factor."""
    C = cov.shape[0]
    if C != 3:
        return np.full(C, np.nan)
    lam2 = np.empty(3)
    for i, (j, k) in enumerate(((1, 2), (0, 2), (0, 1))):
        den = cov[j, k]
        lam2[i] = cov[i, j] * cov[i, k] / den if den != 0 else np.nan
    psi = np.diag(cov) - np.clip(lam2, 0.0, np.diag(cov))
    return np.sqrt(np.maximum(psi, 0.0))


#: The robust scales `estimate_noise` offers (see its ``robust``).
_ROBUST_SCALES = ("clipped", "mad", "mad_raw", "mean_abs")


def estimate_noise(
    image: np.ndarray,
    usable_mask: np.ndarray | None = None,
    *,
    kernel: str = "d2",
    robust: Literal["clipped", "mad", "mad_raw", "mean_abs"] = "clipped",
    clip: float = 3.5,
    dilate: int = 1,
    window: int = 3,
    margin: int = 1,
    censor: tuple[float, float] | None = None,
    censor_margin: float = 2.0,
    check: bool = True,
    check_tolerance: float = 3.0,
    check_rel: float = 0.05,
    correlation_z: float = 4.0,
    min_pixels: int = MIN_PIXELS,
) -> NoiseEstimate:
    """Per-channel standard deviation of additive white noise in ``image`` (H, W[, C]).

    ``usable_mask`` (H, W): pixels that may be used (e.g. the sphere, minus clipped
    pixels). It is eroded by ``margin`` pixels and a residual is used only where the
    kernel's whole footprint lies inside it. Non-finite values inside it are an error.
    ``censor=(0, 1)`` for 8-bit targets: leave out positions whose local level is within
    ``censor_margin``·σ of a code range end (noise truncated at code 0 or 255).
    ``robust="mad_raw"`` and ``"mean_abs"`` (Immerkær's original mean |r|) are the
    unclipped alternatives kept for comparison.

    ``resolved`` is False for a channel when (a) the d2 and d3 kernels disagree, or (b) its
    residual correlates with another channel's (|z| > ``correlation_z``): independent
    noise does not correlate across channels, image content does. Then ``sigma`` is an
    upper bound, and ``details["sigma_rank1"]`` a content-corrected guess (one-factor
    model of the channel covariance; validated only on two-colour patterns).

    Raises `NoiseEstimationError` when fewer than ``min_pixels`` residual positions
    are usable, or when the residual is identically zero (a constant image, or a noise-free
    image without any variation the kernel sees: its noise cannot be measured).

    Method. Residual: the image is correlated with a high-pass kernel K of unit L2 norm, so
    that for white noise of standard deviation σ the residual r = K ⋆ x has standard
    deviation σ too. The default kernel ("d2") is Immerkær's 3×3 operator, the tensor
    product of second differences, ``outer([1, -2, 1], [1, -2, 1]) / 6``: its response to
    smooth content is h⁴·∂⁴f/∂x²∂y² + O(h⁶) — it ignores anything that is at most linear in
    x or at most linear in y — so smooth curved shading leaves almost nothing. A 4×4 kernel
    of third differences ("d3", ``outer([1,-3,3,-1], [1,-3,3,-1]) / 20``) is computed as a
    check (below).

    Footprint: r is kept only where the whole kernel footprint lies inside the usable mask
    after an extra erosion by ``margin`` pixels (partly covered silhouette pixels, pixels
    next to clipped ones).

    Robust scale: start from MAD, s = median|r| / 0.6745 (r has zero mean). Then iterate to
    a fixed point:

    - flag positions where |r| > ``clip``·s in ANY channel (sharp highlights, the
      silhouette, edges of a pattern seen through the sphere give coherent runs of large
      residuals, in every channel at once) and dilate the flags by ``dilate`` positions
      (their weaker neighbours are contaminated too);
    - window test (``window`` > 0): flag positions where the mean of (r/s)² over the kept
      positions of the (2·window+1)² neighbourhood, channels pooled, exceeds
      1 + 4·√(κ/n_local) (κ = 2Σρ², ρ the residual's spatial autocorrelation): content
      below the clip level but spatially coherent (a moiré ring);
    - s = RMS of the remaining residuals divided by the variance factor of a normal
      truncated at clip·s.

    A constant (0.2–0.8 %, measured on pure Gaussian noise) removes the bias left by
    dropping the neighbours of clean outliers. The clipped RMS has 1.3× (vs the raw MAD) to
    1.6× (vs the clipped MAD) smaller variance, and unlike a median of |r| it does not
    collapse to 0 on discrete (8-bit) data where most residuals are 0.

    Standard error: SE = c·σ/√n, n the residual positions used and c measured on pure noise
    (c ≈ 1.47 for d2, larger than the i.i.d. 1/√2 because the residuals of overlapping
    footprints are correlated: σ from n positions is worth about n/4 independent values).

    Checks (``resolved``): two signatures of content, either makes a channel unresolved:

    - the kernels disagree: white noise gives the same σ through every unit-norm kernel,
      smooth content leaks much less through d3 than through d2 (tolerance
      ``check_tolerance`` times the SE of the difference, measured on pure noise, plus
      ``check_rel``);
    - the channels correlate: the sensor's noise is independent between R, G and B, while
      image content (a pattern, an edge, a highlight) appears in all channels at the same
      places. A correlation of the kept residuals beyond ``correlation_z`` standard errors
      (SE ≈ √(κ/2n)) flags both channels. This is what catches aliased patterns (a checker
      seen through glass at 64×64), which look like noise to any single-channel statistic.

    Unresolved: ``sigma`` is (for additive content) an upper bound; do not use it as a noise
    level. ``details["sigma_rank1"]`` holds a content-corrected guess from a one-factor
    model of the 3×3 channel covariance (experimental).

    8-bit targets: ``censor=(0, 1)`` leaves out positions whose local level (a box mean that
    is uncorrelated with the residual, so the selection does not bias it) is within
    ``censor_margin``·σ of code 0 or 255, where the noise is truncated.
    """
    inputs = prepare(image, usable_mask, margin=margin, kernel=kernel)
    if robust not in _ROBUST_SCALES:
        raise NoiseEstimationError(f"unknown robust scale {robust!r}")
    n_cand = _measurable_positions(inputs, margin, min_pixels)
    cleaning = _Cleaning(robust, clip, dilate, window, censor, censor_margin)
    sigma, rob, res = _kernel_estimate(inputs.image, inputs.usable, kernel, cleaning)
    if rob.n_kept < min_pixels:
        raise NoiseEstimationError(
            f"only {rob.n_kept} residual positions are left after rejecting content "
            f"(of {n_cand}); need at least {min_pixels}"
        )
    se = _SE_FACTOR.get((kernel, robust, window), 1.6) * sigma / np.sqrt(max(rob.n_kept, 1))
    C = inputs.image.shape[-1]
    sigma_check, kernels_agree, independent = np.full(C, np.nan), np.ones(C, bool), np.ones(C, bool)
    details = {
        "kernel": kernel,
        "robust": robust,
        "clip": clip,
        "dilate": dilate,
        "window": window,
        "margin": margin,
        "censor": censor,
        "iterations": rob.iterations,
        "rejected_fraction": 1.0 - rob.n_kept / max(rob.n_valid, 1),
        "window_rejected_fraction": rob.window_flagged / max(rob.n_valid, 1),
    }
    if check:
        sigma_check, kernels_agree, details["check_kernel"] = _kernels_agree(
            inputs, sigma, rob, cleaning, tolerance=check_tolerance, rel=check_rel, min_pixels=min_pixels
        )
        if C > 1 and np.all(sigma > 0):
            independent, correlation = _channels_independent(res, rob, inputs, cleaning, correlation_z)
            details.update(correlation)
    resolved = kernels_agree & independent
    details["kernels_agree"] = kernels_agree.tolist()
    details["channels_independent"] = independent.tolist()
    return NoiseEstimate(
        sigma=sigma,
        stderr=se,
        n_pixels=rob.n_kept,
        n_candidates=n_cand,
        sigma_check=sigma_check,
        resolved=resolved,
        method=f"{kernel}/{robust}/w{window}",
        details=details,
        used_positions=rob.kept,
    )


def _measurable_positions(inputs: Inputs, margin: int, min_pixels: int) -> int:
    """The residual positions whose kernel footprint lies inside the usable pixels, after
    checking that there are at least ``min_pixels`` of them and that the residual is not
    zero in any channel (a constant or linear image: no noise to measure).

    Raises `NoiseEstimationError` when either check fails."""
    img, usable, k = inputs.image, inputs.usable, inputs.kernel
    valid = _valid_positions(usable, k.shape) if usable.any() else np.zeros((0, 0), bool)
    n_cand = int(valid.sum())
    if n_cand < min_pixels:
        raise NoiseEstimationError(
            f"only {n_cand} pixel(s) have their whole {k.shape[0]}×{k.shape[1]} neighbourhood inside the usable "
            f"mask (eroded by {margin}); need at least {min_pixels}"
        )
    flat = _flat_channels(img, usable, _correlate_valid(img, k)[valid])
    if flat.any():
        zero = [int(c) for c in np.flatnonzero(flat)]
        raise NoiseEstimationError(
            f"the high-pass residual is identically zero in channel(s) {zero}: the image is constant (or "
            "linear) over the usable pixels, so its noise cannot be measured; give the noise level"
        )
    return n_cand


def _kernels_agree(
    inputs: Inputs,
    sigma: np.ndarray,
    rob: _Robust,
    cleaning: _Cleaning,
    *,
    tolerance: float,
    rel: float,
    min_pixels: int,
) -> tuple[np.ndarray, np.ndarray, str | None]:
    """The first check of `estimate_noise`: the same estimate through the other
    kernel (d3, or d2 when d3 made ``sigma``) must agree with ``sigma`` within
    ``tolerance`` SEs of the difference plus ``rel`` times σ (smooth content leaks much less
    through d3, white noise gives both the same σ), both cleaned by ``cleaning`` (the
    unclipped scales by the clipped one).

    Returns the other kernel's σ (NaN when it has too few positions), per channel whether
    they agree (all False then), and the other kernel's name (None then)."""
    C = inputs.image.shape[-1]
    other = "d3" if inputs.kernel_name != "d3" else "d2"
    checked = replace(cleaning, robust=cleaning.robust if cleaning.robust in ("clipped", "mad") else "clipped")
    hint = sigma if cleaning.censor else None
    s2, rob2, _ = _kernel_estimate(inputs.image, inputs.usable, other, checked, sigma_hint=hint)
    if s2 is None or rob2.n_kept < min_pixels:
        return np.full(C, np.nan), np.zeros(C, bool), None
    n = min(rob.n_kept, rob2.n_kept)
    sd = _CHECK_SD_FACTOR * np.maximum(sigma, s2) / np.sqrt(n)
    agree = (np.abs(s2 - sigma) <= tolerance * sd + rel * np.maximum(sigma, s2)) & (sigma > 0) & (s2 > 0)
    return s2, agree, other


def _channels_independent(
    res: np.ndarray,
    rob: _Robust,
    inputs: Inputs,
    cleaning: _Cleaning,
    correlation_z: float,
) -> tuple[np.ndarray, dict]:
    """The second check of `estimate_noise`: the kept residuals ``res`` must not
    correlate across channels beyond ``correlation_z`` standard errors (independent noise
    does not, image content does).

    Returns per channel whether it is independent of every other, and the details it
    adds: the correlation matrix, its z-scores and, when a channel is not independent, the
    one-factor guess of the noise (``sigma_rank1``, corrected for ``cleaning``'s clipping
    and calibration)."""
    robust, window = cleaning.robust, cleaning.window
    corr, z, cov = _channel_correlation(res, rob.kept, kernel_kappa(inputs.kernel))
    hit = np.abs(z) > correlation_z
    independent = ~np.any(hit, axis=1)
    entries: dict = {"channel_correlation": corr.tolist(), "channel_correlation_z": z.tolist()}
    if not independent.all():
        tf = _truncated_variance_factor(cleaning.clip) if robust == "clipped" else 1.0
        entries["sigma_rank1"] = (
            _rank1_noise(cov / tf) * _CALIBRATION.get((inputs.kernel_name, robust, window), 1.0)
        ).tolist()
    return independent, entries
