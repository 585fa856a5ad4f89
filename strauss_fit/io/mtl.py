r"""Wavefront ``.mtl`` material libraries: reading them as Phong materials, writing them.

Reading (`parse_mtl`, `read_mtl`) maps each ``newmtl`` block to Phong values
(a `PhongMaterial` on demand) plus an opacity and an
index of refraction:

==============  ==========================================================================
statement       becomes
==============  ==========================================================================
``newmtl NAME`` a new material; NAME is the rest of the line, exactly (spaces and ``#``
                included, as in ``newmtl 01 - Default`` or Assimp's ``Material #112``)
``Ka r g b``    ``ka = (r, g, b)`` (the ambient colour; Phong's ``diffuse_color`` is white)
``Kd r g b``    ``kd = (r, g, b)``
``Ks r g b``    ``ks = (r, g, b)`` (``specular_color`` white)
``Ns n``        ``exponent = n`` (0 … 10000)
``d a``         opacity ``a`` in [0, 1] (``d -halo a`` is read as ``a``, with a note)
``Tr x``        opacity ``1 − x`` (ignored, with a note, when ``d`` is also given)
``Tf r g b``    with a refracting ``illum`` (4, 6, 7, 9) and no ``d``/``Tr`` below 1: the
                transmission, opacity ``1 − mean(r, g, b)`` (a glass); otherwise ignored
                with a note (3ds Max writes ``Tf 1 1 1`` for every material)
``Ni n``        index of refraction (Strauss needs n ≥ 1: a smaller value is taken as 1, with a note)
``illum k``     0 or 1: no highlight (``ks`` set to 0, with a note); 2 or more: kept,
                with a note above 2 (reflection and refraction are not part of Phong)
==============  ==========================================================================

A colour statement takes three numbers, or one (grey: ``g = b = r``, as the format allows);
``Ka spectral …`` and ``Ka xyz …`` are not supported (an error for that material), nor
are NaN or infinite values. Comments (``#`` to the end of the line, except on a ``newmtl``
line) and blank lines are skipped; CRLF line ends, tabs and trailing spaces are fine.
Texture maps (``map_Kd``, ``bump``, …) and the PBR extension (``Pr``, ``Pm``, ``Ke``, …)
are ignored with a note naming them; any other unknown statement is ignored with a note
too.

Missing statements take OpenGL's default material — ``Ka 0.2``, ``Kd 0.8``, ``Ks 0``,
``Ns 0`` — and ``d 1``, ``Ni 1.5`` (the project's default n); each default used is noted.

Warnings (`MtlMaterial.warnings`) flag values that are allowed but almost certainly
not meant: ``d 0`` (a fully transparent, invisible material: exporters such as Blender's
write it for opaque materials), a colour coefficient above 1 (the surface would reflect
more light than it receives), ``Ni`` above 3 (no common material refracts that much).

Errors are per material: a malformed line (e.g. ``material 'steel' line 12: Kd needs 3
numbers (or 1 for grey), got 'Kd 0.5 0.5'``), a value out of range or a repeated material
name marks that material as failed (`MtlMaterial.error`) and the others are kept. A
statement before the first ``newmtl`` is reported in `MtlLibrary.notes` and ignored.
The file must be UTF-8 (a byte-order mark is allowed); UTF-16 or other encodings are a
one-line error saying so.

Parsing is plain Python (no JAX array per material), so a library of 50 000 materials
reads in seconds; `MtlMaterial.phong` builds the JAX material when it is used.

Writing (`format_mtl`) emits ``Ka = ka·Cd``, ``Kd = kd·Cd``, ``Ks = ks·Cs``, ``Ns``,
``d``, ``Ni`` and ``illum 2`` for each material, under its name exactly as given (so the
``usemtl`` lines of the matching ``.obj`` still find it), so that reading the file back
gives the same rendering.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import MaterialError, StraussFitError
from ..models.phong import MAX_EXPONENT, PhongMaterial, check_values

#: OpenGL's default material, used for statements a material leaves out.
DEFAULTS = {"Ka": 0.2, "Kd": 0.8, "Ks": 0.0, "Ns": 0.0, "d": 1.0, "Ni": 1.5}
#: Texture statements: known, but nothing a Phong material can hold.
TEXTURES = {
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
    "map_ke",
    "map_pr",
    "map_pm",
    "map_ps",
    "map_norm",
    "map_aat",
    "map_opacity",
    "norm",
}
#: Statements of the PBR extension and other shading extras, known but not converted.
EXTENSIONS = {"ke", "sharpness", "pr", "pm", "ps", "pc", "pcr", "aniso", "anisor"}
#: Both (kept for compatibility).
IGNORED = TEXTURES | EXTENSIONS
COLOR_STATEMENTS = {"ka": "Ka", "kd": "Kd", "ks": "Ks"}
#: ``illum`` modes with refraction, where ``Tf`` is the transmission.
REFRACTING_ILLUM = (4, 6, 7, 9)
#: Above this, an ``Ni`` is flagged (diamond is 2.42; no common material exceeds 3).
PLAUSIBLE_IOR = 3.0
_LINE_BREAK = re.compile(r"\r\n|\r|\n")


@dataclass
class MtlMaterial:
    """One ``newmtl`` block: its Phong values (None if the block has an error), opacity,
    index of refraction, the line it starts on, notes, warnings, and the error if any.
    `phong` is the `PhongMaterial`, built when used."""

    name: str
    line: int
    values: dict[str, Any] | None = None
    opacity: float = 1.0
    ior: float = 1.5
    notes: list[str] = field(default_factory=list)
    error: str | None = None
    warnings: list[str] = field(default_factory=list)

    @property
    def phong(self) -> PhongMaterial | None:
        return None if self.values is None else PhongMaterial(**self.values)


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
        return [float(t) for t in tokens]
    except ValueError:
        return None


def _parse_numbers(block: _Block, number: int, label: str, args: list[str], line: str, counts: tuple[int, ...]):
    """The numbers of a statement, or None after failing the block with a message that
    says what is wrong (not numbers, how many, not finite)."""
    values = _numbers(args)
    if values is None or len(values) not in counts:
        wanted = "3 numbers (or 1 for grey)" if counts == (1, 3) else "1 number"
        block.fail(number, f"{label} needs {wanted}, got '{line}'")
        return None
    if not all(math.isfinite(v) for v in values):
        block.fail(number, f"{label} values must be finite numbers, got '{line}'")
        return None
    return values


def parse_mtl(text: str, source: str = "<mtl>") -> MtlLibrary:
    """Parse the text of a ``.mtl`` library (see the module docstring)."""
    blocks: list[_Block] = []
    file_notes: list[str] = []
    seen: dict[str, int] = {}
    current: _Block | None = None
    if text.startswith("\ufeff"):
        text = text[1:]
    for number, raw in enumerate(_LINE_BREAK.split(text), start=1):
        stripped = raw.strip()
        if not stripped or stripped.startswith("#"):
            continue
        keyword = stripped.split(None, 1)[0]
        key = keyword.lower()
        if key == "newmtl":
            name = stripped[len(keyword) :].strip()  # the rest of the line, '#' included
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
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        args = line.split()[1:]
        if current is None:
            file_notes.append(f"line {number}: '{keyword}' before any newmtl; ignored")
            continue
        block = current
        if key in COLOR_STATEMENTS or key == "tf":
            label = COLOR_STATEMENTS.get(key, "Tf")
            if args and args[0].lower() in ("spectral", "xyz"):
                if key == "tf":
                    block.notes.append(f"line {number}: 'Tf {args[0]}' ignored (only r g b transmission)")
                else:
                    block.fail(number, f"{label} {args[0]} is not supported (only r g b colours)")
                continue
            values = _parse_numbers(block, number, label, args, line, (1, 3))
            if values is None:
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
            values = _parse_numbers(block, number, label, args, line, (1,))
            if values is None:
                continue
            block.values[label] = values[0]
            block.where[label] = number
        elif key == "d":
            if args and args[0].lower() == "-halo":
                block.notes.append(f"line {number}: 'd -halo' read as a plain dissolve (no halo in Phong)")
                args = args[1:]
            values = _parse_numbers(block, number, "d", args, line, (1,))
            if values is None:
                continue
            block.values["d"] = values[0]
            block.where["d"] = number
        elif key in TEXTURES:
            block.notes.append(f"line {number}: '{keyword}' ignored (texture maps are not converted)")
        elif key in EXTENSIONS:
            block.notes.append(f"line {number}: '{keyword}' ignored (the PBR extension is not converted)")
        else:
            block.notes.append(f"line {number}: unknown statement '{keyword}' ignored")
    materials = [_finish(block) for block in blocks]
    return MtlLibrary(source, materials, file_notes)


def _opacity(block: _Block, out: MtlMaterial, values: dict[str, Any], illum: float | None) -> float:
    """The opacity from ``d``, ``Tr`` and (for a refracting ``illum``) ``Tf``."""
    opacity, where, what = DEFAULTS["d"], None, None
    if "d" in values:
        opacity, where, what = values["d"], block.where["d"], "d"
        if "Tr" in values:
            out.notes.append(f"line {block.where['Tr']}: Tr ignored because d is given")
        if not 0 <= opacity <= 1:
            block.fail(where, f"d = {opacity:g} is outside [0, 1]")
    elif "Tr" in values:
        opacity, where, what = 1.0 - values["Tr"], block.where["Tr"], "Tr"
        if not 0 <= values["Tr"] <= 1:
            block.fail(where, f"Tr = {values['Tr']:g} is outside [0, 1]")
    if "Tf" in values:
        tf = values["Tf"]
        line = block.where["Tf"]
        refracting = illum is not None and int(illum) in REFRACTING_ILLUM
        if not refracting:
            mode = f"illum {int(illum)}" if illum is not None else "no illum"
            out.notes.append(f"line {line}: Tf ignored ({mode} has no refraction)")
        elif max(tf) > 1:
            block.fail(line, f"Tf = {tf} must not exceed 1 (a transmission)")
        elif opacity < 1:
            out.notes.append(f"line {line}: Tf ignored because {what} gives the transparency")
        else:
            transmission = float(np.mean(tf))
            opacity, where, what = 1.0 - transmission, line, "Tf"
            tint = "" if max(tf) - min(tf) < 1e-9 else f"; its tint {tf} is lost (Strauss's t is grey)"
            out.notes.append(
                f"line {line}: illum {int(illum)} refracts: Tf {' '.join(f'{v:g}' for v in tf)} is the light "
                f"passing through, transparency t = mean(Tf) = {transmission:.4g}{tint}"
            )
    if what in ("d", "Tr") and opacity == 0:
        out.warnings.append(
            f"line {where}: {what} {values[what]:g} makes the material fully transparent (t = 1: invisible); "
            "exporters such as "
            "Blender's write 'd 0' for opaque materials, so this is almost certainly an exporter quirk: "
            "check the material (converted as given)"
        )
    return float(opacity)


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
    illum = values.get("illum")
    if illum is not None and (illum != int(illum) or not 0 <= illum <= 10):
        block.fail(block.where["illum"], f"illum must be an integer 0 to 10, got {illum:g}")
        illum = None
    opacity = _opacity(block, out, values, illum)
    ior = values.get("Ni", DEFAULTS["Ni"])
    if "Ni" not in values:
        out.notes.append(f"Ni missing: taken as {DEFAULTS['Ni']:g}")
    elif ior < 1:
        out.notes.append(f"line {block.where['Ni']}: Ni = {ior:g} is below 1; taken as 1 (Strauss needs n >= 1)")
        ior = 1.0
    elif ior > PLAUSIBLE_IOR:
        out.warnings.append(
            f"line {block.where['Ni']}: Ni = {ior:g} is far above any common material's index of refraction "
            f"(about 1 to {PLAUSIBLE_IOR:g}); kept as given"
        )
    for label in ("Ka", "Kd", "Ks"):
        if label in block.where and max(values[label]) > 1:
            out.warnings.append(
                f"line {block.where[label]}: {label} = {values[label]} exceeds 1: the surface would reflect more "
                "light than it receives; kept as given"
            )
    ks = values["Ks"]
    if illum is not None:
        if illum in (0, 1):
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
        out.warnings = []
        return out
    phong = {
        "ka": values["Ka"],
        "kd": values["Kd"],
        "ks": ks,
        "exponent": float(ns),
        "diffuse_color": [1.0, 1.0, 1.0],
        "specular_color": [1.0, 1.0, 1.0],
    }
    try:
        check_values(**phong)  # plain Python: no JAX array per material
    except MaterialError as exc:
        out.error = f"material '{block.name}' line {block.line}: {exc}"
        return out
    out.values = phong
    out.opacity = float(opacity)
    out.ior = float(ior)
    return out


def decode_text(data: bytes, path: str | Path, what: str) -> str:
    """The text of a file that must be UTF-8 (a byte-order mark is dropped); UTF-16 and
    other encodings are one-line errors saying so."""
    if data.startswith((b"\xff\xfe", b"\xfe\xff")) or b"\x00" in data[:4096]:
        kind = "UTF-32" if data.startswith((b"\xff\xfe\x00\x00", b"\x00\x00\xfe\xff")) else "UTF-16"
        raise StraussFitError(f"{what} {path} is {kind} text, not UTF-8: save it as UTF-8")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise StraussFitError(
            f"{what} {path} is not UTF-8 text (byte 0x{data[exc.start]:02x} on line {line}): save it as UTF-8"
        ) from None


def read_mtl(path: str | Path) -> MtlLibrary:
    """Read a ``.mtl`` file (a missing, unreadable or non-UTF-8 file is a one-line error)."""
    path = Path(path)
    if not path.is_file():
        raise StraussFitError(f"material library not found: {path}")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise StraussFitError(f"cannot read material library {path}: {exc.strerror or exc}") from None
    return parse_mtl(decode_text(data, path, "material library"), str(path))


def _triple(values: Any) -> list[float]:
    arr = np.broadcast_to(np.asarray(values, dtype=np.float64), (3,))
    return [float(v) for v in arr]


def format_mtl_material(
    name: str, phong: dict[str, Any], opacity: float = 1.0, ior: float = 1.5, comment: str | None = None
) -> str:
    """One ``newmtl`` block for a Phong material given as `PhongMaterial.to_dict`."""
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
    """A whole library from `format_mtl_material` blocks."""
    head = "".join(f"# {line}\n" for line in (header or "").splitlines())
    return head + ("\n" if head else "") + "\n".join(blocks)
