r"""Noise level of a target image that does not come from the model's own residual.

NumPy + SciPy only (no JAX): it runs on the target image before any model exists.
Four sources of a per-channel noise level:

1. :func:`estimate_noise` — the standard deviation of additive white noise, per channel,
   estimated from the image itself with a high-pass residual and a robust, iteratively
   clipped scale (see "Method" below). Returns a :class:`NoiseEstimate` with the number of
   pixels used, a standard error, and checks that say whether the noise (and not the image
   content) sets the value.
2. :func:`estimate_noise_model` — signal-dependent (Poisson–Gaussian) noise,
   Var[x] = a·x + b per channel (Foi et al. 2008 style), with a significance test of a.
3. :func:`noise_from_sensor` — the per-pixel σ of the project's synthetic sensor
   (Var = E/gain + read_noise²).
4. :func:`quantisation_sigma` — the per-pixel noise floor of 8-bit sRGB coding
   (bin width in linear units / √12), and :func:`combine_with_quantisation`.

:func:`mismatch_verdict` turns a fit's residual and a noise level into χ²/dof, its
expected spread and the decision. When the noise cannot be measured, :func:`noise_bound`
still bounds it from above (the local mean square of a second-difference residual: the
noise plus the signal's own curvature), and :func:`one_sided_verdict` tests a residual
against that bound: too large, or too structured, for any noise up to it.

Method (estimate_noise)
-----------------------
Residual. The image is correlated with a high-pass kernel K of unit L2 norm, so that for
white noise of standard deviation σ the residual r = K ⋆ x has standard deviation σ too.
The default kernel ("d2") is Immerkær's 3×3 operator, the tensor product of second
differences, ``outer([1, -2, 1], [1, -2, 1]) / 6``: its response to smooth content is
h⁴·∂⁴f/∂x²∂y² + O(h⁶) — it ignores anything that is at most linear in x or at most linear
in y — so smooth curved shading leaves almost nothing. A 4×4 kernel of third differences
("d3", ``outer([1,-3,3,-1], [1,-3,3,-1]) / 20``) is computed as a check (below).

Footprint. r is kept only where the whole kernel footprint lies inside the usable mask
after an extra erosion by ``margin`` pixels (partly covered silhouette pixels, pixels next
to clipped ones).

Robust scale. Start from MAD: s = median|r| / 0.6745 (r has zero mean). Then iterate to a
fixed point:

- flag positions where |r| > ``clip``·s in ANY channel (sharp highlights, the silhouette,
  edges of a pattern seen through the sphere give coherent runs of large residuals, in
  every channel at once) and dilate the flags by ``dilate`` positions (their weaker
  neighbours are contaminated too);
- window test (``window`` > 0): flag positions where the mean of (r/s)² over the kept
  positions of the (2·window+1)² neighbourhood, channels pooled, exceeds
  1 + 4·√(κ/n_local) (κ = 2Σρ², ρ the residual's spatial autocorrelation): content below
  the clip level but spatially coherent (a moiré ring);
- s = RMS of the remaining residuals divided by the variance factor of a normal truncated
  at clip·s.

A constant (:data:`_CALIBRATION_TABLE`, 0.2–0.8 %) removes the bias left by dropping the
neighbours of clean outliers; it was measured on pure Gaussian noise. The clipped RMS has
1.3× (vs the raw MAD) to 1.6× (vs the clipped MAD) smaller variance, and unlike a median
of |r| it does not collapse to 0 on discrete (8-bit) data where most residuals are 0.

Standard error. SE = c·σ/√n, n the residual positions used and c measured on pure noise
(:data:`_CALIBRATION_TABLE`; c ≈ 1.47 for d2, larger than the i.i.d. 1/√2 because the
residuals of overlapping footprints are correlated: σ from n positions is worth about
n/4 independent values).

Checks (``resolved``). Two signatures of content, either makes a channel unresolved:

- the kernels disagree: white noise gives the same σ through every unit-norm kernel,
  smooth content leaks much less through d3 than through d2 (tolerance ``check_tolerance``
  times the SE of the difference, measured on pure noise, plus ``check_rel``);
- the channels correlate: the sensor's noise is independent between R, G and B, while
  image content (a pattern, an edge, a highlight) appears in all channels at the same
  places. A correlation of the kept residuals beyond ``correlation_z`` standard errors
  (SE ≈ √(κ/2n)) flags both channels. This is what catches aliased patterns (a checker
  seen through glass at 64×64), which look like noise to any single-channel statistic.

Unresolved: ``sigma`` is (for additive content) an upper bound; do not use it as a noise
level. ``details["sigma_rank1"]`` holds a content-corrected guess from a one-factor model
of the 3×3 channel covariance (experimental).

8-bit targets. ``censor=(0, 1)`` leaves out positions whose local level (a box mean that
is uncorrelated with the residual, so the selection does not bias it) is within
``censor_margin``·σ of code 0 or 255, where the noise is truncated.
"""

from __future__ import annotations

import copy
import functools
import hashlib
import math
import threading
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from ..color import srgb_decode, srgb_encode
from ..errors import StraussFitError


class NoiseEstimationError(StraussFitError):
    """The noise level cannot be estimated from this input."""


# --------------------------------------------------------------------------------------
# kernels
# --------------------------------------------------------------------------------------


def _outer(v: list[float]) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    k = np.outer(v, v)
    return k / np.sqrt(np.sum(k * k))


#: High-pass kernels of unit L2 norm (white noise of σ gives residuals of σ).
KERNELS: dict[str, np.ndarray] = {
    # Immerkær (1996): tensor product of second differences (the default)
    "d2": _outer([1, -2, 1]),
    # tensor product of third differences (smooth content leaks less, footprint 4×4)
    "d3": _outer([1, -3, 3, -1]),
    # finest diagonal Haar sub-band (Donoho's HH), undecimated
    "haar": np.array([[1.0, -1.0], [-1.0, 1.0]]) / 2.0,
    # 5-point Laplacian
    "lap": np.array([[0.0, 1.0, 0.0], [1.0, -4.0, 1.0], [0.0, 1.0, 0.0]]) / np.sqrt(20.0),
}

#: (kernel, robust, window): (bias multiplier, SE factor), measured by ``calibrate.py`` on
#: 160 × 3 channels of 96×96 N(0, 1) noise inside a disk. The unclipped estimators
#: ("mad_raw", "mean_abs") are consistent by construction (1.0); the clipped ones lose
#: 0.2–0.8 % to the dilation around clean outliers. SE = factor·σ/√n_pixels: larger than the
#: i.i.d. MAD value 1.17 because residuals of overlapping footprints are correlated. The
#: factors carry ~3 % sampling error.
_CALIBRATION_TABLE: dict[tuple[str, str, int], tuple[float, float]] = {
    ("d2", "clipped", 0): (1.0058, 1.469),
    ("d2", "clipped", 3): (1.0059, 1.467),
    ("d2", "mad", 0): (1.0025, 1.773),
    ("d2", "mad", 3): (1.0026, 1.864),
    ("d3", "clipped", 0): (1.0077, 1.673),
    ("d3", "clipped", 3): (1.0082, 1.701),
    ("d3", "mad", 0): (1.0044, 2.118),
    ("d3", "mad", 3): (1.0036, 2.020),
    ("haar", "clipped", 0): (1.0037, 1.092),
    ("haar", "clipped", 3): (1.0036, 1.129),
    ("haar", "mad", 0): (1.0009, 1.523),
    ("haar", "mad", 3): (1.0024, 1.505),
    ("lap", "clipped", 0): (1.0025, 1.015),
    ("lap", "clipped", 3): (1.0016, 0.969),
    ("lap", "mad", 0): (1.0011, 1.349),
    ("lap", "mad", 3): (1.0014, 1.333),
    ("d2", "mad_raw", 0): (1.0000, 1.649),
    ("d3", "mad_raw", 0): (1.0000, 2.005),
    ("haar", "mad_raw", 0): (1.0000, 1.442),
    ("lap", "mad_raw", 0): (1.0000, 1.294),
    ("d2", "mean_abs", 0): (1.0000, 1.415),
}
_CALIBRATION: dict[tuple[str, str, int], float] = {}
_SE_FACTOR: dict[tuple[str, str, int], float] = {}
#: Standard deviation of (σ_d3 − σ_d2)·√n/σ on pure noise (default settings), for the check.
_CHECK_SD_FACTOR = 0.566


def _load_calibration() -> None:
    for key, (bias, se) in _CALIBRATION_TABLE.items():
        _CALIBRATION[key] = bias
        _SE_FACTOR[key] = se
        if key[1] in ("mad_raw", "mean_abs"):  # no clipping: the window is irrelevant
            _CALIBRATION[(key[0], key[1], 3)] = bias
            _SE_FACTOR[(key[0], key[1], 3)] = se


_load_calibration()


# --------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------


def _as_image(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image, dtype=np.float64)
    if img.ndim == 2:
        img = img[..., None]
    if img.ndim != 3:
        raise NoiseEstimationError(f"image must be (H, W) or (H, W, C), got shape {np.shape(image)}")
    return img


def _as_mask(mask: np.ndarray | None, shape: tuple[int, int]) -> np.ndarray:
    if mask is None:
        return np.ones(shape, dtype=bool)
    m = np.asarray(mask)
    if m.shape != shape:
        raise NoiseEstimationError(f"usable_mask has shape {m.shape} but the image is {shape}")
    return m.astype(bool)


def _check_finite(img: np.ndarray, usable: np.ndarray) -> None:
    bad = ~np.all(np.isfinite(img), axis=-1) & usable
    if bad.any():
        raise NoiseEstimationError(
            f"{int(bad.sum())} usable pixel(s) hold NaN or infinite values; mark them unusable or fix the image"
        )


def _erode(mask: np.ndarray, margin: int) -> np.ndarray:
    if margin <= 0:
        return mask
    from scipy import ndimage  # on first use: importing SciPy cost a command's start 1.5 s (2 cores, load 11)

    return ndimage.binary_erosion(mask, structure=np.ones((3, 3), bool), iterations=margin, border_value=0)


def _valid_positions(usable: np.ndarray, kshape: tuple[int, int]) -> np.ndarray:
    """Top-left positions (H-kh+1, W-kw+1) whose kh×kw footprint lies inside ``usable``."""
    kh, kw = kshape
    H, W = usable.shape
    if H < kh or W < kw:
        return np.zeros((max(H - kh + 1, 0), max(W - kw + 1, 0)), bool)
    c = np.cumsum(np.cumsum(np.pad(usable.astype(np.int64), ((1, 0), (1, 0))), 0), 1)
    s = c[kh:, kw:] - c[:-kh, kw:] - c[kh:, :-kw] + c[:-kh, :-kw]
    return s == kh * kw


def _correlate_valid(img: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Valid-mode correlation of every channel: (H-kh+1, W-kw+1, C)."""
    kh, kw = kernel.shape
    H, W, C = img.shape
    out = np.zeros((H - kh + 1, W - kw + 1, C))
    clean = np.where(np.isfinite(img), img, 0.0)
    for a in range(kh):
        for b in range(kw):
            if kernel[a, b] != 0:
                out += kernel[a, b] * clean[a : a + H - kh + 1, b : b + W - kw + 1]
    return out


def _truncated_variance_factor(k: float) -> float:
    """E[z² | |z| ≤ k] for z ~ N(0, 1)."""
    p = math.erf(k / math.sqrt(2.0))
    phi = math.exp(-0.5 * k * k) / math.sqrt(2 * math.pi)
    return 1.0 - 2.0 * k * phi / p


def _truncated_median_factor(k: float) -> float:
    """median(|z| given |z| ≤ k) for z ~ N(0, 1)."""
    from scipy import special  # on first use (see _erode)

    p = math.erf(k / math.sqrt(2.0))
    return math.sqrt(2.0) * special.erfinv(0.5 * p)


MAD_CONSTANT = 0.6744897501960817  # Φ⁻¹(3/4)


def _scale_once(r: np.ndarray, robust: str) -> np.ndarray:
    """Per-channel scale of the residual rows r (n, C), no clipping."""
    if robust == "mean_abs":
        return np.sqrt(np.pi / 2) * np.mean(np.abs(r), axis=0)
    s = np.median(np.abs(r), axis=0) / MAD_CONSTANT
    zero = s <= 0
    if zero.any():  # discrete data: more than half the residuals are exactly 0
        s = np.where(zero, np.sqrt(np.mean(r * r, axis=0)), s)
    return s


@dataclass
class _Robust:
    sigma: np.ndarray  # (C,)
    kept: np.ndarray  # bool positions
    n_valid: int
    n_kept: int
    iterations: int
    window_flagged: int = 0


def kernel_kappa(kernel: np.ndarray) -> float:
    """Var[mean of (r/σ)² over n positions] ≈ κ/n for white noise: κ = 2·Σ ρ(lag)², ρ the
    autocorrelation of the residual (overlapping footprints make neighbours correlated).
    d2: 7.56, d3: 10.67, haar: 4.5, lap: 3.38."""
    kernel = np.asarray(kernel, dtype=np.float64)
    return _kernel_kappa(kernel.shape, kernel.tobytes())


@functools.lru_cache(maxsize=32)
def _kernel_kappa(shape: tuple[int, int], data: bytes) -> float:
    kernel = np.frombuffer(data, dtype=np.float64).reshape(shape)
    kh, kw = kernel.shape
    padded = np.pad(kernel, ((kh - 1, kh - 1), (kw - 1, kw - 1)))
    ac = np.array(
        [[np.sum(kernel * padded[i : i + kh, j : j + kw]) for j in range(2 * kw - 1)] for i in range(2 * kh - 1)]
    )
    ac = ac / np.sum(kernel * kernel)
    return float(2.0 * np.sum(ac * ac))


def _robust_scale(
    res: np.ndarray,
    valid: np.ndarray,
    robust: str,
    clip: float,
    dilate: int,
    window: int = 0,
    window_k: float = 4.0,
    kappa: float = 7.6,
    max_iter: int = 30,
    tol: float = 1e-4,
) -> _Robust:
    """Iteratively clipped scale of residual images ``res`` (h, w, C) over ``valid`` (h, w).

    Two rejections, iterated to a fixed point with the scale s (C,):
    - position level: |r| > clip·s in any channel, dilated by ``dilate`` (sharp features);
    - window level (``window`` > 0): the mean of (r/s)² over the kept positions of the
      (2·window+1)² neighbourhood, all channels pooled, exceeds 1 + window_k·√(κ/n_local)
      (content that is below the clip level but spatially coherent: a moiré ring, a
      refracted pattern; also a noise level that varies across the image).
    """
    from scipy import ndimage  # on first use (see _erode)

    z = res
    rows = z[valid]
    n_valid = rows.shape[0]
    C = z.shape[-1]
    s = _scale_once(rows, "mad" if robust != "mean_abs" else "mean_abs")
    if robust in ("mad_raw", "mean_abs") or not np.all(s > 0):
        return _Robust(s, valid, n_valid, n_valid, 0)
    kept = valid
    it = 0
    tf = _truncated_variance_factor(clip)
    structure = np.ones((2 * dilate + 1, 2 * dilate + 1), bool) if dilate > 0 else None
    n_window_flagged = 0
    # what the iterations reuse: |r| and r² per channel, flattened positions × channels
    # (0 outside ``valid``, where nothing is read: no stray non-finite value enters a sum)
    magnitude = np.where(valid[..., None], np.abs(z), 0.0)
    square = (magnitude * magnitude).reshape(-1, C)
    for it in range(1, max_iter + 1):  # noqa: B007 (the count is returned)
        flagged = np.any(magnitude > clip * s, axis=-1) & valid
        if structure is not None and flagged.any():
            flagged = ndimage.binary_dilation(flagged, structure=structure)
        kept = valid & ~flagged
        if window > 0:
            size = 2 * window + 1
            # mean over channels of (r/s)², at the kept positions (0 elsewhere)
            q = np.where(kept, (square @ (1.0 / (s * s))).reshape(kept.shape) / (C * tf), 0.0)
            both = ndimage.uniform_filter(
                np.stack([kept.astype(np.float64), q]), size=(1, size, size), mode="constant"
            ) * (size * size)
            cnt, tot = both[0], both[1]
            local = tot / np.maximum(cnt, 1.0)
            n_local = np.maximum(cnt, 1.0) * C
            wflag = kept & (cnt >= size) & (local > 1.0 + window_k * np.sqrt(kappa / n_local))
            n_window_flagged = int(wflag.sum())
            kept = kept & ~wflag
        n_kept = int(np.count_nonzero(kept))
        if n_kept < 10:
            break
        if robust == "clipped":
            s_new = np.sqrt((kept.reshape(-1) @ square) / n_kept / tf)
        else:  # "mad": median of the kept |r|, corrected for the truncation
            rows = z[kept]
            s_new = np.median(np.abs(rows), axis=0) / _truncated_median_factor(clip)
            zero = s_new <= 0
            if zero.any():
                s_new = np.where(zero, np.sqrt(np.mean(rows * rows, axis=0) / tf), s_new)
        done = np.all(np.abs(s_new - s) <= tol * np.maximum(s, 1e-300))
        s = s_new
        if done or not np.all(s > 0):
            break
    return _Robust(s, kept, n_valid, int(kept.sum()), it, n_window_flagged)


# --------------------------------------------------------------------------------------
# additive noise, per channel
# --------------------------------------------------------------------------------------


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


def _box_levels(img: np.ndarray, kshape: tuple[int, int]) -> np.ndarray:
    """Mean of each residual position's footprint grown by one pixel on every side, per
    channel, on the residual grid. The box weight is constant over the footprint and the
    kernel sums to 0, so for white noise this level is uncorrelated with the residual:
    selecting positions by it does not bias the residual's scale."""
    kh, kw = kshape
    padded = np.pad(img, ((1, 1), (1, 1), (0, 0)), mode="edge")
    box = np.ones((kh + 2, kw + 2)) / ((kh + 2) * (kw + 2))
    return _correlate_valid(padded, box)


def _kernel_estimate(
    img: np.ndarray,
    usable: np.ndarray,
    kernel: str,
    robust: str,
    clip: float,
    dilate: int,
    window: int,
    censor: tuple[float, float] | None = None,
    sigma_hint: np.ndarray | None = None,
    censor_margin: float = 2.0,
) -> tuple[np.ndarray | None, _Robust | None, np.ndarray | None]:
    """Calibrated scale through one kernel. ``censor`` = (low, high): values are clipped to
    this range by the encoding (8-bit: (0, 1)); positions whose local level lies within
    ``censor_margin``·σ of either end are left out (the noise there is truncated: at 2σ
    2.3 % of the values are clipped), σ iterated twice."""
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


#: Fewest residual positions an estimate is made from.
MIN_PIXELS = 50


def _channel_correlation(res: np.ndarray, kept: np.ndarray, kappa: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Correlation matrix of the kept residuals across channels, its z-scores against
    independent noise (SE ≈ √(κ/2n): the residuals are spatially correlated) and the
    covariance matrix (truncation-corrected)."""
    r = res[kept]
    n = max(r.shape[0], 1)
    cov = r.T @ r / n
    sd = np.sqrt(np.maximum(np.diag(cov), 1e-300))
    corr = cov / np.outer(sd, sd)
    z = corr / np.sqrt(kappa / 2.0 / n)
    np.fill_diagonal(z, 0.0)
    return corr, z, cov


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
    See the module docstring for the method; ``robust="mad_raw"`` and ``"mean_abs"``
    (Immerkær's original mean |r|) are the unclipped alternatives kept for comparison.

    ``resolved`` is False for a channel when (a) the d2 and d3 kernels disagree, or (b) its
    residual correlates with another channel's (|z| > ``correlation_z``): independent
    noise does not correlate across channels, image content does. Then ``sigma`` is an
    upper bound, and ``details["sigma_rank1"]`` a content-corrected guess (one-factor
    model of the channel covariance; validated only on two-colour patterns).

    Raises :class:`NoiseEstimationError` when fewer than ``min_pixels`` residual positions
    are usable, or when the residual is identically zero (a constant image, or a noise-free
    image without any variation the kernel sees: its noise cannot be measured).
    """
    img = _as_image(image)
    H, W, C = img.shape
    usable = _as_mask(usable_mask, (H, W))
    _check_finite(img, usable)
    usable = _erode(usable & np.all(np.isfinite(img), axis=-1), margin)
    if kernel not in KERNELS:
        raise NoiseEstimationError(f"unknown kernel {kernel!r}; expected one of {', '.join(KERNELS)}")
    if robust not in ("clipped", "mad", "mad_raw", "mean_abs"):
        raise NoiseEstimationError(f"unknown robust scale {robust!r}")
    k = KERNELS[kernel]
    valid = _valid_positions(usable, k.shape) if usable.any() else np.zeros((0, 0), bool)
    n_cand = int(valid.sum())
    if n_cand < min_pixels:
        raise NoiseEstimationError(
            f"only {n_cand} pixel(s) have their whole {k.shape[0]}×{k.shape[1]} neighbourhood inside the usable "
            f"mask (eroded by {margin}); need at least {min_pixels}"
        )
    raw = _correlate_valid(img, k)[valid]
    scale = np.max(np.abs(img[usable]), axis=0)
    flat = np.max(np.abs(raw), axis=0) <= 1e-12 * np.maximum(scale, 1e-300)  # zero up to float rounding
    if flat.any():
        zero = [int(c) for c in np.flatnonzero(flat)]
        raise NoiseEstimationError(
            f"the high-pass residual is identically zero in channel(s) {zero}: the image is constant (or "
            "linear) over the usable pixels, so its noise cannot be measured; give the noise level"
        )
    sigma, rob, res = _kernel_estimate(
        img, usable, kernel, robust, clip, dilate, window, censor, censor_margin=censor_margin
    )
    if rob.n_kept < min_pixels:
        raise NoiseEstimationError(
            f"only {rob.n_kept} residual positions are left after rejecting content "
            f"(of {n_cand}); need at least {min_pixels}"
        )
    se = _SE_FACTOR.get((kernel, robust, window), 1.6) * sigma / np.sqrt(max(rob.n_kept, 1))
    sigma_check = np.full(C, np.nan)
    kernels_agree = np.ones(C, bool)
    independent = np.ones(C, bool)
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
        other = "d3" if kernel != "d3" else "d2"
        s2, rob2, _ = _kernel_estimate(
            img,
            usable,
            other,
            robust if robust in ("clipped", "mad") else "clipped",
            clip,
            dilate,
            window,
            censor,
            sigma_hint=sigma if censor else None,
            censor_margin=censor_margin,
        )
        if s2 is not None and rob2.n_kept >= min_pixels:
            sigma_check = s2
            n = min(rob.n_kept, rob2.n_kept)
            sd = _CHECK_SD_FACTOR * np.maximum(sigma, s2) / np.sqrt(n)
            kernels_agree = (
                (np.abs(s2 - sigma) <= check_tolerance * sd + check_rel * np.maximum(sigma, s2))
                & (sigma > 0)
                & (s2 > 0)
            )
            details["check_kernel"] = other
        else:
            kernels_agree = np.zeros(C, bool)
            details["check_kernel"] = None
        if C > 1 and np.all(sigma > 0):
            corr, z, cov = _channel_correlation(res, rob.kept, kernel_kappa(k))
            hit = np.abs(z) > correlation_z
            independent = ~np.any(hit, axis=1)
            details["channel_correlation"] = corr.tolist()
            details["channel_correlation_z"] = z.tolist()
            if not independent.all():
                tf = _truncated_variance_factor(clip) if robust == "clipped" else 1.0
                details["sigma_rank1"] = (
                    _rank1_noise(cov / tf) * _CALIBRATION.get((kernel, robust, window), 1.0)
                ).tolist()
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


# --------------------------------------------------------------------------------------
# signal-dependent noise: Poisson–Gaussian, Var = a·x + b
# --------------------------------------------------------------------------------------


@dataclass
class PoissonGaussian:
    """Per-channel Var[x] = a·x + b (a: shot-noise slope = 1/gain; b: read-noise variance).

    ``a``, ``b``, ``a_stderr``, ``b_stderr`` (C,). ``signal_dependent`` (C,): a is
    significantly > 0 (a / SE(a) > ``z``). ``bins`` holds, per channel, the binned
    (mean level, variance, SE of variance, count) the line was fitted to."""

    a: np.ndarray
    b: np.ndarray
    a_stderr: np.ndarray
    b_stderr: np.ndarray
    signal_dependent: np.ndarray
    chi2_dof: np.ndarray
    n_pixels: int
    channels_independent: np.ndarray | None = None
    bins: list = field(default_factory=list)

    def variance(self, values: np.ndarray) -> np.ndarray:
        """Var at the level ``values`` (…, C), the level clipped at 0."""
        v = np.maximum(np.asarray(values, dtype=np.float64), 0.0)
        return self.a * v + self.b

    def sigma_map(self, values: np.ndarray) -> np.ndarray:
        """Per-pixel σ at the level ``values`` (…, C): use the model render (or a smoothed
        target) as the level, not the noisy target, where possible."""
        return np.sqrt(self.variance(values))

    def to_dict(self) -> dict:
        return {
            "a": self.a.tolist(),
            "b": self.b.tolist(),
            "a_stderr": self.a_stderr.tolist(),
            "b_stderr": self.b_stderr.tolist(),
            "signal_dependent": self.signal_dependent.tolist(),
            "chi2_dof": self.chi2_dof.tolist(),
            "n_pixels": self.n_pixels,
            "channels_independent": None if self.channels_independent is None else self.channels_independent.tolist(),
        }


def _fit_line(x: np.ndarray, y: np.ndarray, se: np.ndarray) -> tuple[float, float, float, float, float]:
    r"""Weighted line y = a x + b with a, b ≥ 0. Returns a, b, se_a, se_b, chi2/dof.

    Solved in centred form: with :math:`\bar x = \sum w x / \sum w` and
    :math:`S = \sum w (x - \bar x)^2`, :math:`a = \sum w (x - \bar x) y / S`,
    :math:`b = \bar y - a \bar x`, :math:`\mathrm{var}\,a = 1/S` and
    :math:`\mathrm{var}\,b = 1/\sum w + \bar x^2/S`. Why not the inverse of the 2 × 2
    normal matrix: when one bin's error is tiny (a noise-free 8-bit image has a level bin
    whose variance is all quantisation: se ~ 1e-16, a weight 10¹⁴ times the others) that
    matrix is singular in float64 and its inverse had negative variances (a math domain
    error in the fit of a recovery target). S ≥ 0 by construction; S = 0 (one level) leaves
    the slope undetermined: a = 0 with an infinite error."""
    w = 1.0 / se**2
    total = np.sum(w)
    x_mean = np.sum(w * x) / total
    y_mean = np.sum(w * y) / total
    spread = float(np.sum(w * (x - x_mean) ** 2))
    if spread > 0:
        a = float(np.sum(w * (x - x_mean) * y) / spread)
        var_a = 1.0 / spread
    else:
        a, var_a = 0.0, math.inf
    b = float(y_mean - a * x_mean)
    var_b = 1.0 / total + (x_mean**2 * var_a if x_mean else 0.0)
    cov = np.array([[var_a, -x_mean * var_a], [-x_mean * var_a, var_b]])
    if a < 0 or b < 0:
        # one-parameter fits on the boundary; keep the better one that is admissible
        cands = []
        b0 = np.sum(w * y) / np.sum(w)  # a = 0
        if b0 >= 0:
            cands.append((np.sum(w * (y - b0) ** 2), 0.0, b0, 0.0, 1.0 / math.sqrt(np.sum(w))))
        a0 = np.sum(w * x * y) / np.sum(w * x * x)  # b = 0
        if a0 >= 0:
            cands.append((np.sum(w * (y - a0 * x) ** 2), a0, 0.0, 1.0 / math.sqrt(np.sum(w * x * x)), 0.0))
        if not cands:
            cands.append((np.sum(w * y * y), 0.0, 0.0, 0.0, 0.0))
        chi2, a, b, sa, sb = min(cands)
        # the SE of a parameter at its bound is still that of the unconstrained fit (for the test)
        sa = sa if sa > 0 else math.sqrt(cov[0, 0])
        sb = sb if sb > 0 else math.sqrt(cov[1, 1])
    else:
        sa, sb = math.sqrt(cov[0, 0]), math.sqrt(cov[1, 1])
        chi2 = np.sum(w * (y - a * x - b) ** 2)
    dof = max(len(x) - 2, 1)
    red = chi2 / dof
    if red > 1:  # the bins scatter more than noise: content leaks in; widen (Birge ratio)
        sa, sb = sa * math.sqrt(red), sb * math.sqrt(red)
    return float(a), float(b), float(sa), float(sb), float(red)


def _bin_variances(
    mu: np.ndarray, r: np.ndarray, qv: np.ndarray, idx: np.ndarray, bins: int, *, first: bool, factor: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per level bin (``idx``: each position's bin) with at least 30 positions: the mean
    level, the residuals' variance less the mean quantisation variance ``qv``, the count
    and the mean ``qv``. The variance is (MAD/0.6745)² on the ``first`` pass (no model
    yet, nothing clipped; the mean square where the MAD is 0), else the mean square
    times ``factor`` (the truncation and calibration of clipped residuals)."""
    counts = np.bincount(idx, minlength=bins)
    used = counts >= 30
    n = np.maximum(counts, 1)
    level = np.bincount(idx, weights=mu, minlength=bins) / n
    quantisation = np.bincount(idx, weights=qv, minlength=bins) / n
    mean_square = np.bincount(idx, weights=r * r, minlength=bins) / n
    if first:
        # each bin's median |r|: sorted by bin, then by |r|, the middle one (two) of each bin
        magnitude = np.abs(r)
        magnitude = magnitude[np.lexsort((magnitude, idx))]
        start = np.concatenate(([0], np.cumsum(counts)[:-1]))
        low, high = start + (n - 1) // 2, start + counts // 2
        median = (magnitude[np.minimum(low, len(r) - 1)] + magnitude[np.minimum(high, len(r) - 1)]) / 2
        variance = (median / MAD_CONSTANT) ** 2
        variance = np.where(variance > 0, variance, mean_square)
    else:
        variance = mean_square * factor
    return level[used], (variance - quantisation)[used], counts[used], quantisation[used]


#: Relative change of (a, b) between two clipped passes of :func:`estimate_noise_model`
#: below which the passes have reached their fixed point (the rest would repeat them).
FIXED_POINT = 1e-12


def estimate_noise_model(
    image: np.ndarray,
    usable_mask: np.ndarray | None = None,
    *,
    kernel: str = "d2",
    clip: float = 3.5,
    dilate: int = 1,
    window: int = 3,
    margin: int = 1,
    n_bins: int | None = None,
    min_per_bin: int = 300,
    z: float = 3.0,
    iterations: int = 4,
    quantisation: Literal[None, "srgb8"] = None,
    censor: tuple[float, float] | None = None,
    correlation_z: float = 4.0,
) -> PoissonGaussian:
    """Fit Var[x] = a·x + b per channel from the image itself (Foi et al. 2008 style).

    For every residual position: the high-pass residual r (unit-norm kernel K) and the
    level μ = Σ K²·x (the same weights the residual's variance is a mean over, so
    Var[r] = a·μ + b exactly for a smooth image). Positions are binned by μ (equal counts).
    First pass: each bin's variance from the MAD of its residuals (no clipping). Then,
    ``iterations`` times: the residuals are divided by the current model's σ(μ) and
    cleaned exactly as in :func:`estimate_noise` (clip, dilate, window test), so bright,
    noisier pixels are not rejected as content; each bin's variance is the truncated
    second moment of its kept residuals; a line is fitted by weighted least squares
    (weights from the model's predicted SE), a and b clamped ≥ 0. The passes stop early
    once one gives the a and b of the one before (:data:`FIXED_POINT`): each pass is a
    function of the previous a and b, so the rest would repeat it.

    ``signal_dependent``: a / SE(a) > ``z``. ``chi2_dof`` of the line fit (> 1: the bins
    scatter more than noise allows — content, or a noise that is not a·x + b; the SEs are
    then widened by √chi2_dof).

    ``quantisation="srgb8"``: subtract each bin's mean 8-bit quantisation variance
    (:func:`quantisation_sigma`) before the fit (sRGB-decoded 8-bit targets).
    ``censor=(0, 1)``: leave out positions whose local level is within 2σ(level) of an end
    of the code range (as in :func:`estimate_noise`). ``channels_independent``: the
    normalised residuals do not correlate across channels (|z| ≤ ``correlation_z``);
    False means image content leaks into the bins.
    """
    img = _as_image(image)
    H, W, C = img.shape
    usable = _as_mask(usable_mask, (H, W))
    _check_finite(img, usable)
    usable = _erode(usable & np.all(np.isfinite(img), axis=-1), margin)
    if kernel not in KERNELS:
        raise NoiseEstimationError(f"unknown kernel {kernel!r}; expected one of {', '.join(KERNELS)}")
    k = KERNELS[kernel]
    valid = _valid_positions(usable, k.shape)
    n_valid = int(valid.sum())
    if n_valid < 200:
        raise NoiseEstimationError(f"only {n_valid} usable residual positions; need at least 200 to fit a noise model")
    res = _correlate_valid(img, k)
    scale = np.max(np.abs(img[usable]), axis=0)
    if np.any(np.max(np.abs(res[valid]), axis=0) <= 1e-12 * np.maximum(scale, 1e-300)):
        raise NoiseEstimationError(
            "the high-pass residual is identically zero in a channel: the noise cannot be measured"
        )
    level = _correlate_valid(img, k * k)  # Σ K² x, weights sum to 1
    box = _box_levels(img, k.shape) if censor is not None else None
    if quantisation == "srgb8":
        qvar = _correlate_valid(quantisation_sigma(img) ** 2, k * k)
    elif quantisation is None:
        qvar = np.zeros_like(level)
    else:
        raise NoiseEstimationError(f"unknown quantisation {quantisation!r}; expected None or 'srgb8'")
    nb = n_bins or int(np.clip(n_valid // min_per_bin, 3, 20))
    se_factor = _SE_FACTOR.get((kernel, "clipped", window), 1.6)
    calib = _CALIBRATION.get((kernel, "clipped", window), 1.0)
    tf = _truncated_variance_factor(clip)
    kappa = kernel_kappa(k)

    a = np.zeros(C)
    b = np.zeros(C)
    out_bins: list = []
    stats = np.zeros((3, C))
    kept = valid
    last = None  # (a, b) of the previous clipped pass
    for it in range(iterations + 1):
        if it == 0:
            kept = valid
            scale = np.ones(C)
        else:
            sd = np.sqrt(np.maximum(a * np.maximum(level, 0) + b + qvar, 1e-300))
            v = valid
            if box is not None:
                v = valid & ~np.any((box < censor[0] + 2 * sd) | (box > censor[1] - 2 * sd), axis=-1)
                if v.sum() < 200:
                    raise NoiseEstimationError("fewer than 200 positions are far enough from the code range's ends")
            rob = _robust_scale(res / sd, v, "clipped", clip, dilate, window=window, kappa=kappa)
            kept = rob.kept
            scale = rob.sigma
        out_bins = []
        for c in range(C):
            mu = level[..., c][kept]
            rr = res[..., c][kept]
            qv = qvar[..., c][kept]
            edges = np.quantile(mu, np.linspace(0, 1, nb + 1))
            idx = np.clip(np.searchsorted(edges, mu, side="right") - 1, 0, nb - 1)
            xs, vs, ns, qs = _bin_variances(mu, rr, qv, idx, nb, first=it == 0, factor=calib**2 / tf)
            if len(xs) < 3:
                raise NoiseEstimationError("too few populated level bins to fit a noise model")
            # SE of each bin's variance: from the model's prediction once there is a model
            # (weights from the noisy bin values themselves would favour low-variance bins)
            total = np.maximum(a[c] * np.maximum(xs, 0) + b[c] + qs, 1e-300) if it else np.maximum(vs + qs, 1e-300)
            se_v = 2 * (se_factor if it else 1.7) * total / np.sqrt(ns)
            ac, bc, sa, sb, chi = _fit_line(xs, vs, se_v)
            a[c], b[c] = ac, bc
            stats[:, c] = sa, sb, chi
            out_bins.append(
                {
                    "level": xs.tolist(),
                    "variance": vs.tolist(),
                    "variance_se": se_v.tolist(),
                    "count": ns.tolist(),
                    "normalised_scale": float(scale[c]),
                }
            )
        if it >= 1:
            now = np.concatenate([a, b])
            if last is not None and np.all(np.abs(now - last) <= FIXED_POINT * np.maximum(np.abs(now), 1e-300)):
                break  # a fixed point: every further pass would repeat this one
            last = now
    sig = (a / np.where(stats[0] > 0, stats[0], np.inf)) > z
    independent = np.ones(C, bool)
    if C > 1:
        sd = np.sqrt(np.maximum(a * np.maximum(level, 0) + b + qvar, 1e-300))
        _, zc, _ = _channel_correlation(res / sd, kept, kappa)
        independent = ~np.any(np.abs(zc) > correlation_z, axis=1)
    return PoissonGaussian(
        a=a.copy(),
        b=b.copy(),
        a_stderr=stats[0].copy(),
        b_stderr=stats[1].copy(),
        signal_dependent=sig,
        chi2_dof=stats[2].copy(),
        n_pixels=int(kept.sum()),
        channels_independent=independent,
        bins=out_bins,
    )


# --------------------------------------------------------------------------------------
# sensor description
# --------------------------------------------------------------------------------------


def noise_from_sensor(
    values: np.ndarray,
    gain: float,
    read_noise: float,
    exposure: float = 1.0,
    *,
    values_are: Literal["recorded", "radiance"] = "recorded",
) -> np.ndarray:
    r"""Per-pixel σ of the project's synthetic sensor, in recorded units.

    Sensor: E = exposure·L, S = Poisson(gain·max(E, 0))/gain (gain 0: S = E),
    O = S + N(0, read_noise²), so Var[O] = max(E, 0)/gain + read_noise².

    ``values_are="recorded"``: ``values`` are the recorded image O (the target, or a model
    of it in the same units) and are the plug-in estimate of E (clipped at 0; exposure is
    already in them and is not used). ``"radiance"``: ``values`` are radiance L and
    E = exposure·L. With the noisy target as the plug-in, E[σ²] is still exact (Var is
    linear in E, clipping at 0 aside) but each pixel's σ is noisy; a model render or a
    smoothed target is a better plug-in.
    """
    if not (np.isfinite(gain) and gain >= 0):
        raise NoiseEstimationError(f"gain must be a finite number >= 0, got {gain!r}")
    if not (np.isfinite(read_noise) and read_noise >= 0):
        raise NoiseEstimationError(f"read_noise must be a finite number >= 0, got {read_noise!r}")
    if not (np.isfinite(exposure) and exposure > 0):
        raise NoiseEstimationError(f"exposure must be a finite number > 0, got {exposure!r}")
    v = np.asarray(values, dtype=np.float64)
    e = np.maximum(v * (exposure if values_are == "radiance" else 1.0), 0.0)
    var = (e / gain if gain > 0 else 0.0) + read_noise**2
    return np.sqrt(var) * np.ones_like(v)


# --------------------------------------------------------------------------------------
# 8-bit sRGB quantisation
# --------------------------------------------------------------------------------------


def quantisation_sigma(linear_values: np.ndarray, bits: int = 8) -> np.ndarray:
    """Per-value σ of the sRGB quantisation error, in linear units.

    The code k = round(255·encode(x)) covers the linear interval
    [decode((k − ½)/255), decode((k + ½)/255)] (clamped to [0, 1]); the rounding error is
    uniform over it (for a signal that varies, or noise, across codes), so
    σ_q = width/√12. At the level x this is ≈ decode'(encode(x))/(255·√12): from
    8.8e-5 below linear 0.0031 (slope 1/12.92) to 2.6e-3 at 1.0.
    """
    levels = 2**bits - 1
    k = np.round(srgb_encode(linear_values) * levels)
    lo = srgb_decode(np.clip((k - 0.5) / levels, 0.0, 1.0))
    hi = srgb_decode(np.clip((k + 0.5) / levels, 0.0, 1.0))
    return (hi - lo) / np.sqrt(12.0)


def combine_with_quantisation(
    sigma: np.ndarray | float,
    linear_values: np.ndarray,
    usable_mask: np.ndarray | None = None,
    *,
    sigma_from_image: bool = True,
) -> np.ndarray:
    """Per-pixel σ of an 8-bit sRGB target: noise and quantisation in quadrature.

    ``sigma`` (C,) or a per-pixel map: the noise level. When it was estimated from the
    8-bit image itself (``sigma_from_image``), it already includes the quantisation noise,
    pooled over the pixels it used; that pooled part (mean σ_q² over ``usable_mask``) is
    taken out first, σ_n² = max(σ² − ⟨σ_q²⟩, 0), and each pixel's own σ_q² added back.
    A given or sensor σ (``sigma_from_image=False``) is combined as σ² + σ_q²."""
    vals = np.asarray(linear_values, dtype=np.float64)
    sq = quantisation_sigma(vals)
    s2 = np.asarray(sigma, dtype=np.float64) ** 2
    if sigma_from_image:
        m = np.ones(vals.shape[:2], bool) if usable_mask is None else np.asarray(usable_mask, bool)
        pooled = np.mean(sq[m] ** 2, axis=0) if m.any() else 0.0
        s2 = np.maximum(s2 - pooled, 0.0)
    return np.sqrt(s2 + sq**2)


# --------------------------------------------------------------------------------------
# the verdict the fit draws from it
# --------------------------------------------------------------------------------------


@dataclass
class Verdict:
    """χ²/dof of a fit's residual against a known noise, with its expected spread."""

    chi2_dof: float
    dof: int
    expected_sd: float
    z: float
    consistent: bool
    per_channel: list = field(default_factory=list)


def mismatch_verdict(
    residual: np.ndarray,
    sigma: np.ndarray,
    usable: np.ndarray,
    n_params: int,
    *,
    sigma_rel_se: np.ndarray | float = 0.0,
    z_threshold: float = 3.0,
) -> Verdict:
    """χ²/dof = Σ (r/σ)² / (N − P) over the usable pixels and channels, against its expected
    spread: √(2/dof) from the noise alone, widened by the noise level's own uncertainty
    (a relative SE ε of σ is ≈ 2ε on σ², hence on χ²/dof; per-channel ε (C,) are taken as
    independent, each channel carrying 1/C of χ², a scalar ε as common to all channels).
    ``sigma``: (C,) or a per-pixel map (H, W, C). ``consistent`` when
    (χ²/dof − 1)/spread < ``z_threshold`` (one-sided: χ²/dof well below 1 means the noise
    level was over-estimated, which is reported by z but is not a model mismatch).
    ``per_channel``: the same per channel (chi2_dof, expected_sd, z)."""
    res = np.asarray(residual, np.float64)
    r = res[usable]
    s = np.broadcast_to(np.asarray(sigma, np.float64), res.shape)[usable]
    z2 = (r / s) ** 2
    if z2.ndim == 1:
        z2 = z2[:, None]
    n_rows, C = z2.shape
    dof = max(z2.size - n_params, 1)
    chi = float(z2.sum() / dof)
    eps = np.asarray(sigma_rel_se, np.float64)
    eps_c = np.broadcast_to(eps, (C,)) if eps.ndim else np.full(C, float(eps))
    sigma_part = 2 * float(eps) if eps.ndim == 0 else 2 * float(np.sqrt(np.sum(eps_c**2))) / C
    sd = math.sqrt(2.0 / dof + sigma_part**2)
    zval = (chi - 1.0) / sd
    per = []
    for c in range(C):
        dof_c = max(n_rows - n_params / C, 1.0)
        chi_c = float(z2[:, c].sum() / dof_c)
        sd_c = math.sqrt(2.0 / dof_c + (2 * float(eps_c[c])) ** 2)
        per.append({"chi2_dof": chi_c, "expected_sd": sd_c, "z": (chi_c - 1.0) / sd_c})
    return Verdict(chi, dof, sd, float(zval), bool(zval < z_threshold), per)


# --------------------------------------------------------------------------------------
# the largest noise an image can hold: a one-sided verdict when its noise is unknown
# --------------------------------------------------------------------------------------

#: Standard deviation, in pixels, of the Gaussian neighbourhood over which
#: :func:`noise_bound` averages the squared high-pass residual: about 4π·4² ≈ 200 positions
#: inside the sphere, narrow enough to follow a highlight or a reflection, wide enough
#: for a local mean square with a relative standard error of about √(κ/200) ≈ 0.19.
BOUND_WIDTH = 4.0
#: Standard errors of the local mean square added to it (an upper confidence limit).
BOUND_CONFIDENCE = 3.0
#: Every bound is at least this fraction of the image's level (the 98th percentile of
#: |x| over the used pixels, at least 1e-6): a residual below a millionth of the level is
#: the solver's tolerance on a noise-free (in-memory) image, not a mismatch.
BOUND_FLOOR = 1e-6
#: χ²/dof at the bound above which the residual is too large for any noise the image can
#: hold (the "magnitude" test): the residual's RMS is then over √10 ≈ 3.2 times the bound,
#: over the whole sphere or over one tile (below).
BOUND_CHI2 = 10.0
#: The magnitude test is also made on square tiles of this many pixels a side (a fixed
#: grid from the image's corner) that hold at least half a tile of used pixels: a misfit
#: confined to a small region (a refraction's centre, a highlight) is diluted in the
#: sphere's mean but not in its tile's.
BOUND_TILE = 8
#: The "structure" test: the residual's lag-1 autocovariance, in units of the bound's
#: variance, above this (its smooth part alone holds twice the largest noise variance)...
STRUCTURE_POWER = 2.0
#: ...and at least this many of its own standard errors above 0 (white noise: N(0, 1)).
STRUCTURE_Z = 8.0


@dataclass
class NoiseBound:
    r"""An upper bound on an image's noise, per pixel and channel (:func:`noise_bound`).

    ``variance`` (H, W, C): the bound on the noise variance at every pixel of ``used``
    (0 elsewhere); ``sigma`` (C,): the root mean square of its square root over the used
    pixels, √⟨U⟩, the one number per channel a result reports; ``positions``: the
    high-pass positions it was computed from; ``method``: how, in words."""

    variance: np.ndarray
    used: np.ndarray
    sigma: np.ndarray
    positions: int
    method: str

    def at(self, index: np.ndarray) -> np.ndarray:
        """(N, C): the bound's σ at the flat pixel indices ``index``."""
        flat = self.variance.reshape(-1, self.variance.shape[-1])
        return np.sqrt(flat[np.asarray(index)])


def _gaussian_1d(width: float) -> np.ndarray:
    """A sampled Gaussian of standard deviation ``width`` over ±4·width, summing to 1."""
    radius = max(int(math.ceil(4.0 * width)), 1)
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    g = np.exp(-0.5 * (x / width) ** 2)
    return g / g.sum()


def _separable(values: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """``values`` (H, W[, C]) correlated with the 2-D kernel kernel ⊗ kernel, zero outside."""
    from scipy import ndimage  # on first use (see _erode)

    out = ndimage.correlate1d(values, kernel, axis=0, mode="constant", cval=0.0)
    return ndimage.correlate1d(out, kernel, axis=1, mode="constant", cval=0.0)


def noise_bound(
    image: np.ndarray,
    used: np.ndarray,
    *,
    storage: float = 0.0,
    quantised: bool = False,
    width: float = BOUND_WIDTH,
    confidence: float = BOUND_CONFIDENCE,
    floor: float = BOUND_FLOOR,
    min_positions: int = MIN_PIXELS,
) -> NoiseBound:
    r"""An upper bound on the noise of ``image`` (H, W, C) at each of its ``used`` pixels,
    from the image alone: what the noise can at most be, even where it cannot be measured.

    High-pass residual. h = K ⋆ x with Immerkær's kernel K (``KERNELS["d2"]``, unit L2
    norm), at every position whose 3 × 3 footprint lies inside ``used``. For an image
    x = s + n, s the noise-free signal and n zero-mean noise, independent between pixels,
    of variance σ²(q) at pixel q,

    .. math:: E[h_p^2] = (K \star s)_p^2 + \sum_q K_q^2\,\sigma^2(p + q) \;\ge\; \sum_q K_q^2\,\sigma^2(p + q),

    the local mean noise variance (the weights K² sum to 1): the signal's own curvature
    only adds to it, however strong (a highlight, a reflection, a pattern).

    Local mean square. At each used pixel i, B(i) = Σ_p w_ip h_p² / Σ_p w_ip, w a Gaussian
    of standard deviation ``width`` pixels centred on i (p the footprints' centres): an
    upper bound, in expectation, on the noise variance around i, that follows
    signal-dependent (shot) noise and a highlight's local curvature alike. Its relative
    standard error for white noise is √(κ/n_eff), n_eff = (Σw)²/Σw² (about 200 inside the
    sphere, fewer at the rim) and κ = :func:`kernel_kappa` (7.56: neighbouring h share
    pixels), so the bound is the upper confidence limit

    .. math:: U(i) = B(i)\,\bigl(1 + c\sqrt{\kappa / n_\mathrm{eff}(i)}\bigr)
              + (\varepsilon_\mathrm{storage}\,x_i)^2 + \sigma_q(x_i)^2 + (f\,L)^2,

    c = ``confidence``; plus the known floors: the file's storage precision ``storage``
    (relative), the 8-bit quantisation σ_q when ``quantised``, and ``floor`` times the
    image's level L (the 98th percentile of |x| over the used pixels, at least 1e-6), so
    that U > 0 everywhere and every z = r/√U stays finite. A used pixel farther
    than 4·``width`` from every footprint gets the largest bound of the image.

    Assumes noise that is independent between neighbouring pixels (renders, raw sensor
    data): noise correlated between neighbours (demosaicing, denoising, compression)
    leaks less through K, and the bound can fall below it.

    Raises :class:`NoiseEstimationError` when fewer than ``min_positions`` footprints fit
    inside ``used``."""
    img = _as_image(image)
    H, W, C = img.shape
    mask = _as_mask(used, (H, W))
    _check_finite(img, mask)
    kernel = KERNELS["d2"]
    valid = _valid_positions(mask, kernel.shape)
    positions = int(valid.sum())
    if positions < min_positions:
        raise NoiseEstimationError(
            f"only {positions} pixel(s) have their whole 3×3 neighbourhood among the pixels used; "
            f"need at least {min_positions} to bound the noise"
        )
    # the squared residual at the centre of each footprint (the 3 × 3 kernel's centre is
    # one pixel below and right of its top-left position), 0 where there is none
    centre = np.zeros((H, W), dtype=bool)
    centre[1 : H - 1, 1 : W - 1] = valid
    square = np.zeros((H, W, C))
    square[1 : H - 1, 1 : W - 1] = np.where(valid[..., None], _correlate_valid(img, kernel) ** 2, 0.0)
    g = _gaussian_1d(width)
    weight = _separable(centre.astype(np.float64), g)  # Σ_p w_ip
    weight_sq = _separable(centre.astype(np.float64), g * g)  # Σ_p w_ip² (w² = g² ⊗ g²)
    summed = np.stack([_separable(square[..., c], g) for c in range(C)], axis=-1)
    # the sums of zeros are exactly 0: a pixel is unreached only beyond the truncation
    # radius (4·width) of every footprint; a barely reached one has n_eff ≈ 1 and a wide
    # confidence margin
    reached = weight > 0
    safe = np.where(reached, weight, 1.0)
    mean_square = summed / safe[..., None]
    n_eff = np.where(reached, weight**2 / np.where(reached, weight_sq, 1.0), 1.0)
    variance = mean_square * (1.0 + confidence * np.sqrt(kernel_kappa(kernel) / np.maximum(n_eff, 1e-12)))[..., None]
    inside = mask & reached
    if (mask & ~reached).any():  # thin or scattered masks: the largest bound there is
        largest = np.max(variance[inside], axis=0) if inside.any() else np.max(mean_square[centre], axis=0)
        variance = np.where((mask & ~reached)[..., None], largest, variance)
    values = img[mask]
    level = float(np.percentile(np.abs(values), 98)) if values.size else 1.0
    # the level as the reference noise takes it (at least 1e-6, so that a black image's
    # floor stays far inside float64: z² of a unit residual is then at most 1e24)
    floors = (storage * img) ** 2 + (floor * max(level, 1e-6)) ** 2
    if quantised:
        floors = floors + quantisation_sigma(np.clip(img, 0.0, 1.0)) ** 2
    variance = np.where(mask[..., None], variance + floors, 0.0)
    sigma = np.sqrt(np.mean(variance[mask], axis=0))
    method = (
        f"local mean square of the 3×3 second-difference residual (Immerkær's kernel) over a Gaussian "
        f"neighbourhood of {width:g} px, plus {confidence:g} standard errors, over {positions} positions: "
        "an upper bound on noise independent between neighbouring pixels"
    )
    return NoiseBound(variance, mask, sigma, positions, method)


#: Median of χ²₁: the median of z² for Gaussian z (turns a median of squares into a variance).
MEDIAN_CHI2_1 = 0.454936423119572
#: Level bins of :func:`binned_laplacian_bound` (quantiles of the observed values).
LAPLACIAN_BOUND_BINS = 8


def binned_laplacian_bound(
    laplacian: np.ndarray,
    levels: np.ndarray,
    usable: np.ndarray,
    query_levels: np.ndarray,
    bins: int = LAPLACIAN_BOUND_BINS,
) -> tuple[np.ndarray, list[dict[str, Any]]]:
    """An upper bound on the noise σ of many images of one scene (a capture), per level.

    ``laplacian`` (..., 3) holds the five-point Laplacian 4 I(p) − Σ I(neighbours) of each
    image at each pixel (NaN where it is not defined), ``levels`` the observed values and
    ``usable`` which enter. Noise of level σ, independent between pixels, gives the
    Laplacian a spread of √20 σ, and the picture's own curvature only adds to it (as for
    :func:`noise_bound`, with the plain Laplacian instead of Immerkær's kernel). The values
    are binned by level (quantiles, per channel), and in each bin
    σ² ≤ median(Δ²)/(20 · median χ²₁). Why the median: a few pixels of strong curvature (a
    highlight's edge) would dominate a mean; the median still only grows with curvature.
    An empty bin borrows its nearest neighbour's. Returns the bound at ``query_levels``
    (same shape) and the bins per channel (``level_edges``, ``sigma``)."""
    bound = np.full(np.shape(query_levels), np.nan)
    out: list[dict[str, Any]] = []
    for c in range(3):
        ok = np.isfinite(laplacian[..., c]) & usable[..., c]
        if ok.sum() < 50:
            continue
        edges = np.quantile(levels[..., c][ok], np.linspace(0, 1, bins + 1))
        edges[0], edges[-1] = -np.inf, np.inf
        which = np.clip(np.searchsorted(edges, query_levels[..., c], side="right") - 1, 0, bins - 1)
        own = np.clip(np.searchsorted(edges, levels[..., c][ok], side="right") - 1, 0, bins - 1)
        squares = laplacian[..., c][ok] ** 2
        sigma = np.zeros(bins)
        for b in range(bins):
            values = squares[own == b]
            sigma[b] = math.sqrt(float(np.median(values)) / (20 * MEDIAN_CHI2_1)) if values.size >= 20 else np.nan
        for b in range(bins):
            if not np.isfinite(sigma[b]):
                finite = np.where(np.isfinite(sigma))[0]
                sigma[b] = sigma[finite[np.argmin(np.abs(finite - b))]] if finite.size else np.nan
        bound[..., c] = sigma[which]
        out.append(
            {"channel": "rgb"[c], "level_edges": [float(e) for e in edges[1:-1]], "sigma": [float(v) for v in sigma]}
        )
    return bound, out


@dataclass
class OneSidedVerdict:
    """The residual of a fit against the largest noise its target can hold
    (:func:`one_sided_verdict`).

    ``chi2_dof``: Σ(r/σ_b)²/(N − P); ``per_channel``: the same per channel;
    ``worst_tile``: the tile with the largest mean (r/σ_b)² (``chi2_per_dof``, ``pixels``
    used in it, its top-left ``row`` and ``column``, its ``size``), None when no tile holds
    enough used pixels; ``lag1_correlation``: ρ₁ of the residual in bound units over
    neighbouring used pixels; ``structured_power``: their mean product C₁ (the power of the
    residual's smooth part, in units of the bound's variance); ``structure_z``: C₁ in its
    own standard errors; ``pairs``: how many neighbour pairs; ``too_large`` /
    ``too_structured``: which test fired. ``mismatch`` when either did."""

    chi2_dof: float
    per_channel: list[float]
    worst_tile: dict | None
    lag1_correlation: float
    structured_power: float
    structure_z: float
    pairs: int
    too_large: bool
    too_structured: bool

    @property
    def mismatch(self) -> bool:
        return self.too_large or self.too_structured


def one_sided_verdict(
    residual: np.ndarray,
    bound: NoiseBound,
    n_params: int,
    *,
    chi2_threshold: float = BOUND_CHI2,
    tile: int = BOUND_TILE,
    structure_power: float = STRUCTURE_POWER,
    structure_z: float = STRUCTURE_Z,
) -> OneSidedVerdict:
    r"""Is the residual ``residual`` (H, W, C; read at ``bound.used``) too large or too
    structured for any noise up to ``bound``? A one-sided test: it can say that the model
    does not reproduce the target, never that it does.

    With z_i = r_i/σ_b(i) (σ_b² = ``bound.variance``, each value's noise σ_i ≤ σ_b(i)):

    - **magnitude**: χ²_b = Σ z²/(N − P) ≤ χ²/dof at the true noise, whose expected value
      is 1 when the model is right. The test fires when χ²_b > ``chi2_threshold`` (10)
      over the used pixels, or when the mean z² over the used values of one ``tile`` ×
      ``tile`` square (a fixed grid; squares with fewer than tile²/2 used pixels are
      skipped) does. With white noise E[z²] ≲ 0.7 (the bound's confidence margin), and a
      tile's mean over at least 32 pixels exceeds 10 with a probability below 1e-45 even
      if the channels' noise were one (a χ² with 32 degrees of freedom beyond 320): the
      margin is for what the bound assumes, not for chance. Noise whose neighbours correlate by ρ leaks through the
      high-pass kernel at only g(ρ) = ((6 − 8ρ + 2ρ²)/6)² of its variance; a threshold of
      10 tolerates ρ up to about 0.6.
    - **structure**: over the pairs (i, j) of horizontally or vertically neighbouring used
      pixels, p_ij = (1/C) Σ_c z_ic z_jc. For noise independent between pixels
      E[p_ij] = 0, and the p_ij are uncorrelated (E[z_i z_j z_j z_k] = 0), so
      C₁ = mean p_ij has the standard error √(Σ p²)/n_pairs, whatever the noise's level
      or its correlation between channels, and t = Σ p/√(Σ p²) is about N(0, 1). A smooth
      residual m (the model's misfit) gives C₁ ≈ mean (m/σ_b)²: the power of its smooth
      part in units of the bound, whatever the noise. The test fires when
      C₁ > ``structure_power`` (2) **and** t > ``structure_z`` (8): the smooth part alone
      exceeds twice the largest noise variance, and is no accident (8 standard errors;
      a self-normalised sum of symmetric terms exceeds x with probability below
      exp(−x²/2) ≈ 1e-14). Noise whose neighbours correlate by ρ gives C₁ ≈ ρ/g(ρ) in
      bound units (0.36 at ρ = 0.2, 0.9 at 0.35, 2.9 at 0.5), so the test tolerates
      neighbour correlations up to about 0.45.

    ``lag1_correlation`` ρ₁ = Σ p / Σ (z_i² + z_j²)/2 (channel means) is reported, not
    tested: 0 for white noise, near 1 for a smooth residual."""
    res = np.asarray(residual, dtype=np.float64)
    if res.ndim == 2:
        res = res[..., None]
    used = bound.used
    C = res.shape[-1]
    z = np.where(used[..., None], res / np.sqrt(np.where(used[..., None], bound.variance, 1.0)), 0.0)
    values = z[used]
    n_used = values.shape[0]
    dof = max(values.size - n_params, 1)
    chi2 = float(np.sum(values**2) / dof)
    per_channel = [float(np.sum(values[:, c] ** 2) / max(n_used - n_params / C, 1.0)) for c in range(C)]
    worst_tile = _worst_tile(np.sum(z * z, axis=-1) / C, used, tile)
    products, squares = [], []
    for a, b, both in (
        (z[:, :-1], z[:, 1:], used[:, :-1] & used[:, 1:]),
        (z[:-1, :], z[1:, :], used[:-1, :] & used[1:, :]),
    ):
        products.append(np.mean(a * b, axis=-1)[both])
        squares.append(np.mean(a * a + b * b, axis=-1)[both] / 2.0)
    p, q = np.concatenate(products), np.concatenate(squares)
    pairs = int(p.size)
    total, spread, power = float(np.sum(p)), float(np.sqrt(np.sum(p * p))), float(np.sum(q))
    c1 = total / pairs if pairs else 0.0
    t = total / spread if spread > 0 else 0.0
    rho = total / power if power > 0 else 0.0
    return OneSidedVerdict(
        chi2_dof=chi2,
        per_channel=per_channel,
        worst_tile=worst_tile,
        lag1_correlation=rho,
        structured_power=c1,
        structure_z=t,
        pairs=pairs,
        too_large=bool(
            chi2 > chi2_threshold or (worst_tile is not None and worst_tile["chi2_per_dof"] > chi2_threshold)
        ),
        too_structured=bool(c1 > structure_power and t > structure_z),
    )


def _worst_tile(z2: np.ndarray, used: np.ndarray, tile: int) -> dict | None:
    """The ``tile`` × ``tile`` square of a fixed grid (from the image's corner) with the
    largest mean of ``z2`` (H, W: the mean over channels of z²) over its used pixels,
    among the squares with at least tile²/2 of them; None when there is none."""
    H, W = used.shape
    rows, cols = -(-H // tile), -(-W // tile)
    padded_z = np.zeros((rows * tile, cols * tile))
    padded_u = np.zeros((rows * tile, cols * tile))
    padded_z[:H, :W] = np.where(used, z2, 0.0)
    padded_u[:H, :W] = used
    sums = padded_z.reshape(rows, tile, cols, tile).sum(axis=(1, 3))
    counts = padded_u.reshape(rows, tile, cols, tile).sum(axis=(1, 3))
    enough = counts >= tile * tile / 2
    if not enough.any():
        return None
    means = np.where(enough, sums / np.maximum(counts, 1.0), -np.inf)
    row, col = np.unravel_index(int(np.argmax(means)), means.shape)
    return {
        "chi2_per_dof": float(means[row, col]),
        "pixels": int(counts[row, col]),
        "row": int(row * tile),
        "column": int(col * tile),
        "size": int(tile),
    }


# --------------------------------------------------------------------------------------
# the noise model a fit uses
# --------------------------------------------------------------------------------------

#: Relative rounding of stored floating-point values (EXR, TIFF, PFM), by pixel type: the
#: floor of a noise-free render's noise.
STORAGE_PRECISION = {"half": 2.0**-11, "float": 2.0**-24, "double": 2.0**-53}
#: Fewest residual positions for a signal-dependent (Poisson–Gaussian) model from the image:
#: on smaller images (a 24 × 24 sphere has ~300) its slope test fires on chance structure.
MIN_PIXELS_SIGNAL_DEPENDENT = 2000
#: Where :func:`describe_noise` got the level from.
NOISE_SOURCES = ("given", "sensor", "image", "unknown")


@dataclass
class NoiseModel:
    r"""The noise of a target image, per value: :math:`\mathrm{Var} = a·\max(L, 0) + b`
    per channel (a: the shot-noise slope, 1/gain; b: additive noise), plus the 8-bit sRGB
    quantisation at the level L when ``quantised``, plus the storage precision
    (``storage`` × |L|)². :meth:`sigma_at` evaluates it at a level — the fitted model's
    radiance, the best estimate of the true one.

    ``source``: ``"given"`` (the user's value), ``"sensor"`` (the target's sidecar: the
    synthetic sensor that made it, or a renderer's measured noise), ``"image"`` (estimated
    from the image itself, model-free: :func:`estimate_noise`), ``"unknown"`` (it could not
    be estimated: a noise-free image, or content the estimator cannot separate from
    noise; then :meth:`sigma_at` gives NaN). ``relative_stderr`` (3,): the level's own
    uncertainty (0 when given or from a sensor)."""

    source: str
    a: np.ndarray
    b: np.ndarray
    quantised: bool = False
    storage: float = 0.0
    relative_stderr: np.ndarray = field(default_factory=lambda: np.zeros(3))
    notes: list[str] = field(default_factory=list)
    details: dict = field(default_factory=dict)

    @property
    def known(self) -> bool:
        return self.source != "unknown"

    @property
    def signal_dependent(self) -> bool:
        return bool(np.any(self.a > 0))

    def sigma_at(self, level: np.ndarray) -> np.ndarray:
        """σ per value at the radiance ``level`` (..., 3) (NaN when the noise is unknown)."""
        level = np.asarray(level, dtype=np.float64)
        if not self.known:
            return np.full(level.shape, np.nan)
        variance = self.a * np.maximum(level, 0.0) + self.b + (self.storage * level) ** 2
        if self.quantised:
            variance = variance + quantisation_sigma(np.clip(level, 0.0, 1.0)) ** 2
        return np.sqrt(variance)

    def typical(self, level: np.ndarray) -> np.ndarray:
        """(3,) the root-mean-square σ per channel over the values ``level`` (N, 3)."""
        return np.sqrt(np.mean(self.sigma_at(level) ** 2, axis=0))

    def to_dict(self) -> dict:
        return {
            "source": self.source,
            "shot_slope": self.a.tolist(),
            "additive_sd": np.sqrt(self.b).tolist(),
            "quantised": self.quantised,
            "storage_precision": self.storage,
            "relative_stderr": np.asarray(self.relative_stderr, dtype=float).tolist(),
            "notes": list(self.notes),
        }


def _triple(value: float | tuple | list | np.ndarray) -> np.ndarray:
    return np.broadcast_to(np.asarray(value, dtype=np.float64), (3,)).copy()


#: The noise levels σ (linear units) a fit, a chain or a noise model accepts: from 1e-100
#: to 1e100. Outside, σ² or 1/σ² — and the χ², the noise sandwich and the likelihood built
#: from them with the image's values, pixel counts and slopes — leave float64's range
#: (about 1e±308): a given σ of 1e300 overflowed σ² and made every deviation NaN, one of
#: 1e-300 underflowed σ² to 0 and broke the robust refit. Inside, every product has a
#: hundred orders of magnitude to spare, far beyond any image's scale.
NOISE_RANGE = (1e-100, 1e100)


def check_noise_level(value: float | tuple | list | np.ndarray, what: str = "the noise level") -> np.ndarray:
    """``value``, one noise σ or three (R, G, B), as (3,) float64, or a one-line
    :class:`~strauss_fit.errors.StraussFitError` naming ``what`` when it is not one or three
    finite numbers within :data:`NOISE_RANGE`."""
    low, high = NOISE_RANGE
    try:
        values = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        values = np.zeros(0)
    if values.size not in (1, 3) or not np.all(np.isfinite(values)) or np.any(values <= 0):
        raise StraussFitError(f"{what} must be one positive number or three (R, G, B), got {value}")
    if np.any(values < low) or np.any(values > high):
        raise StraussFitError(
            f"{what} must be from {low:g} to {high:g} (linear units; beyond, its square or inverse square "
            f"leaves float64's range), got {', '.join(f'{v:g}' for v in values)}"
        )
    return np.broadcast_to(values, (3,)).copy()


def storage_precision(path: str | None) -> float:
    """The relative rounding of a floating-point image file's values (0 for 8-bit and
    unknown files: their floor is the quantisation)."""
    from pathlib import Path

    if not path or not Path(path).is_file():
        return 0.0
    try:
        import OpenImageIO as oiio

        image = oiio.ImageInput.open(str(path))
        if image is None:
            oiio.geterror()  # read (and drop) the error, or OpenImageIO prints it at exit
            return 0.0
        try:
            basetype = image.spec().format.basetype
        finally:
            image.close()
    except Exception:  # a header we cannot read only loses the floor
        return 0.0
    names = {oiio.HALF: "half", oiio.FLOAT: "float", oiio.DOUBLE: "double"}
    return STORAGE_PRECISION.get(names.get(basetype, ""), 0.0)


def _zero_or_in_range(sigma: float) -> bool:
    """A noise σ of 0 (none) or within :data:`NOISE_RANGE`."""
    return sigma == 0 or (math.isfinite(sigma) and NOISE_RANGE[0] <= sigma <= NOISE_RANGE[1])


def sidecar_path(path: str | Path) -> Path:
    """Where an image's sidecar would be: ``ID.json`` beside ``ID.png`` (docs/datasets.md)."""
    return Path(path).with_suffix(".json")


def read_sidecar(path: str | None) -> dict | None:
    """The synth sidecar beside an image (``ID.png`` → ``ID.json``, see docs/datasets.md)
    if there is one and it is a strauss-fit sample description, else None."""
    if not path:
        return None
    import json

    candidate = sidecar_path(path)
    if not candidate.is_file():  # a regular file only: reading a FIFO would block
        return None
    try:
        data = json.loads(candidate.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or data.get("format") != "strauss-fit synth sample":
        return None
    return data


def _from_sidecar(sidecar: dict) -> tuple[np.ndarray, np.ndarray, str] | None:
    """(a, b, note) of a sidecar's noise: a renderer's measured per-channel noise
    (``noise.per_channel``) or the synthetic sensor (Var = E/gain + read_noise²)."""
    measured = (sidecar.get("noise") or {}).get("per_channel")
    if measured is not None:
        try:
            sigma = _triple(measured)
        except (TypeError, ValueError):
            sigma = np.full(3, np.nan)
        if all(_zero_or_in_range(v) for v in sigma):
            return np.zeros(3), sigma**2, "measured noise recorded in the sidecar"
    sensor = sidecar.get("sensor")
    if isinstance(sensor, dict):
        try:
            gain, read = float(sensor.get("gain", 0.0)), float(sensor.get("read_noise", 0.0))
        except (TypeError, ValueError):
            return None
        # the shot noise's σ at level 1 is 1/√gain: in range too
        shot_ok = gain == 0 or (math.isfinite(gain) and gain > 0 and _zero_or_in_range(1.0 / math.sqrt(gain)))
        if not (shot_ok and _zero_or_in_range(read)):
            return None
        a = np.full(3, 1.0 / gain if gain > 0 else 0.0)
        note = f"sensor of the sidecar (gain {gain:g}, read noise {read:g})"
        if gain == 0 and read == 0:
            note = "the sidecar's sensor adds no noise: only the file's precision limits the fit"
        return a, np.full(3, read**2), note
    return None


def describe_noise(
    pixels: np.ndarray,
    usable: np.ndarray,
    *,
    encoding: str = "linear",
    path: str | None = None,
    given: float | tuple | None = None,
    sidecar: dict | None = None,
) -> NoiseModel:
    """The noise model of a target image (see :class:`NoiseModel`): the ``given`` level if
    any, else the ``sidecar``'s (read beside ``path`` when not passed; pass ``{}`` to
    ignore it), else estimated from the image over the ``usable`` pixels (the sphere's
    fully covered ones), signal-dependent when the estimate finds shot noise. An 8-bit sRGB
    target (``encoding="srgb"``) adds its quantisation; a float file its precision. An
    estimate is computed once per image content and reused (a copy) when the same image is
    described again."""
    pixels = np.asarray(pixels, dtype=np.float64)
    quantised = encoding == "srgb"
    storage = 0.0 if quantised else storage_precision(path)
    if given is not None:
        sigma = check_noise_level(given)
        return NoiseModel("given", np.zeros(3), sigma**2, quantised, storage, notes=["the noise level given"])
    if sidecar is None:
        sidecar = read_sidecar(path)
    described = _from_sidecar(sidecar) if sidecar else None
    if described is not None:
        a, b, note = described
        return NoiseModel("sensor", a, b, quantised, storage, notes=[note])
    usable = np.asarray(usable, dtype=bool)
    key = _image_key(pixels, usable, quantised, storage)
    with _ESTIMATED_LOCK:
        known = _ESTIMATED.get(key)
        if known is not None:
            _ESTIMATED.move_to_end(key)
            return copy.deepcopy(known)
    described = _estimated_noise(pixels, usable, quantised, storage)
    with _ESTIMATED_LOCK:
        _ESTIMATED[key] = copy.deepcopy(described)
        while len(_ESTIMATED) > ESTIMATED_KEPT:
            _ESTIMATED.popitem(last=False)
    return described


#: Noise models estimated from images, by the image's content (:func:`_image_key`): a
#: target fitted again (another loss, other free parameters, a batch's retry, a benchmark)
#: is the same image with the same noise, and estimating it costs a third of a warm fit.
_ESTIMATED: OrderedDict[bytes, NoiseModel] = OrderedDict()
_ESTIMATED_LOCK = threading.Lock()  # fits may describe targets from several threads
#: How many estimates :data:`_ESTIMATED` keeps (the least recently used go first).
ESTIMATED_KEPT = 32


def _image_key(pixels: np.ndarray, usable: np.ndarray, quantised: bool, storage: float) -> bytes:
    """What decides an image's estimated noise: its values, the pixels used, the 8-bit
    quantisation and the file's precision (a 256² image hashes in about 2 ms)."""
    digest = hashlib.blake2b(digest_size=20)
    for array in (pixels, usable):
        digest.update(repr((array.shape, array.dtype.str)).encode())
        digest.update(np.ascontiguousarray(array).data)
    digest.update(repr((quantised, storage)).encode())
    return digest.digest()


def _estimated_noise(pixels: np.ndarray, usable: np.ndarray, quantised: bool, storage: float) -> NoiseModel:
    """The noise model estimated from the image itself (:func:`describe_noise`'s last case)."""
    try:
        estimate = estimate_noise(pixels, usable, censor=(0.0, 1.0) if quantised else None)
    except NoiseEstimationError as exc:
        return NoiseModel("unknown", np.zeros(3), np.zeros(3), quantised, storage, notes=[str(exc)])
    if not np.all(estimate.resolved):
        why = (
            "the image's fine detail, not noise, sets its high-frequency content (a noise-free render, or a "
            "pattern seen in the sphere)"
        )
        return NoiseModel(
            "unknown", np.zeros(3), np.zeros(3), quantised, storage, notes=[why], details=estimate.to_dict()
        )
    variance = estimate.sigma**2
    if quantised:  # the estimate holds the quantisation pooled over the pixels it used; each pixel gets its own
        variance = np.maximum(variance - np.mean(quantisation_sigma(pixels[usable]) ** 2, axis=0), 0.0)
    a = np.zeros(3)
    note = "estimated from the image (additive, per channel)"
    if estimate.n_pixels >= MIN_PIXELS_SIGNAL_DEPENDENT:
        try:
            model = estimate_noise_model(
                pixels, usable, quantisation="srgb8" if quantised else None, censor=(0.0, 1.0) if quantised else None
            )
        except NoiseEstimationError:
            model = None
        if model is not None and np.any(model.signal_dependent) and np.all(model.channels_independent):
            # the line must agree with the additive estimate on average over the pixels it
            # describes, within the latter's own uncertainty (3 standard errors of σ²)
            level = pixels[usable]
            mean_variance = np.mean(model.a * np.maximum(level, 0.0) + model.b, axis=0)
            tolerance = 3 * 2 * np.asarray(estimate.relative_stderr, dtype=float) * variance
            if np.all(np.abs(mean_variance - variance) <= tolerance):
                a, variance = model.a.copy(), model.b.copy()
                note = "estimated from the image (signal-dependent: Var = a·L + b per channel)"
    return NoiseModel(
        "image",
        a,
        variance,
        quantised,
        storage,
        relative_stderr=np.asarray(estimate.relative_stderr, dtype=float),
        notes=[note],
        details=estimate.to_dict(),
    )
