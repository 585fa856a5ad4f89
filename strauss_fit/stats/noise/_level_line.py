"""Signal-dependent noise: the Poisson–Gaussian level line Var = a·x + b per channel
(`estimate_noise_model`, its result `PoissonGaussian`), fitted to the
variance of the high-pass residual in bins of the local level.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from ._calibration import _CALIBRATION, _SE_FACTOR
from ._errors import NoiseEstimationError
from ._highpass import _box_levels, _correlate_valid, _flat_channels, _valid_positions, kernel_kappa
from ._inputs import Inputs, prepare
from ._quantisation import quantisation_sigma
from ._robust import MAD_CONSTANT, _channel_correlation, _robust_scale, _truncated_variance_factor


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

    Solved in centred form: with `\bar x = \sum w x / \sum w` and
    `S = \sum w (x - \bar x)^2`, `a = \sum w (x - \bar x) y / S`,
    `b = \bar y - a \bar x`, `\mathrm{var}\,a = 1/S` and
    `\mathrm{var}\,b = 1/\sum w + \bar x^2/S`. Why not the inverse of the 2 × 2
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


#: Relative change of (a, b) between two clipped passes of `estimate_noise_model`
#: below which the passes have reached their fixed point (the rest would repeat them).
FIXED_POINT = 1e-12
#: Fewest residual positions the level line is fitted to (and left after censoring).
_MIN_POSITIONS = 200


@dataclass(frozen=True)
class _Residuals:
    """What every pass of `estimate_noise_model` reads, on the residual grid (h, w):
    the residual ``res`` (h, w, C), the ``level`` Σ K²·x its variance is a mean over, the
    quantisation variance ``qvar`` at that level (0 without quantisation), the box level
    ``box`` the censoring tests (None without censoring) and the ``valid`` positions."""

    res: np.ndarray
    level: np.ndarray
    qvar: np.ndarray
    box: np.ndarray | None
    valid: np.ndarray

    def model_sd(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """(h, w, C): the residual's σ the line a, b (plus the quantisation) predicts."""
        return np.sqrt(np.maximum(a * np.maximum(self.level, 0) + b + self.qvar, 1e-300))


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
    cleaned exactly as in `estimate_noise` (clip, dilate, window test), so bright,
    noisier pixels are not rejected as content; each bin's variance is the truncated
    second moment of its kept residuals; a line is fitted by weighted least squares
    (weights from the model's predicted SE), a and b clamped ≥ 0. The passes stop early
    once one gives the a and b of the one before (`FIXED_POINT`): each pass is a
    function of the previous a and b, so the rest would repeat it.

    ``signal_dependent``: a / SE(a) > ``z``. ``chi2_dof`` of the line fit (> 1: the bins
    scatter more than noise allows — content, or a noise that is not a·x + b; the SEs are
    then widened by √chi2_dof).

    ``quantisation="srgb8"``: subtract each bin's mean 8-bit quantisation variance
    (`quantisation_sigma`) before the fit (sRGB-decoded 8-bit targets).
    ``censor=(0, 1)``: leave out positions whose local level is within 2σ(level) of an end
    of the code range (as in `estimate_noise`). ``channels_independent``: the
    normalised residuals do not correlate across channels (|z| ≤ ``correlation_z``);
    False means image content leaks into the bins.
    """
    inputs = prepare(image, usable_mask, margin=margin, kernel=kernel)
    r = _level_residuals(inputs, censor, quantisation)
    C = inputs.image.shape[-1]
    nb = n_bins or int(np.clip(int(r.valid.sum()) // min_per_bin, 3, 20))
    se_factor = _SE_FACTOR.get((kernel, "clipped", window), 1.6)
    factor = _CALIBRATION.get((kernel, "clipped", window), 1.0) ** 2 / _truncated_variance_factor(clip)
    kappa = kernel_kappa(inputs.kernel)

    a = np.zeros(C)
    b = np.zeros(C)
    stats = np.zeros((3, C))  # per channel: SE of a, SE of b, chi²/dof of the line
    bins: list = []
    kept = r.valid
    last = None  # (a, b) of the previous clipped pass
    for it in range(iterations + 1):
        if it == 0:  # no model yet: every position, unscaled
            kept, scale = r.valid, np.ones(C)
        else:
            kept, scale = _clean_positions(r, a, b, censor, clip=clip, dilate=dilate, window=window, kappa=kappa)
        a, b, stats, bins = _fit_pass(
            r, kept, scale, a, b, n_bins=nb, first=it == 0, se_factor=se_factor, factor=factor
        )
        if it >= 1:
            now = np.concatenate([a, b])
            if last is not None and np.all(np.abs(now - last) <= FIXED_POINT * np.maximum(np.abs(now), 1e-300)):
                break  # a fixed point: every further pass would repeat this one
            last = now
    independent = np.ones(C, bool)
    if C > 1:
        _, zc, _ = _channel_correlation(r.res / r.model_sd(a, b), kept, kappa)
        independent = ~np.any(np.abs(zc) > correlation_z, axis=1)
    return PoissonGaussian(
        a=a.copy(),
        b=b.copy(),
        a_stderr=stats[0].copy(),
        b_stderr=stats[1].copy(),
        signal_dependent=(a / np.where(stats[0] > 0, stats[0], np.inf)) > z,
        chi2_dof=stats[2].copy(),
        n_pixels=int(kept.sum()),
        channels_independent=independent,
        bins=bins,
    )


def _level_residuals(
    inputs: Inputs, censor: tuple[float, float] | None, quantisation: Literal[None, "srgb8"]
) -> _Residuals:
    """The residual, its level, the quantisation variance and the censoring level of
    `estimate_noise_model`, over the positions whose footprint is usable.

    Raises `NoiseEstimationError` with fewer than 200 such positions, a residual that
    is zero in a channel, or an unknown ``quantisation``."""
    img, k = inputs.image, inputs.kernel
    valid = _valid_positions(inputs.usable, k.shape)
    n_valid = int(valid.sum())
    if n_valid < _MIN_POSITIONS:
        raise NoiseEstimationError(f"only {n_valid} usable residual positions; need at least 200 to fit a noise model")
    res = _correlate_valid(img, k)
    if np.any(_flat_channels(img, inputs.usable, res[valid])):
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
    return _Residuals(res, level, qvar, box, valid)


def _clean_positions(
    r: _Residuals,
    a: np.ndarray,
    b: np.ndarray,
    censor: tuple[float, float] | None,
    *,
    clip: float,
    dilate: int,
    window: int,
    kappa: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The positions a clipped pass keeps, and the robust scale (C,) of the residuals in
    units of the line a, b's σ: cleaned as in `estimate_noise` after the censoring
    (positions within 2σ of an end of ``censor``), so that brighter, noisier pixels are not
    taken for content.

    Raises `NoiseEstimationError` when the censoring leaves fewer than 200."""
    sd = r.model_sd(a, b)
    v = r.valid
    if r.box is not None:
        v = r.valid & ~np.any((r.box < censor[0] + 2 * sd) | (r.box > censor[1] - 2 * sd), axis=-1)
        if v.sum() < _MIN_POSITIONS:
            raise NoiseEstimationError("fewer than 200 positions are far enough from the code range's ends")
    rob = _robust_scale(r.res / sd, v, "clipped", clip, dilate, window=window, kappa=kappa)
    return rob.kept, rob.sigma


def _fit_pass(
    r: _Residuals,
    kept: np.ndarray,
    scale: np.ndarray,
    a: np.ndarray,
    b: np.ndarray,
    *,
    n_bins: int,
    first: bool,
    se_factor: float,
    factor: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list]:
    """One pass of the level line over the ``kept`` positions: per channel, the residuals'
    variance in ``n_bins`` equal-count level bins (`_bin_variances`) and the line
    fitted to them (`_fit_line`). Each bin's SE comes from the previous line a, b
    once there is one (weights from the noisy bin values themselves would favour
    low-variance bins); ``first``: there is none yet.

    Returns the new a, b (C,), their SEs and the fit's chi²/dof (3, C), and each channel's
    bins (``scale``: the robust scale of the normalised residuals, for the record).

    Raises `NoiseEstimationError` when a channel has fewer than 3 populated bins."""
    C = r.res.shape[-1]
    new_a, new_b, stats, bins = np.zeros(C), np.zeros(C), np.zeros((3, C)), []
    for c in range(C):
        mu = r.level[..., c][kept]
        edges = np.quantile(mu, np.linspace(0, 1, n_bins + 1))
        idx = np.clip(np.searchsorted(edges, mu, side="right") - 1, 0, n_bins - 1)
        xs, vs, ns, qs = _bin_variances(
            mu, r.res[..., c][kept], r.qvar[..., c][kept], idx, n_bins, first=first, factor=factor
        )
        if len(xs) < 3:
            raise NoiseEstimationError("too few populated level bins to fit a noise model")
        if first:  # the bins' own variances, and the SE factor of an unclipped MAD
            total, factor_now = np.maximum(vs + qs, 1e-300), 1.7
        else:
            total, factor_now = np.maximum(a[c] * np.maximum(xs, 0) + b[c] + qs, 1e-300), se_factor
        se_v = 2 * factor_now * total / np.sqrt(ns)
        ac, bc, sa, sb, chi = _fit_line(xs, vs, se_v)
        new_a[c], new_b[c] = ac, bc
        stats[:, c] = sa, sb, chi
        bins.append(
            {
                "level": xs.tolist(),
                "variance": vs.tolist(),
                "variance_se": se_v.tolist(),
                "count": ns.tolist(),
                "normalised_scale": float(scale[c]),
            }
        )
    return new_a, new_b, stats, bins
