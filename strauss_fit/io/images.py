"""Reading and writing images (OpenImageIO), safely.

- HDR formats (``.exr``, ``.hdr``, ``.tif``/``.tiff``, ``.pfm``) hold linear float radiance.
- LDR formats (``.png``, ``.jpg``/``.jpeg``, ``.bmp``, ``.tga``) hold sRGB-encoded 8-bit
  values; they are decoded to linear with colour-science's sRGB transfer function on
  reading and encoded (clipped to [0, 1], rounded to 8 bits) on writing. Saturated
  pixels (any channel at the top code value) are reported as *clipped*: their true
  radiance is unknown, so fits ignore them.

Every write is atomic and an existing file is never overwritten unless ``force`` is true
(:mod:`strauss_fit.io.files`). Written images carry no timestamp, so the same pixels always
give the same bytes (reproducible datasets).
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal, NamedTuple

import numpy as np

from ..color import srgb_decode, srgb_encode
from ..errors import ImageError
from . import files
from .files import check_writable

HDR_EXTENSIONS = (".exr", ".hdr", ".tif", ".tiff", ".pfm")
LDR_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tga")
Encoding = Literal["auto", "linear", "srgb"]


class LoadedImage(NamedTuple):
    """A decoded image: ``pixels`` linear RGB float64 (H, W, 3); ``clipped`` (H, W) bool,
    true where an LDR pixel is saturated; ``encoding`` the decoding applied."""

    pixels: np.ndarray
    clipped: np.ndarray
    encoding: str


def _oiio():
    import OpenImageIO as oiio  # imported lazily: it is only needed for image files

    return oiio


def default_encoding(path: str | Path) -> str:
    """``"srgb"`` for LDR extensions, ``"linear"`` otherwise."""
    return "srgb" if Path(path).suffix.lower() in LDR_EXTENSIONS else "linear"


def read_image(path: str | Path, encoding: Encoding = "auto") -> LoadedImage:
    """Read any image OpenImageIO reads, as linear RGB.

    ``encoding="auto"`` decodes LDR formats from sRGB and takes HDR formats as linear;
    ``"linear"`` or ``"srgb"`` override that. Grey images are replicated to RGB; an alpha
    channel is ignored.
    """
    path = Path(path)
    if not path.exists():
        raise ImageError(f"image not found: {path}")
    if path.is_dir():
        raise ImageError(f"image path is a directory: {path}")
    oiio = _oiio()
    image_input = oiio.ImageInput.open(str(path))
    if image_input is None:
        detail = oiio.geterror().strip().splitlines()
        raise ImageError(f"cannot read image {path}: {detail[0] if detail else 'unknown format'}")
    try:
        spec = image_input.spec()
        raw = image_input.read_image(0, 0, 0, spec.nchannels, "float")
        if raw is None:
            detail = image_input.geterror().strip().splitlines()
            raise ImageError(f"cannot read image {path}: {detail[0] if detail else 'corrupt data'}")
        integer = spec.format.basetype not in (oiio.FLOAT, oiio.HALF, oiio.DOUBLE)
    finally:
        image_input.close()
    pixels = np.asarray(raw, dtype=np.float64)
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    channels = pixels.shape[-1]
    if channels in (1, 2):
        pixels = np.repeat(pixels[..., :1], 3, axis=-1)
    else:
        pixels = pixels[..., :3]
    if encoding == "auto":
        encoding = default_encoding(path)
    if encoding not in ("linear", "srgb"):
        raise ImageError(f"unknown encoding {encoding!r}; expected auto, linear or srgb")
    clipped = np.any(pixels >= 1.0, axis=-1) if integer else np.zeros(pixels.shape[:2], dtype=bool)
    if encoding == "srgb":
        pixels = srgb_decode(pixels)
    return LoadedImage(pixels, clipped, encoding)


def write_image(path: str | Path, image: np.ndarray, *, force: bool = False, encoding: Encoding = "auto") -> Path:
    """Write a linear RGB image (H, W, 3) atomically.

    HDR formats store float32 linear values; LDR formats store 8-bit values encoded with
    ``encoding`` (``"auto"``: sRGB), clipped to [0, 1].
    """
    path = check_writable(path, force)
    image = np.asarray(image, dtype=np.float64)
    if image.ndim != 3 or image.shape[-1] not in (1, 3, 4):
        raise ImageError(f"cannot write an image of shape {image.shape} to {path}")
    if not np.all(np.isfinite(image)):
        raise ImageError(f"refusing to write non-finite pixel values to {path}")
    if encoding == "auto":
        encoding = default_encoding(path)
    oiio = _oiio()
    if Path(path).suffix.lower() in LDR_EXTENSIONS:
        encoded = srgb_encode(image) if encoding == "srgb" else np.clip(image, 0.0, 1.0)
        data = np.round(encoded * 255.0).astype(np.uint8)
        pixel_type = oiio.UINT8
    else:
        data = np.ascontiguousarray(image.astype(np.float32))
        pixel_type = oiio.FLOAT

    def write(tmp: Path) -> None:
        output = oiio.ImageOutput.create(str(path))
        if output is None:
            oiio.geterror()  # clear OpenImageIO's pending message; ours says it in one line
            raise ImageError(f"no image writer for {path.suffix or 'files without extension'}: {path}")
        spec = oiio.ImageSpec(data.shape[1], data.shape[0], data.shape[2], pixel_type)
        if pixel_type == oiio.FLOAT:
            spec.attribute("compression", "zip")
        spec.attribute("DateTime", "")  # an empty value drops OpenImageIO's timestamp
        if not output.open(str(tmp), spec) or not output.write_image(data):
            message = output.geterror().strip().splitlines()
            output.close()
            raise ImageError(f"cannot write {path}: {message[0] if message else 'write failed'}")
        output.close()

    files.write_atomic(path, write)  # looked up at call time: one writer for every file
    return path
