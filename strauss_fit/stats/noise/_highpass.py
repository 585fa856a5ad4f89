"""The high-pass kernels and the residual grid every estimator reads the noise through.

A residual position is the top-left corner of a kernel footprint: the valid-mode
correlation of an (H, W) image with a kh×kw kernel has (H-kh+1, W-kw+1) of them.
"""

from __future__ import annotations

import functools

import numpy as np


def _outer(v: list[float]) -> np.ndarray:
    """The tensor product v ⊗ v scaled to unit L2 norm."""
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


def kernel_kappa(kernel: np.ndarray) -> float:
    """Var[mean of (r/σ)² over n positions] ≈ κ/n for white noise: κ = 2·Σ ρ(lag)², ρ the
    autocorrelation of the residual (overlapping footprints make neighbours correlated).
    d2: 7.56, d3: 10.67, haar: 4.5, lap: 3.38."""
    kernel = np.asarray(kernel, dtype=np.float64)
    return _kernel_kappa(kernel.shape, kernel.tobytes())


@functools.lru_cache(maxsize=32)
def _kernel_kappa(shape: tuple[int, int], data: bytes) -> float:
    """`kernel_kappa` of the kernel held in ``data`` (cached: a kernel is hashable only
    as bytes, and every estimate asks for the same few)."""
    kernel = np.frombuffer(data, dtype=np.float64).reshape(shape)
    kh, kw = kernel.shape
    padded = np.pad(kernel, ((kh - 1, kh - 1), (kw - 1, kw - 1)))
    ac = np.array(
        [[np.sum(kernel * padded[i : i + kh, j : j + kw]) for j in range(2 * kw - 1)] for i in range(2 * kh - 1)]
    )
    ac = ac / np.sum(kernel * kernel)
    return float(2.0 * np.sum(ac * ac))


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


def _box_levels(img: np.ndarray, kshape: tuple[int, int]) -> np.ndarray:
    """Mean of each residual position's footprint grown by one pixel on every side, per
    channel, on the residual grid. The box weight is constant over the footprint and the
    kernel sums to 0, so for white noise this level is uncorrelated with the residual:
    selecting positions by it does not bias the residual's scale."""
    kh, kw = kshape
    padded = np.pad(img, ((1, 1), (1, 1), (0, 0)), mode="edge")
    box = np.ones((kh + 2, kw + 2)) / ((kh + 2) * (kw + 2))
    return _correlate_valid(padded, box)


def _flat_channels(img: np.ndarray, usable: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """(C,) True where the residual ``rows`` (n, C) is zero up to float rounding relative to
    the image's largest |value| over ``usable``: a constant (or linear) channel, whose
    noise the kernel cannot see."""
    scale = np.max(np.abs(img[usable]), axis=0)
    return np.max(np.abs(rows), axis=0) <= 1e-12 * np.maximum(scale, 1e-300)
