"""Reading and writing images (OpenImageIO), safely.

- HDR formats (``.exr``, ``.hdr``, ``.tif``/``.tiff``, ``.pfm``) hold linear float radiance.
- LDR formats (``.png``, ``.jpg``/``.jpeg``, ``.bmp``, ``.tga``) hold sRGB-encoded 8-bit
  values; they are decoded to linear with colour-science's sRGB transfer function on
  reading and encoded (clipped to [0, 1], rounded to 8 bits) on writing. Saturated
  pixels (any channel at the top code value) are reported as *clipped*: their true
  radiance is unknown, so fits ignore them.

Reading goes by the file's real format, not its name (a PNG renamed ``.exr`` is still
decoded from sRGB), and a damaged file is refused: a truncated JPEG, whose decoder fills
the missing part with grey and only warns, is an error here.

Writing encodes the image in memory first (an anonymous in-memory file on Linux: some
image libraries end the whole process when the disk fills up under them) and then writes
the bytes through `strauss_fit.io.files.Outputs`: atomically, every write checked,
and an existing file is never overwritten unless ``force`` is true. Written images carry
no timestamp, so the same pixels always give the same bytes (reproducible datasets).
"""

from __future__ import annotations

import os
import stat
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Literal, NamedTuple

import numpy as np

from ..color import srgb_decode, srgb_encode
from ..errors import ImageError
from .files import Outputs, check_input_file, check_writable

# The extensions and how each is written are plain data in table_formats (the command line
# reads them without NumPy); HDR_EXTENSIONS and LDR_EXTENSIONS stay importable from here.
from .table_formats import HDR_EXTENSIONS as HDR_EXTENSIONS
from .table_formats import IMAGE_ENCODINGS, IMAGE_FORMATS
from .table_formats import LDR_EXTENSIONS as LDR_EXTENSIONS

#: OpenImageIO format names whose integer pixels are sRGB-encoded (decoded from sRGB by default).
LDR_FORMATS = ("png", "jpeg", "bmp", "targa", "gif", "webp", "ico", "pnm", "jpeg2000")
Encoding = Literal["auto", "linear", "srgb"]


class LoadedImage(NamedTuple):
    """A decoded image: ``pixels`` linear RGB float64 (H, W, 3); ``clipped`` (H, W) bool,
    true where an LDR pixel is saturated; ``encoding`` the decoding applied; ``bits`` the
    stored integer depth (8, 16, ...), None for floating-point files."""

    pixels: np.ndarray
    clipped: np.ndarray
    encoding: str
    bits: int | None = None


def _oiio():
    import OpenImageIO as oiio  # imported lazily: it is only needed for image files

    return oiio


def default_encoding(path: str | Path) -> str:
    """``"srgb"`` for LDR extensions, ``"linear"`` otherwise
    (`strauss_fit.io.table_formats.ImageFormat.encoding`)."""
    image_format = IMAGE_FORMATS.get(Path(path).suffix.lower())
    return "linear" if image_format is None else image_format.encoding


def _first_line(text: str, fallback: str) -> str:
    lines = [line.strip() for line in (text or "").strip().splitlines() if line.strip()]
    return lines[0] if lines else fallback


#: Bytes per pixel and channel a read image occupies at its peak: the decoder's float32
#: copy of every channel plus the float64 RGB pixels and a working copy of them.
_READ_BYTES = (4, 2 * 3 * 8)


def check_memory_for(path: str | Path, width: int, height: int, channels: int) -> None:
    """Refuse, before reading it, an image too large for the memory there is."""
    from ..runtime import available_memory

    need = width * height * (_READ_BYTES[0] * channels + _READ_BYTES[1])
    have = available_memory()
    if have is not None and need > have:
        raise ImageError(
            f"image {path} is {width}x{height}: reading it needs about {need / 2**30:.1f} GB of memory, "
            f"and {have / 2**30:.1f} GB are available"
        )


def read_image(path: str | Path, encoding: Encoding = "auto") -> LoadedImage:
    """Read any image OpenImageIO reads, as linear RGB.

    ``encoding="auto"`` decodes LDR formats from sRGB and takes HDR formats as linear, by
    the file's real format; ``"linear"`` or ``"srgb"`` override that. Grey images are
    replicated to RGB; an alpha channel is ignored (the colour channels are read as
    stored, never premultiplied by it). A damaged or truncated file, and a path that is not
    a regular file (`check_input_file`), are an
    `ImageError`.
    """
    path = check_input_file(path, "image", ImageError)  # never open a FIFO: it blocks
    if encoding not in IMAGE_ENCODINGS:
        raise ImageError(f"unknown encoding {encoding!r}; expected auto, linear or srgb")
    oiio = _oiio()
    # The colour channels as stored: OpenImageIO would otherwise premultiply them by an
    # unassociated alpha (PNG, GIF, ...), so that a PNG whose alpha is 0 reads as black
    # although its RGB holds the picture. Alpha is ignored, whatever the format.
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    with _readable_copy(path) as readable:
        return _decode(oiio, path, readable, config, encoding)


def _readable_suffixes(oiio) -> set[str]:
    """The file suffixes OpenImageIO has a reader for (``exr``, ``png``, ...)."""
    suffixes = set()
    for entry in oiio.get_string_attribute("extension_list").split(";"):
        suffixes.update(entry.partition(":")[2].split(","))
    return suffixes - {""}


def _decode(oiio, path: Path, readable: str, config, encoding: Encoding) -> LoadedImage:
    """`read_image`'s decoding of the file at ``readable`` (``path``'s bytes)."""
    image_input = oiio.ImageInput.open(readable, config)
    if image_input is None:
        detail = _first_line(oiio.geterror(), "unknown format").replace(readable, str(path))
        # OpenImageIO blames the format when a file of a format it reads is empty or cut short
        if os.path.getsize(readable) == 0:
            detail = "the file is empty"
        elif "could not find a format reader" in detail and path.suffix.lower().lstrip(".") in _readable_suffixes(oiio):
            detail = f"not a readable {path.suffix.lower()} file (damaged or truncated?)"
        raise ImageError(f"cannot read image {path}: {detail}")
    try:
        spec = image_input.spec()
        if spec.width < 1 or spec.height < 1 or spec.nchannels < 1:
            raise ImageError(f"cannot read image {path}: it holds no pixels")
        check_memory_for(path, spec.width, spec.height, spec.nchannels)
        raw = image_input.read_image(0, 0, 0, spec.nchannels, "float")
        # a decoder may fill a truncated file and only warn ("Premature end of JPEG file")
        damaged = image_input.has_error
        detail = image_input.geterror() if damaged or raw is None else ""
        if raw is None or damaged:
            raise ImageError(f"cannot read image {path}: {_first_line(detail, 'corrupt or truncated data')}")
        integer = spec.format.basetype not in (oiio.FLOAT, oiio.HALF, oiio.DOUBLE)
        bits = spec.format.size() * 8 if integer else None
        # a file may store fewer bits than its container (a 12-bit camera in 16-bit PNG)
        declared = spec.get_int_attribute("oiio:BitsPerSample", 0)
        if integer and 0 < declared < bits:
            bits = declared
        real_format = image_input.format_name()
    finally:
        image_input.close()
        oiio.geterror()  # clear anything left pending
    pixels = np.asarray(raw, dtype=np.float64)
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    channels = pixels.shape[-1]
    if channels in (1, 2):
        pixels = np.repeat(pixels[..., :1], 3, axis=-1)
    else:
        pixels = pixels[..., :3]
    if encoding == "auto":
        encoding = "srgb" if integer and real_format in LDR_FORMATS else "linear"
    clipped = np.any(pixels >= 1.0, axis=-1) if integer else np.zeros(pixels.shape[:2], dtype=bool)
    if encoding == "srgb":
        pixels = srgb_decode(pixels)
    return LoadedImage(pixels, clipped, encoding, bits)


def check_image_output(path: str | Path, force: bool = False) -> Path:
    """Refuse, before any work, an image output that exists (without ``force``), whose
    folder is missing, or whose extension no image writer knows."""
    path = check_writable(path, force)
    oiio = _oiio()
    output = oiio.ImageOutput.create(str(path))
    if output is None:
        oiio.geterror()  # clear OpenImageIO's pending message; ours says it in one line
        raise _no_writer(path)
    return path


def _no_writer(path: Path) -> ImageError:
    """The error for an image output whose extension no image writer knows, listing the
    formats of `IMAGE_FORMATS`."""
    return ImageError(
        f"no image writer for {path.suffix or 'files without extension'}: {path}; "
        f"expected one of {', '.join(IMAGE_FORMATS)}"
    )


#: How `encode_image` stores pixels: a function of the linear image (H, W, C), the
#: encoding (``"linear"`` or ``"srgb"``), the output path and the OpenImageIO module,
#: giving the array to write and its OpenImageIO pixel type.
PixelWriter = Callable[[np.ndarray, str, Path, Any], tuple[np.ndarray, Any]]


def _eight_bit(image: np.ndarray, encoding: str, path: Path, oiio: Any) -> tuple[np.ndarray, Any]:
    """LDR files: 8-bit values, sRGB-encoded (or, with ``encoding="linear"``, as they are),
    clipped to [0, 1]."""
    encoded = srgb_encode(image) if encoding == "srgb" else np.clip(image, 0.0, 1.0)
    return np.round(encoded * 255.0).astype(np.uint8), oiio.UINT8


def _float32(image: np.ndarray, encoding: str, path: Path, oiio: Any) -> tuple[np.ndarray, Any]:
    """HDR files (and any other extension OpenImageIO writes): float32 linear values."""
    if np.max(np.abs(image)) > np.finfo(np.float32).max:  # would be written as infinity
        raise ImageError(f"refusing to write pixel values that overflow float32 (above 3.4e38) to {path}")
    return np.ascontiguousarray(image.astype(np.float32)), oiio.FLOAT


#: The pixel writer of each image format (`IMAGE_FORMATS`,
#: keyed by the same extensions); another extension is written by `_float32`.
IMAGE_WRITERS: dict[str, PixelWriter] = {
    suffix: _eight_bit if image_format.ldr else _float32 for suffix, image_format in IMAGE_FORMATS.items()
}


def _memory_file(name: str) -> int | None:
    """The descriptor of a new anonymous in-memory file, reachable as
    ``/proc/self/fd/N``; None where the system has none."""
    if not (hasattr(os, "memfd_create") and Path("/proc/self/fd").is_dir()):
        return None
    try:
        return os.memfd_create(name)
    except OSError:
        return None


#: Bytes per read when an input is copied into memory (`_readable_copy`).
_READ_CHUNK = 1 << 24


@contextmanager
def _readable_copy(path: Path) -> Iterator[str]:
    """A path from which OpenImageIO reads ``path``'s bytes without touching ``path``: an
    anonymous in-memory copy made by Python where the system has them, else ``path``.

    OpenImageIO opens and reads files inside compiled code that holds Python's global
    lock, where Ctrl-C cannot reach: a file that blocks (a FIFO swapped in after the check,
    a hung network file system) would hang the command for good. Python's own reads wait
    with the lock released and let a signal handler raise, so Ctrl-C ends the read (exit
    130). The file is opened non-blocking and must still be a regular file once open."""
    fd = _memory_file("strauss-fit-input")
    if fd is None:
        yield str(path)
        return
    try:
        try:
            source = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
        except OSError as exc:
            raise ImageError(f"cannot read image {path}: {exc.strerror or exc}") from None
        try:
            if not stat.S_ISREG(os.fstat(source).st_mode):
                raise ImageError(f"image {path} is not a regular file")
            while chunk := os.read(source, _READ_CHUNK):
                view = memoryview(chunk)
                while view:
                    view = view[os.write(fd, view) :]
        except OSError as exc:
            raise ImageError(f"cannot read image {path}: {exc.strerror or exc}") from None
        finally:
            os.close(source)
        yield f"/proc/self/fd/{fd}"
    finally:
        os.close(fd)


@contextmanager
def _scratch_file(suffix: str) -> Iterator[str]:
    """A path to encode an image into: an anonymous in-memory file where the system has
    them (it cannot run out of disk space), else a temporary file."""
    fd = _memory_file("strauss-fit-image")
    if fd is not None:
        try:
            yield f"/proc/self/fd/{fd}"
        finally:
            os.close(fd)
        return
    handle, name = tempfile.mkstemp(suffix=suffix)
    os.close(handle)
    try:
        yield name
    finally:
        Path(name).unlink(missing_ok=True)


def encode_image(image: np.ndarray, path: str | Path, *, encoding: Encoding = "auto") -> bytes:
    """The bytes of the image file ``path`` (its extension picks the format) holding the
    linear RGB image (H, W, 3): HDR formats store float32 linear values, LDR formats 8-bit
    values encoded with ``encoding`` (``"auto"``: sRGB), clipped to [0, 1]."""
    path = Path(path)
    image = np.asarray(image, dtype=np.float64)
    if image.ndim != 3 or image.shape[-1] not in (1, 3, 4) or image.shape[0] < 1 or image.shape[1] < 1:
        raise ImageError(f"cannot write an image of shape {image.shape} to {path}")
    if not np.all(np.isfinite(image)):
        raise ImageError(f"refusing to write non-finite pixel values to {path}")
    if encoding == "auto":
        encoding = default_encoding(path)
    if encoding not in ("linear", "srgb"):
        raise ImageError(f"unknown encoding {encoding!r}; expected auto, linear or srgb")
    oiio = _oiio()
    data, pixel_type = IMAGE_WRITERS.get(path.suffix.lower(), _float32)(image, encoding, path, oiio)
    output = oiio.ImageOutput.create(str(path))
    if output is None:
        oiio.geterror()
        raise _no_writer(path)
    spec = oiio.ImageSpec(data.shape[1], data.shape[0], data.shape[2], pixel_type)
    if pixel_type == oiio.FLOAT:
        spec.attribute("compression", "zip")
    spec.attribute("DateTime", "")  # an empty value drops OpenImageIO's timestamp
    with _scratch_file(path.suffix) as scratch:
        # every step checked: PNG reports a failed write only through geterror()
        ok = output.open(scratch, spec) and output.write_image(data) and not output.has_error
        message = output.geterror() if not ok else ""
        closed = output.close()
        if ok and not closed:
            message, ok = output.geterror(), False
        if not ok:
            raise ImageError(f"cannot write {path}: {_first_line(message, 'the image encoder failed')}")
        with open(scratch, "rb") as handle:
            return handle.read()


def add_image(out: Outputs, path: str | Path, image: np.ndarray, *, encoding: Encoding = "auto") -> Path:
    """Stage a linear RGB image (H, W, 3), encoded for ``path`` (`encode_image`), among
    ``out``'s outputs: written when they are committed, all of them or none. A function here
    rather than a method of `Outputs`, so that the atomic
    writer does not import the image codecs that write through it."""
    path = check_writable(path, out.force)
    return out.add_bytes(path, encode_image(image, path, encoding=encoding))


def write_image(path: str | Path, image: np.ndarray, *, force: bool = False, encoding: Encoding = "auto") -> Path:
    """Write a linear RGB image (H, W, 3) atomically (see `encode_image`)."""
    with Outputs(force=force) as out:
        add_image(out, path, image, encoding=encoding)
        return out.commit()[0]
