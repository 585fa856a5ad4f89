"""The largest noise an image can hold, from the image alone, when its noise cannot be
measured: `noise_bound` per pixel (Immerkær's residual), and
`binned_laplacian_bound` per level for a capture's many images.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ._errors import NoiseEstimationError
from ._highpass import _correlate_valid, _valid_positions, kernel_kappa
from ._inputs import MIN_PIXELS, prepare
from ._quantisation import quantisation_sigma

#: Standard deviation, in pixels, of the Gaussian neighbourhood over which
#: `noise_bound` averages the squared high-pass residual: about 4π·4² ≈ 200 positions
#: inside the sphere, narrow enough to follow a highlight or a reflection, wide enough
#: for a local mean square with a relative standard error of about √(κ/200) ≈ 0.19.
BOUND_WIDTH = 4.0
#: Standard errors of the local mean square added to it (an upper confidence limit).
BOUND_CONFIDENCE = 3.0
#: Every bound is at least this fraction of the image's level (the 98th percentile of
#: |x| over the used pixels, at least 1e-6): a residual below a millionth of the level is
#: the solver's tolerance on a noise-free (in-memory) image, not a mismatch.
BOUND_FLOOR = 1e-6


@dataclass
class NoiseBound:
    r"""An upper bound on an image's noise, per pixel and channel (`noise_bound`).

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
    from scipy import ndimage  # on first use (see _inputs._erode)

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

    ```text
    E[h_p^2] = (K \star s)_p^2 + \sum_q K_q^2\,\sigma^2(p + q) \;\ge\; \sum_q K_q^2\,\sigma^2(p + q),
    ```

    the local mean noise variance (the weights K² sum to 1): the signal's own curvature
    only adds to it, however strong (a highlight, a reflection, a pattern).

    Local mean square. At each used pixel i, B(i) = Σ_p w_ip h_p² / Σ_p w_ip, w a Gaussian
    of standard deviation ``width`` pixels centred on i (p the footprints' centres): an
    upper bound, in expectation, on the noise variance around i, that follows
    signal-dependent (shot) noise and a highlight's local curvature alike. Its relative
    standard error for white noise is √(κ/n_eff), n_eff = (Σw)²/Σw² (about 200 inside the
    sphere, fewer at the rim) and κ = `kernel_kappa` (7.56: neighbouring h share
    pixels), so the bound is the upper confidence limit

    ```text
    U(i) = B(i)\,\bigl(1 + c\sqrt{\kappa / n_\mathrm{eff}(i)}\bigr)
                  + (\varepsilon_\mathrm{storage}\,x_i)^2 + \sigma_q(x_i)^2 + (f\,L)^2,
    ```

    c = ``confidence``; plus the known floors: the file's storage precision ``storage``
    (relative), the 8-bit quantisation σ_q when ``quantised``, and ``floor`` times the
    image's level L (the 98th percentile of |x| over the used pixels, at least 1e-6), so
    that U > 0 everywhere and every z = r/√U stays finite. A used pixel farther
    than 4·``width`` from every footprint gets the largest bound of the image.

    Assumes noise that is independent between neighbouring pixels (renders, raw sensor
    data): noise correlated between neighbours (demosaicing, denoising, compression)
    leaks less through K, and the bound can fall below it.

    Raises `NoiseEstimationError` when fewer than ``min_positions`` footprints fit
    inside ``used``."""
    inputs = prepare(image, used)  # no erosion: every used pixel gets a bound
    img, mask, kernel = inputs.image, inputs.usable, inputs.kernel
    H, W, C = img.shape
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
#: Level bins of `binned_laplacian_bound` (quantiles of the observed values).
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
    `noise_bound`, with the plain Laplacian instead of Immerkær's kernel). The values
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
