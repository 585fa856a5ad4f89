"""Reading and writing images (OpenImageIO) and results, safely.

- HDR formats (``.exr``, ``.hdr``, ``.tif``/``.tiff``, ``.pfm``) hold linear float radiance.
- LDR formats (``.png``, ``.jpg``/``.jpeg``, ``.bmp``, ``.tga``) hold sRGB-encoded 8-bit
  values; they are decoded to linear with colour-science's sRGB transfer function on
  reading and encoded (clipped to [0, 1], rounded to 8 bits) on writing. Saturated
  pixels (any channel at the top code value) are reported as *clipped*: their true
  radiance is unknown, so fits ignore them.

Every write is atomic (a temporary file in the same folder, then a rename), and an existing
file is never overwritten unless ``force`` is true. Written images carry no timestamp, so the
same pixels always give the same bytes (reproducible datasets).
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any, Literal, NamedTuple

import numpy as np

from .errors import ImageError, OutputExistsError

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


def srgb_decode(values: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0, 1] to linear (IEC 61966-2-1, via colour-science)."""
    import colour

    return np.asarray(colour.cctf_decoding(np.asarray(values, dtype=np.float64), function="sRGB"))


def srgb_encode(values: np.ndarray) -> np.ndarray:
    """Linear values to sRGB-encoded values; the input is clipped to [0, 1] first."""
    import colour

    clipped = np.clip(np.asarray(values, dtype=np.float64), 0.0, 1.0)
    return np.asarray(colour.cctf_encoding(clipped, function="sRGB"))


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


def check_writable(path: str | Path, force: bool) -> Path:
    """Refuse an existing output without ``force`` and a missing parent folder."""
    path = Path(path)
    if path.is_dir():
        raise ImageError(f"output path is a directory: {path}")
    if path.exists() and not force:
        raise OutputExistsError(f"output {path} exists; pass --force to overwrite it")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise ImageError(f"output folder does not exist: {parent}")
    if not os.access(parent, os.W_OK):
        raise ImageError(f"output folder is not writable: {parent}")
    return path


def _atomic(path: Path, write) -> None:
    """Call ``write(tmp_path)`` on a temporary sibling of ``path``, then rename it over
    ``path``; the temporary file is removed if anything fails."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=path.suffix, dir=path.parent or ".")
    os.close(fd)
    try:
        write(Path(tmp))
        # mkstemp creates the file owner-only; give the result the usual umask permissions
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


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

    _atomic(path, write)
    return path


def write_bytes(path: str | Path, data: bytes, *, force: bool = False) -> Path:
    """Write bytes (e.g. an encoded PNG) atomically (refusing to overwrite without ``force``)."""
    path = check_writable(path, force)
    _atomic(path, lambda tmp: tmp.write_bytes(data))
    return path


def write_text(path: str | Path, text: str, *, force: bool = False) -> Path:
    """Write a text file atomically (refusing to overwrite without ``force``)."""
    path = check_writable(path, force)
    _atomic(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))
    return path


def write_json(path: str | Path, data: Any, *, force: bool = False) -> Path:
    """Write JSON atomically; NaN/inf are refused (they are not JSON)."""
    return write_text(path, json.dumps(data, indent=2, allow_nan=False) + "\n", force=force)


def read_json(path: str | Path, what: str = "JSON file") -> Any:
    """Read a JSON file, with one-line errors."""
    from .errors import StraussFitError

    path = Path(path)
    if not path.is_file():
        raise StraussFitError(f"{what} not found: {path}")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise StraussFitError(f"cannot read {what} {path}: {exc}") from None
