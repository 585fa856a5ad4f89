"""The robust scale of a high-pass residual: MAD, then clipped and window-tested to a
fixed point (see `_robust_scale`), and the residuals' correlation across channels.
Shared by the kernel estimator and the level line.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def _truncated_variance_factor(k: float) -> float:
    """E[z² | |z| ≤ k] for z ~ N(0, 1)."""
    p = math.erf(k / math.sqrt(2.0))
    phi = math.exp(-0.5 * k * k) / math.sqrt(2 * math.pi)
    return 1.0 - 2.0 * k * phi / p


def _truncated_median_factor(k: float) -> float:
    """median(|z| given |z| ≤ k) for z ~ N(0, 1)."""
    from scipy import special  # on first use (see _inputs._erode)

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
    """A robust scale (C,) and the positions it kept, with the counts the estimate reports."""

    sigma: np.ndarray  # (C,)
    kept: np.ndarray  # bool positions
    n_valid: int
    n_kept: int
    iterations: int
    window_flagged: int = 0


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
    from scipy import ndimage  # on first use (see _inputs._erode)

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
