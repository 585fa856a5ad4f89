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
