"""The input preparation every estimator starts from: one place that turns an image and a
mask into what the high-pass residual is computed over, with the same checks and the same
error messages for `estimate_noise`, `estimate_noise_model` and
`noise_bound`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._errors import NoiseEstimationError
from ._highpass import KERNELS

#: Fewest residual positions an estimate is made from.
MIN_PIXELS = 50


@dataclass(frozen=True)
class Inputs:
    """An estimator's prepared input (`prepare`).

    ``image`` (H, W, C) float64 (a grey image gets C = 1); ``usable`` (H, W) the pixels the
    residual may read: the mask's finite pixels, eroded by the margin; ``kernel`` the
    high-pass kernel (unit L2 norm) named ``kernel_name`` in `KERNELS`."""

    image: np.ndarray
    usable: np.ndarray
    kernel: np.ndarray
    kernel_name: str


def prepare(image: np.ndarray, mask: np.ndarray | None, *, margin: int = 0, kernel: str = "d2") -> Inputs:
    """The image as (H, W, C) float64, the ``mask`` (H, W; None: every pixel) less its
    non-finite pixels and eroded by ``margin`` pixels, and the kernel named ``kernel``.

    Raises `NoiseEstimationError` for an image that is not (H, W) or (H, W, C), a
    mask of another shape, a NaN or infinite value inside the mask (the caller should mark
    it unusable: silently dropping it would hide a broken image), or an unknown kernel.
    The checks run in this order (the first failure is the one reported)."""
    img = _as_image(image)
    H, W, _ = img.shape
    usable = _as_mask(mask, (H, W))
    _check_finite(img, usable)
    usable = _erode(usable & np.all(np.isfinite(img), axis=-1), margin)
    if kernel not in KERNELS:
        raise NoiseEstimationError(f"unknown kernel {kernel!r}; expected one of {', '.join(KERNELS)}")
    return Inputs(img, usable, KERNELS[kernel], kernel)


def _as_image(image: np.ndarray) -> np.ndarray:
    """``image`` as (H, W, C) float64 (a grey image gets one channel)."""
    img = np.asarray(image, dtype=np.float64)
    if img.ndim == 2:
        img = img[..., None]
    if img.ndim != 3:
        raise NoiseEstimationError(f"image must be (H, W) or (H, W, C), got shape {np.shape(image)}")
    return img


def _as_mask(mask: np.ndarray | None, shape: tuple[int, int]) -> np.ndarray:
    """``mask`` as a bool array of the image's (H, W) ``shape`` (None: every pixel)."""
    if mask is None:
        return np.ones(shape, dtype=bool)
    m = np.asarray(mask)
    if m.shape != shape:
        raise NoiseEstimationError(f"usable_mask has shape {m.shape} but the image is {shape}")
    return m.astype(bool)


def _check_finite(img: np.ndarray, usable: np.ndarray) -> None:
    """Raise when a ``usable`` pixel holds a NaN or an infinity in any channel."""
    bad = ~np.all(np.isfinite(img), axis=-1) & usable
    if bad.any():
        raise NoiseEstimationError(
            f"{int(bad.sum())} usable pixel(s) hold NaN or infinite values; mark them unusable or fix the image"
        )


def _erode(mask: np.ndarray, margin: int) -> np.ndarray:
    """``mask`` eroded by ``margin`` pixels (3×3 steps; outside the image counts as unusable)."""
    if margin <= 0:
        return mask
    from scipy import ndimage  # on first use: importing SciPy cost a command's start 1.5 s (2 cores, load 11)

    return ndimage.binary_erosion(mask, structure=np.ones((3, 3), bool), iterations=margin, border_value=0)
