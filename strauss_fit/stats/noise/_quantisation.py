"""The noise floor of 8-bit sRGB coding: `quantisation_sigma` per value, and
`combine_with_quantisation` with a noise level.
"""

from __future__ import annotations

import numpy as np

from ...color import srgb_decode, srgb_encode


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
