r"""Wavefront ``.mtl`` material libraries: reading them as Phong materials, writing them.

Reading (:func:`parse_mtl`, :func:`read_mtl`) maps each ``newmtl`` block to a
:class:`~strauss_fit.models.phong.PhongMaterial` plus an opacity and an index of refraction:

==============  ==========================================================================
statement       becomes
==============  ==========================================================================
``newmtl NAME`` a new material (NAME is the rest of the line)
``Ka r g b``    ``ka = (r, g, b)`` (the ambient colour; Phong's ``diffuse_color`` is white)
``Kd r g b``    ``kd = (r, g, b)``
``Ks r g b``    ``ks = (r, g, b)`` (``specular_color`` white)
``Ns n``        ``exponent = n`` (0 … 10000)
``d a``         opacity ``a`` in [0, 1] (``d -halo a`` is read as ``a``, with a note)
``Tr x``        opacity ``1 − x`` (ignored, with a note, when ``d`` is also given)
``Ni n``        index of refraction (Strauss needs n ≥ 1: a smaller value is taken as 1, with a note)
``illum k``     0 or 1: no highlight (``ks`` set to 0, with a note); 2 or more: kept,
                with a note above 2 (reflection and refraction are not part of Phong)
==============  ==========================================================================

A colour statement takes three numbers, or one (grey: ``g = b = r``, as the format allows);
``Ka spectral …`` and ``Ka xyz …`` are not supported (an error for that material).
Comments (``#`` to the end of the line) and blank lines are skipped. Texture maps and the
PBR extension (``map_Kd``, ``bump``, ``Pr``, ``Pm``, ``Ke``, ``Tf``, …) are ignored with a
note naming them; any other unknown statement is ignored with a note too.

Missing statements take OpenGL's default material — ``Ka 0.2``, ``Kd 0.8``, ``Ks 0``,
``Ns 0`` — and ``d 1``, ``Ni 1.5`` (the project's default n); each default used is noted.

Errors are per material: a malformed line (e.g. ``material 'steel' line 12: Kd needs 3
numbers (or 1 for grey), got 'Kd 0.5 0.5'``), a value out of range or a repeated material
name marks that material as failed (:attr:`MtlMaterial.error`) and the others are kept. A
statement before the first ``newmtl`` is reported in :attr:`MtlLibrary.notes` and ignored.

Writing (:func:`format_mtl`) emits ``Ka = ka·Cd``, ``Kd = kd·Cd``, ``Ks = ks·Cs``, ``Ns``,
``d``, ``Ni`` and ``illum 2`` for each material, so that reading the file back gives the
same rendering.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import StraussFitError
from ..models.phong import MAX_EXPONENT, PhongMaterial

#: OpenGL's default material, used for statements a material leaves out.
DEFAULTS = {"Ka": 0.2, "Kd": 0.8, "Ks": 0.0, "Ns": 0.0, "d": 1.0, "Ni": 1.5}
#: Statements that are known but carry nothing a Phong material can hold.
IGNORED = {
    "map_ka",
    "map_kd",
    "map_ks",
    "map_ns",
    "map_d",
    "map_tr",
    "map_bump",
    "bump",
    "map_disp",
    "disp",
    "decal",
    "refl",
    "map_refl",
    "ke",
    "map_ke",
    "tf",
    "sharpness",
    "pr",
    "pm",
    "ps",
    "pc",
    "pcr",
    "aniso",
    "anisor",
    "norm",
    "map_pr",
    "map_pm",
    "map_ps",
    "map_norm",
    "map_aat",
    "map_opacity",
}
COLOR_STATEMENTS = {"ka": "Ka", "kd": "Kd", "ks": "Ks"}


@dataclass
class MtlMaterial:
    """One ``newmtl`` block: the Phong material (None if the block has an error), opacity,
    index of refraction, the line it starts on, notes, and the error if any."""

    name: str
    line: int
    phong: PhongMaterial | None = None
    opacity: float = 1.0
    ior: float = 1.5
    notes: list[str] = field(default_factory=list)
    error: str | None = None


@dataclass
class MtlLibrary:
    """Every material of a library, in file order, and notes about the file as a whole."""

    source: str
    materials: list[MtlMaterial]
    notes: list[str] = field(default_factory=list)


class _Block:
    def __init__(self, name: str, line: int, source: str):
        self.name, self.line, self.source = name, line, source
        self.values: dict[str, Any] = {}
        self.where: dict[str, int] = {}
        self.notes: list[str] = []
        self.error: str | None = None

    def fail(self, line: int, message: str) -> None:
        if self.error is None:  # the first problem is the one reported
            self.error = f"material '{self.name}' line {line}: {message}"


def _numbers(tokens: list[str]) -> list[float] | None:
    try:
        values = [float(t) for t in tokens]
    except ValueError:
        return None
    return values if all(math.isfinite(v) for v in values) else None


def parse_mtl(text: str, source: str = "<mtl>") -> MtlLibrary:
    """Parse the text of a ``.mtl`` library (see the module docstring)."""
    blocks: list[_Block] = []
    file_notes: list[str] = []
    seen: dict[str, int] = {}
    current: _Block | None = None
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split()
        keyword, args = parts[0], parts[1:]
        rest = line[len(keyword) :]
        key = keyword.lower()
        if key == "newmtl":
            name = rest.strip()
            if not name:
                file_notes.append(f"line {number}: newmtl without a name; the block is skipped")
                current = _Block(f"<unnamed, line {number}>", number, source)
                current.fail(number, "newmtl needs a name")
                blocks.append(current)
                continue
            current = _Block(name, number, source)
            if name in seen:
                current.fail(number, f"duplicate material name (first defined on line {seen[name]})")
            else:
                seen[name] = number
            blocks.append(current)
            continue
        if current is None:
            file_notes.append(f"line {number}: '{keyword}' before any newmtl; ignored")
            continue
        block = current
        if key in COLOR_STATEMENTS:
            label = COLOR_STATEMENTS[key]
            if args and args[0].lower() in ("spectral", "xyz"):
                block.fail(number, f"{label} {args[0]} is not supported (only r g b colours)")
                continue
            values = _numbers(args)
            if values is None or len(values) not in (1, 3):
                block.fail(number, f"{label} needs 3 numbers (or 1 for grey), got '{line}'")
                continue
            if len(values) == 1:
                values = values * 3
            if min(values) < 0:
                block.fail(number, f"{label} = {values} must not be negative")
                continue
            block.values[label] = values
            block.where[label] = number
        elif key in ("ns", "ni", "tr", "illum"):
            label = {"ns": "Ns", "ni": "Ni", "tr": "Tr", "illum": "illum"}[key]
            values = _numbers(args)
            if values is None or len(values) != 1:
                block.fail(number, f"{label} needs 1 number, got '{line}'")
                continue
            block.values[label] = values[0]
            block.where[label] = number
        elif key == "d":
            if args and args[0].lower() == "-halo":
                block.notes.append(f"line {number}: 'd -halo' read as a plain dissolve (no halo in Phong)")
                args = args[1:]
            values = _numbers(args)
            if values is None or len(values) != 1:
                block.fail(number, f"d needs 1 number, got '{line}'")
                continue
            block.values["d"] = values[0]
            block.where["d"] = number
        elif key in IGNORED:
            block.notes.append(f"line {number}: '{keyword}' ignored (textures and PBR extensions are not converted)")
        else:
            block.notes.append(f"line {number}: unknown statement '{keyword}' ignored")
    materials = [_finish(block) for block in blocks]
    return MtlLibrary(source, materials, file_notes)


def _finish(block: _Block) -> MtlMaterial:
    out = MtlMaterial(block.name, block.line, notes=list(block.notes))
    if block.error:
        out.error = block.error
        return out
    values = dict(block.values)
    for label in ("Ka", "Kd", "Ks", "Ns"):
        if label not in values:
            values[label] = [DEFAULTS[label]] * 3 if label != "Ns" else DEFAULTS[label]
            out.notes.append(f"{label} missing: taken as {DEFAULTS[label]:g} (OpenGL's default material)")
    ns = values["Ns"]
    if not 0 <= ns <= MAX_EXPONENT:
        block.fail(block.where["Ns"], f"Ns = {ns:g} is outside [0, {MAX_EXPONENT:g}]")
    if "d" in values:
        opacity = values["d"]
        if "Tr" in values:
            out.notes.append(f"line {block.where['Tr']}: Tr ignored because d is given")
        where = block.where["d"]
        what = "d"
    elif "Tr" in values:
        opacity = 1.0 - values["Tr"]
        where, what = block.where["Tr"], "Tr"
        if not 0 <= values["Tr"] <= 1:
            block.fail(where, f"Tr = {values['Tr']:g} is outside [0, 1]")
    else:
        opacity, where, what = DEFAULTS["d"], None, None
    if what == "d" and not 0 <= opacity <= 1:
        block.fail(where, f"d = {opacity:g} is outside [0, 1]")
    ior = values.get("Ni", DEFAULTS["Ni"])
    if "Ni" not in values:
        out.notes.append(f"Ni missing: taken as {DEFAULTS['Ni']:g}")
    elif ior < 1:
        out.notes.append(f"line {block.where['Ni']}: Ni = {ior:g} is below 1; taken as 1 (Strauss needs n >= 1)")
        ior = 1.0
    ks = values["Ks"]
    if "illum" in values:
        illum = values["illum"]
        if illum != int(illum) or not 0 <= illum <= 10:
            block.fail(block.where["illum"], f"illum must be an integer 0 to 10, got {illum:g}")
        elif illum in (0, 1):
            if max(ks) > 0:
                out.notes.append(f"line {block.where['illum']}: illum {int(illum)} has no highlight: Ks ignored")
            ks = [0.0, 0.0, 0.0]
        elif illum > 2:
            out.notes.append(
                f"line {block.where['illum']}: illum {int(illum)}: reflection/refraction modes are "
                "not part of Phong; the local model is converted"
            )
    if block.error:
        out.error = block.error
        return out
    out.phong = PhongMaterial(
        ka=values["Ka"],
        kd=values["Kd"],
        ks=ks,
        exponent=float(ns),
        diffuse_color=(1.0, 1.0, 1.0),
        specular_color=(1.0, 1.0, 1.0),
    )
    out.opacity = float(opacity)
    out.ior = float(ior)
    return out


def read_mtl(path: str | Path) -> MtlLibrary:
    """Read a ``.mtl`` file (a missing or unreadable file is a one-line error)."""
    path = Path(path)
    if not path.is_file():
        raise StraussFitError(f"material library not found: {path}")
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise StraussFitError(f"cannot read material library {path}: {exc}") from None
    return parse_mtl(text, str(path))


def _triple(values: Any) -> list[float]:
    arr = np.broadcast_to(np.asarray(values, dtype=np.float64), (3,))
    return [float(v) for v in arr]


def format_mtl_material(
    name: str, phong: dict[str, Any], opacity: float = 1.0, ior: float = 1.5, comment: str | None = None
) -> str:
    """One ``newmtl`` block for a Phong material given as :meth:`PhongMaterial.to_dict`."""
    cd = np.asarray(phong.get("diffuse_color", (1.0, 1.0, 1.0)), dtype=np.float64)
    cs = np.asarray(phong.get("specular_color", (1.0, 1.0, 1.0)), dtype=np.float64)
    lines = []
    if comment:
        lines += [f"# {c}" for c in comment.splitlines()]
    lines.append(f"newmtl {name}")
    for label, coefficient, colour in (
        ("Ka", phong.get("ka", 0.0), cd),
        ("Kd", phong.get("kd", 0.0), cd),
        ("Ks", phong.get("ks", 0.0), cs),
    ):
        rgb = np.asarray(_triple(coefficient)) * colour
        lines.append(f"{label} {rgb[0]:.6f} {rgb[1]:.6f} {rgb[2]:.6f}")
    lines.append(f"Ns {float(phong.get('exponent', 0.0)):.6f}")
    lines.append(f"d {float(opacity):.6f}")
    lines.append(f"Ni {float(ior):.6f}")
    lines.append("illum 2")
    return "\n".join(lines) + "\n"


def format_mtl(blocks: list[str], header: str | None = None) -> str:
    """A whole library from :func:`format_mtl_material` blocks."""
    head = "".join(f"# {line}\n" for line in (header or "").splitlines())
    return head + ("\n" if head else "") + "\n".join(blocks)
