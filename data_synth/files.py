"""Encoding a sample's files reproducibly (same pixels → same bytes).

- HDR: float32 linear OpenEXR (zip compression, no timestamp:
  `strauss_fit.io.images.encode_image`), so that the same seed gives byte-identical
  files.
- LDR: 8-bit PNG holding exactly the given sRGB codes.
- Clip mask: 8-bit single-channel PNG, 255 where the LDR image is clipped, 0 elsewhere.
- Float images with another compression or channel layout (the bundled Mitsuba targets:
  PXR24 images, a one-channel coverage): `float_exr_bytes`, read back with
  `decode_exr`.

The ``*_bytes`` functions encode in memory; `data_synth.generate` writes a sample's
files together through `strauss_fit.io.files.Outputs` (temporary files, every write
checked, then renamed together). The ``write_*`` functions write one file the same way.
"""

from __future__ import annotations

import hashlib
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from strauss_fit.errors import ImageError
from strauss_fit.io.images import encode_image, write_image


def exr_bytes(image: np.ndarray) -> bytes:
    """A linear RGB image (H, W, 3) as float32 OpenEXR bytes (no timestamp, zip)."""
    data = np.asarray(image, dtype=np.float32)
    if data.ndim != 3 or data.shape[-1] != 3:
        raise ImageError(f"cannot write an image of shape {data.shape} as OpenEXR")
    return encode_image(data, "sample.exr")


def float_exr_bytes(image: np.ndarray, *, compression: str = "zip", channel_names: tuple[str, ...] = ()) -> bytes:
    """A float image (H, W) or (H, W, C) as float32 OpenEXR bytes, no timestamp (same pixels,
    same bytes). ``compression``: an OpenEXR compression OpenImageIO knows, e.g. ``zip``
    (lossless) or ``pxr24`` (float32 rounded to 24 bits: relative error ≤ 1.5e-5, files
    less than half the size); ``channel_names`` default to OpenImageIO's (R, G, B, ...)."""
    import OpenImageIO as oiio

    data = np.asarray(image, dtype=np.float32)
    if data.ndim == 2:
        data = data[..., None]
    if data.ndim != 3 or not np.all(np.isfinite(data)):
        raise ImageError(f"cannot write an image of shape {data.shape} (or with non-finite values) as OpenEXR")
    data = np.ascontiguousarray(data)
    spec = oiio.ImageSpec(data.shape[1], data.shape[0], data.shape[2], oiio.FLOAT)
    spec.attribute("compression", compression)
    spec.attribute("DateTime", "")  # an empty value drops OpenImageIO's timestamp
    if channel_names:
        spec.channelnames = tuple(channel_names)
    return encoded_bytes(data, spec, "image.exr", "an OpenEXR image")


def encoded_bytes(data: np.ndarray, spec: Any, name: str, what: str) -> bytes:
    """``data`` encoded by OpenImageIO with ``spec`` into the format ``name``'s extension
    names (written to a scratch folder, since OpenImageIO encodes to files), or an
    `ImageError` naming ``what``."""
    with tempfile.TemporaryDirectory(prefix="strauss-fit-encode-") as folder:
        path = str(Path(folder) / name)
        import OpenImageIO as oiio

        output = oiio.ImageOutput.create(path)
        ok = output is not None and output.open(path, spec) and output.write_image(data) and not output.has_error
        message = output.geterror() if output is not None and not ok else ""
        if output is not None and not output.close() and ok:
            message, ok = output.geterror(), False
        if not ok:
            raise ImageError(f"cannot encode {what}: {message or 'the encoder failed'}")
        return Path(path).read_bytes()


def decode_exr(data: bytes) -> np.ndarray:
    """The pixels (H, W, C) float64 of OpenEXR bytes (see `float_exr_bytes`)."""
    import OpenImageIO as oiio

    with tempfile.TemporaryDirectory(prefix="strauss-fit-exr-") as folder:
        path = Path(folder) / "image.exr"
        path.write_bytes(data)
        image_input = oiio.ImageInput.open(str(path))
        if image_input is None:
            raise ImageError(f"cannot decode OpenEXR bytes: {oiio.geterror()}")
        try:
            spec = image_input.spec()
            pixels = image_input.read_image(0, 0, 0, spec.nchannels, "float")
        finally:
            image_input.close()
    if pixels is None:
        raise ImageError("cannot decode OpenEXR bytes")
    return np.asarray(pixels, dtype=np.float64).reshape(spec.height, spec.width, spec.nchannels)


def codes_bytes(codes: np.ndarray) -> bytes:
    """8-bit codes (H, W, C) uint8 as PNG bytes, unchanged."""
    values = np.asarray(codes, dtype=np.float64) / 255.0
    return encode_image(values, "sample.png", encoding="linear")  # round(code/255·255) = code


def mask_bytes(mask: np.ndarray) -> bytes:
    """A boolean mask (H, W) as a grey 8-bit PNG: 255 where true."""
    return codes_bytes(np.asarray(mask, dtype=np.uint8)[..., None] * 255)


def write_exr(path: str | Path, image: np.ndarray, *, force: bool = False) -> Path:
    """Write a linear RGB image (H, W, 3) as float32 OpenEXR (no timestamp, zip)."""
    data = np.asarray(image, dtype=np.float32)
    if data.ndim != 3 or data.shape[-1] != 3:
        raise ImageError(f"cannot write an image of shape {data.shape} to {path}")
    return write_image(path, data, force=force)


def write_codes(path: str | Path, codes: np.ndarray, *, force: bool = False) -> Path:
    """Write 8-bit codes (H, W, C) uint8 to an LDR file unchanged."""
    values = np.asarray(codes, dtype=np.float64) / 255.0
    return write_image(path, values, force=force, encoding="linear")


def write_mask(path: str | Path, mask: np.ndarray, *, force: bool = False) -> Path:
    """Write a boolean mask (H, W) as a grey 8-bit PNG: 255 where true."""
    return write_codes(path, np.asarray(mask, dtype=np.uint8)[..., None] * 255, force=force)


def sha256(path: str | Path) -> str:
    """Hex SHA-256 of a file's bytes."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def sha256_bytes(data: bytes) -> str:
    """Hex SHA-256 of bytes."""
    return hashlib.sha256(data).hexdigest()
