"""The file formats of material tables, by extension: what each kind of material is read
from and what each conversion writes. Plain data without the readers and writers
(:mod:`strauss_fit.io.material_tables` binds those to it), so that the command line builds
its help and checks extensions without importing the numerical stack."""

from __future__ import annotations

from collections.abc import Sequence

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
