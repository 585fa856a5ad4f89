"""Reference images to fit: loading, masks, and matching them to a scene's camera.

The pixels a fit uses are the sphere's pixels (per the scene's camera) that are finite,
not clipped (saturated LDR pixels carry no radiance value) and, when a mask image is
given, where the mask is non-zero.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ImageError
from ..scene.loading import Scene
from .images import Encoding, read_image


@dataclass(frozen=True)
class Target:
    """A reference image ready to fit: linear RGB ``pixels`` (H, W, 3) and ``usable`` (H, W),
    the pixels the fit may use before the sphere mask is applied."""

    pixels: np.ndarray
    usable: np.ndarray
    path: str
    encoding: str
    clipped_count: int
    masked_out_count: int


def load_target(path: str | Path, mask: str | Path | None = None, encoding: Encoding = "auto") -> Target:
    """Read a reference image (and an optional mask image: non-zero = use the pixel).

    Non-finite pixels are an error (a NaN in a reference is a broken file, not data).
    """
    image = read_image(path, encoding=encoding)
    pixels = image.pixels
    bad = ~np.all(np.isfinite(pixels), axis=-1)
    if bad.any():
        raise ImageError(f"target {path} has {int(bad.sum())} pixel(s) with NaN or infinite values")
    usable = ~image.clipped
    masked_out = 0
    if mask is not None:
        mask_image = read_image(mask, encoding="linear").pixels
        if mask_image.shape[:2] != pixels.shape[:2]:
            raise ImageError(
                f"mask {mask} is {mask_image.shape[1]}x{mask_image.shape[0]} but the target is "
                f"{pixels.shape[1]}x{pixels.shape[0]}"
            )
        keep = np.any(mask_image > 0, axis=-1)
        masked_out = int((~keep).sum())
        usable = usable & keep
    return Target(pixels, usable, str(path), image.encoding, int(image.clipped.sum()), masked_out)


def match_scene(scene: Scene, target: Target) -> tuple[Scene, str | None]:
    """The scene with its camera at the target's size, and a message if it was changed.

    The camera's image plane is defined in normalised coordinates, so a target of another
    size but the same aspect ratio is fitted by rendering at the target's size (no
    resampling of the data). A different aspect ratio is an error.
    """
    height, width = target.pixels.shape[:2]
    if (height, width) == scene.shape:
        return scene, None
    if width * scene.camera.height != height * scene.camera.width:
        raise ImageError(
            f"target {target.path} is {width}x{height} but the scene's camera is "
            f"{scene.camera.width}x{scene.camera.height} (a different aspect ratio); "
            "resize the target or change [camera] width/height"
        )
    message = (
        f"the scene's camera is {scene.camera.width}x{scene.camera.height} and the target "
        f"{width}x{height}: rendering at the target's size"
    )
    return scene.resized(width, height), message


#: The most pixels a fit works on: a larger target is fitted box-averaged to at most this
#: many (`reduce_target`), so that any image the scene format allows (8192 × 8192)
#: fits in a few GB. A 1024 × 1024 sphere has 820 000 pixels, far more than the handful
#: of parameters need.
MAX_FIT_PIXELS = 1024 * 1024


def reduce_target(scene: Scene, target: Target, limit: int = MAX_FIT_PIXELS) -> tuple[Scene, Target, str | None]:
    """``scene`` and ``target`` as a fit sees them: unchanged up to ``limit`` pixels; above
    it, the target averaged over k × k blocks (the smallest k that divides both sides and
    brings it under the limit: what a camera of k times fewer pixels per side records) and
    the scene's camera at that size, with a message saying so. A block is usable when all
    its pixels are. Averaging keeps what the fit needs — the shading is smooth over a few
    pixels, silhouette blocks are left out like silhouette pixels, and the noise estimated
    from the averaged image is that of the averaged image."""
    height, width = target.pixels.shape[:2]
    if height * width <= limit:
        return scene, target, None
    for k in range(2, min(height, width) + 1):
        if height % k == 0 and width % k == 0 and (height // k) * (width // k) <= limit:
            break
    else:
        raise ImageError(
            f"target {target.path} is {width}x{height}: more than {limit} pixels and no block size divides both "
            "sides; resize it (or crop it to sides with a common factor)"
        )
    h, w = height // k, width // k
    pixels = target.pixels.reshape(h, k, w, k, 3).mean(axis=(1, 3))
    usable = target.usable.reshape(h, k, w, k).all(axis=(1, 3))
    reduced = Target(pixels, usable, target.path, target.encoding, target.clipped_count, target.masked_out_count)
    message = (
        f"the target is {width}x{height}: fitted averaged over {k}x{k} blocks, at {w}x{h} "
        f"(at most {limit} pixels; the fitted image is at that size)"
    )
    return scene.resized(w, h), reduced, message
