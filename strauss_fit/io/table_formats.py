"""The file formats strauss-fit reads and writes, by extension: the images it writes and
the material tables of a conversion. Plain data without the readers and writers
(`strauss_fit.io.images` and `strauss_fit.io.material_tables` bind those to it,
keyed by the same extensions), so that the command line builds its help and checks
extensions without importing the numerical stack."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

# --- images ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class ImageFormat:
    """How an image file of one extension is written (and, by default, read)."""

    #: The extension, lower case with its dot: ``".exr"``.
    suffix: str
    #: 8-bit integer values, sRGB-encoded and clipped to [0, 1] by default; else float32
    #: linear radiance.
    ldr: bool

    @property
    def encoding(self) -> str:
        """The default encoding of its values: ``"srgb"`` for 8-bit files, else ``"linear"``."""
        return "srgb" if self.ldr else "linear"


#: The image formats strauss-fit writes (`strauss_fit.io.images.encode_image`), by
#: extension: HDR formats as linear float32, LDR formats as 8-bit sRGB. Another extension
#: OpenImageIO writes is written as linear float32 too, converted by OpenImageIO as that
#: format stores it.
IMAGE_FORMATS: dict[str, ImageFormat] = {
    image_format.suffix: image_format
    for image_format in (
        *(ImageFormat(suffix, ldr=False) for suffix in (".exr", ".hdr", ".tif", ".tiff", ".pfm")),
        *(ImageFormat(suffix, ldr=True) for suffix in (".png", ".jpg", ".jpeg", ".bmp", ".tga")),
    )
}
#: The extensions of HDR images (linear float values).
HDR_EXTENSIONS: tuple[str, ...] = tuple(suffix for suffix, image in IMAGE_FORMATS.items() if not image.ldr)
#: The extensions of LDR images (8-bit sRGB values).
LDR_EXTENSIONS: tuple[str, ...] = tuple(suffix for suffix, image in IMAGE_FORMATS.items() if image.ldr)


#: How an input image's values are decoded (`strauss_fit.io.images.read_image`):
#: ``"auto"`` by the file's real format (sRGB for 8-bit formats), or as named.
IMAGE_ENCODINGS = ("auto", "linear", "srgb")


def describe_image_formats() -> str:
    """``.exr, .hdr, .tif, .tiff or .pfm are written as linear float; .png, ... are
    sRGB-encoded and clipped to 8 bits``: the image formats for a help text."""
    return (
        f"{describe_suffixes(HDR_EXTENSIONS)} are written as linear float; {describe_suffixes(LDR_EXTENSIONS)} are "
        "sRGB-encoded and clipped to 8 bits"
    )


# --- material tables -------------------------------------------------------------------------

#: The two conversions between models.
DIRECTIONS = ("phong2strauss", "strauss2phong")
#: The extensions each kind of material is read from (a Wavefront ``.mtl`` library holds
#: Phong materials only).
INPUT_SUFFIXES_BY_KIND = {"phong": (".json", ".csv", ".mtl"), "strauss": (".json", ".csv")}
#: Every extension a material file may have.
INPUT_SUFFIXES = (".json", ".csv", ".mtl")
#: A conversion's output formats by extension: the format's name and the directions that
#: can write it (a ``.mtl`` library holds Phong materials, hence Strauss → Phong only).
OUTPUT_FORMATS: dict[str, tuple[str, tuple[str, ...]]] = {
    ".json": ("json", DIRECTIONS),
    ".csv": ("csv", DIRECTIONS),
    ".mtl": ("mtl", ("strauss2phong",)),
}


def describe_suffixes(suffixes: Sequence[str]) -> str:
    """``.json, .csv or .mtl``: a list of extensions for a message or a help text."""
    suffixes = list(suffixes)
    return suffixes[0] if len(suffixes) == 1 else f"{', '.join(suffixes[:-1])} or {suffixes[-1]}"


def output_suffixes(direction: str) -> list[str]:
    """The extensions a conversion in ``direction`` can write."""
    return [suffix for suffix, (_, directions) in OUTPUT_FORMATS.items() if direction in directions]
