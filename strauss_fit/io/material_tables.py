"""Reading material batches for the conversions and writing their results.

Inputs (`read_phong_input`, `read_strauss_input`):

- **inline**: one material on the command line, as ``KEY=VALUE`` tokens (``kd=0.6
  ks=0.3 n=40 Cd=0.8,0.2,0.1``; RGB values as ``r,g,b``) or as a JSON object
  (``'{"kd": 0.6, ...}'``);
- **JSON** (``.json``): one material object, a list of them, or ``{"materials": [...]}``
  (so the output of one direction can be fed to the other: entries with a ``"phong"`` or
  ``"strauss"`` object use it, failed entries stay failed). A ``strauss-fit fit`` result
  is read as one Strauss material;
- **CSV** (``.csv``): a header row, one material per row (columns in
  `PHONG_CSV_INPUT` / `STRAUSS_CSV_INPUT`; an RGB value is three columns
  ``NAME_r``, ``NAME_g``, ``NAME_b``, or one column holding ``r g b``); empty cells take the
  defaults; the result columns written by the conversions are ignored, unknown ones are
  an error;
- **Wavefront** ``.mtl`` (Phong only): `strauss_fit.io.mtl`.

A material that cannot be read becomes an `Entry` with an
error (reported in the output, the others converted); a file that cannot be read at all
is a one-line `StraussFitError`.

Outputs (`write_results`): JSON (everything), CSV (one row per material, columns
in `csv_columns`) or, for Strauss → Phong, a ``.mtl`` library.
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .._escaping import CONTROL_CHARACTERS, escape
from ..errors import MaterialError, StraussFitError
from ..models import phong as phong_values
from ..models.material import COLOR_RANGE, PARAMETER_NAMES, PARAMETER_RANGES, Material
from ..models.phong import PhongMaterial
from .files import Outputs
from .mtl import decode_text, format_mtl, format_mtl_material, read_mtl
from .table_formats import INPUT_SUFFIXES, INPUT_SUFFIXES_BY_KIND, OUTPUT_FORMATS, describe_suffixes, output_suffixes


class Entry:
    """One material to convert: the source material (a `PhongMaterial` for
    Phong → Strauss, a `Material` for Strauss → Phong), its opacity and index of
    refraction (for a Strauss source: opacity = 1 − t), where it came from, notes,
    warnings (values that are allowed but almost certainly not meant), or the error that
    makes it unusable.

    Read from a file, an entry holds its validated parameters as plain values
    (``values``, of ``kind`` "phong" or "strauss", a key of `KINDS`):
    `material` builds the JAX material when it is first used, `release` drops
    it again (reading 50 000 materials builds no JAX array)."""

    def __init__(
        self,
        name: str,
        source: str,
        material: Any = None,
        opacity: float = 1.0,
        ior: float = 1.5,
        notes: list[str] | None = None,
        error: str | None = None,
        *,
        values: dict[str, Any] | None = None,
        kind: str | None = None,
        warnings: list[str] | None = None,
    ):
        self.name, self.source = name, source
        self._material = material
        self.opacity, self.ior = opacity, ior
        self.notes = list(notes or [])
        self.error = error
        self.values, self.kind = values, kind
        self.warnings = list(warnings or [])

    def __repr__(self) -> str:
        return f"Entry({self.name!r}, {self.source!r}, error={self.error!r})"

    @property
    def material(self) -> Any:
        """The material (built from `values` on first use)."""
        if self._material is None and self.values is not None:
            self._material = KINDS[self.kind].material(**self.values)
        return self._material

    @material.setter
    def material(self, value: Any) -> None:
        self._material = value

    def build(self) -> Any:
        """The material, built now if it is not yet."""
        return self.material

    def release(self) -> None:
        """Drop a material built from `values` (it is rebuilt when needed)."""
        if self.values is not None:
            self._material = None

    def describe(self) -> dict[str, Any]:
        """Everything that determines the entry's conversion, as plain values."""
        if self.values is not None:
            values: Any = self.values
        elif self._material is not None:
            values = self._material.to_dict()
        else:
            values = None
        return {
            "name": self.name,
            "source": self.source,
            "values": values,
            "opacity": self.opacity,
            "ior": self.ior,
            "error": self.error,
            "notes": self.notes,
            "warnings": self.warnings,
        }


PHONG_ALIASES = {
    "n": "exponent",
    "ns": "exponent",
    "shininess": "exponent",
    "cd": "diffuse_color",
    "diffuse": "diffuse_color",
    "cs": "specular_color",
    "specular": "specular_color",
    "d": "opacity",
    "ni": "ior",
}
STRAUSS_ALIASES = {
    "c": "color",
    "colour": "color",
    "s": "smoothness",
    "m": "metalness",
    "t": "transparency",
    "n": "ior",
}
PHONG_KEYS = ("ka", "kd", "ks", "exponent", "diffuse_color", "specular_color", "blinn")
STRAUSS_KEYS = PARAMETER_NAMES
RGB_KEYS = {"diffuse_color", "specular_color", "color"}
MAYBE_RGB_KEYS = {"ka", "kd", "ks"}
#: CSV input columns (an RGB key X may also be given as X_r, X_g, X_b).
PHONG_CSV_INPUT = ("name",) + PHONG_KEYS + ("opacity", "ior")
STRAUSS_CSV_INPUT = ("name",) + STRAUSS_KEYS
#: Columns the conversions write that are not inputs (ignored when reading a CSV back).
RESULT_COLUMNS = {
    "status",
    "message",
    "rms",
    "max_abs",
    "delta_e2000_mean",
    "delta_e2000_p95",
    "notes",
    "source",
    "solver_status",
}


# --- parsing values ---------------------------------------------------------------------------


def _number(text: Any, what: str) -> float:
    if isinstance(text, bool):
        raise MaterialError(f"{what} must be a number, got {text!r}")
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise MaterialError(f"{what} must be a number, got {text!r}") from None
    if not math.isfinite(value):
        raise MaterialError(f"{what} must be finite, got {text!r}")
    return value


def _value(key: str, raw: Any, what: str) -> Any:
    """A parsed value: a number, a list of 3 numbers (from 'r,g,b', 'r g b' or a list) or a bool."""
    if key == "blinn":
        if isinstance(raw, bool):
            return raw
        text = str(raw).strip().lower()
        if text in ("true", "1", "yes"):
            return True
        if text in ("false", "0", "no", ""):
            return False
        raise MaterialError(f"{what} must be true or false, got {raw!r}")
    if isinstance(raw, (list, tuple)):
        parts = list(raw)
    elif isinstance(raw, str):
        parts = [p for p in raw.replace(",", " ").split() if p]
    else:
        parts = [raw]
    numbers = [_number(p, what) for p in parts]
    if key in RGB_KEYS:
        if len(numbers) == 1:
            numbers = numbers * 3
        if len(numbers) != 3:
            raise MaterialError(f"{what} must be 3 numbers (r,g,b) or 1 (grey), got {raw!r}")
        return numbers
    if key in MAYBE_RGB_KEYS:
        if len(numbers) == 1:
            return numbers[0]
        if len(numbers) != 3:
            raise MaterialError(f"{what} must be 1 number or 3 (r,g,b), got {raw!r}")
        return numbers
    if len(numbers) != 1:
        raise MaterialError(f"{what} must be one number, got {raw!r}")
    return numbers[0]


def _canonical(key: str, aliases: dict[str, str]) -> str:
    lowered = key.strip().lower()
    return aliases.get(lowered, lowered)


def phong_entry(values: dict[str, Any], name: str, source: str) -> Entry:
    """An `Entry` from a mapping of Phong keys (aliases allowed) plus ``opacity``
    and ``ior``; problems make an entry with an error."""
    entry = Entry(name=name, source=source)
    try:
        params: dict[str, Any] = {}
        for raw_key, raw in values.items():
            key = _canonical(raw_key, PHONG_ALIASES)
            if key == "name":
                continue
            if key not in PHONG.inputs:
                raise PHONG.unknown_key(raw_key)
            if key in params:
                raise MaterialError(f"{raw_key!r} given twice")
            params[key] = _value(key, raw, f"phong {key}")
        opacity = params.pop("opacity", 1.0)
        ior = params.pop("ior", 1.5)
        if not 0 <= opacity <= 1:
            raise MaterialError(f"opacity = {opacity:g} is outside its range [0, 1]")
        if ior < 1:
            raise MaterialError(f"ior = {ior:g} is below 1 (Strauss needs n >= 1)")
        phong_values.check_values(**params)  # plain Python; the JAX material is built when converted
        entry.values, entry.kind = params, "phong"
        entry.opacity, entry.ior = float(opacity), float(ior)
    except MaterialError as exc:
        entry.error = str(exc)
    return entry


def strauss_entry(values: dict[str, Any], name: str, source: str) -> Entry:
    """An `Entry` from a mapping of Strauss keys (aliases allowed)."""
    entry = Entry(name=name, source=source)
    try:
        params: dict[str, Any] = {}
        for raw_key, raw in values.items():
            key = _canonical(raw_key, STRAUSS_ALIASES)
            if key == "name":
                continue
            if key not in STRAUSS.inputs:
                raise STRAUSS.unknown_key(raw_key)
            if key in params:
                raise MaterialError(f"{raw_key!r} given twice")
            params[key] = _value(key, raw, f"material {key}")
        _check_strauss(params)  # plain Python; the JAX material is built when converted
        entry.values, entry.kind = params, "strauss"
        entry.opacity = 1.0 - float(params.get("transparency", 0.0))
        entry.ior = float(params.get("ior", 1.5))
    except MaterialError as exc:
        entry.error = str(exc)
    return entry


def _check_strauss(params: dict[str, Any]) -> None:
    """Check Strauss values as `_value` gives them (finite floats; colours as 3 of
    them) against the material's ranges, in parameter order, with the messages of the
    material's own check, and without building a JAX array (a library of 50 000
    materials)."""
    for key in STRAUSS_KEYS:
        if key not in params:
            continue
        value = params[key]
        low, high = COLOR_RANGE if key in RGB_KEYS else PARAMETER_RANGES[key]
        if all(x >= low and (high is None or x <= high) for x in (value if isinstance(value, list) else [value])):
            continue
        span = f"[{low:g}, {'inf' if high is None else f'{high:g}'}]"
        per = " per channel" if key in RGB_KEYS else ""
        raise MaterialError(f"material {key} = {value} is outside its range {span}{per}")


@dataclass(frozen=True)
class Kind:
    """What reading one kind of material takes: the `Entry` maker, the material class
    built from an entry's values, the material's keys (in order) and the other keys an input
    may give, the aliases of both, the file formats read, and whether a ``strauss-fit fit``
    result is one such material."""

    name: str
    label: str
    entry: Callable[[dict[str, Any], str, str], Entry]
    material: Callable[..., Any]
    keys: tuple[str, ...]
    extra: tuple[str, ...]
    aliases: Mapping[str, str]
    alias_help: str
    suffixes: tuple[str, ...]
    fit_results: bool = False

    @property
    def inputs(self) -> tuple[str, ...]:
        """Every key an input may give (aliases resolved)."""
        return self.keys + self.extra

    def unknown_key(self, raw_key: str) -> MaterialError:
        return MaterialError(
            f"unknown {self.label} key {raw_key!r}; expected {', '.join(self.inputs)} (aliases: {self.alias_help})"
        )


PHONG = Kind(
    "phong",
    "Phong",
    phong_entry,
    PhongMaterial,
    PHONG_KEYS,
    ("opacity", "ior"),  # a Phong material has neither; they become Strauss's transparency and n
    PHONG_ALIASES,
    "n/Ns for exponent, Cd, Cs, d for opacity, Ni for ior",
    INPUT_SUFFIXES_BY_KIND["phong"],
)
STRAUSS = Kind(
    "strauss",
    "Strauss",
    strauss_entry,
    Material,
    STRAUSS_KEYS,
    (),
    STRAUSS_ALIASES,
    "C, s, m, t, n",
    INPUT_SUFFIXES_BY_KIND["strauss"],
    fit_results=True,
)
#: The kinds of material read, by `Entry.kind`.
KINDS: dict[str, Kind] = {kind.name: kind for kind in (PHONG, STRAUSS)}


# --- inline ---------------------------------------------------------------------------------


def parse_inline(tokens: list[str]) -> dict[str, Any]:
    """``KEY=VALUE`` tokens (a token may hold several, separated by spaces or ';') or a
    JSON object, as a mapping of raw values."""
    text = " ".join(tokens).strip()
    if text.startswith("{"):
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise StraussFitError(f"the material on the command line is not valid JSON: {exc}") from None
        if not isinstance(data, dict):
            raise StraussFitError("the material on the command line must be a JSON object")
        return data
    values: dict[str, Any] = {}
    for token in text.replace(";", " ").split():
        key, sep, value = token.partition("=")
        if not sep or not key:
            raise StraussFitError(
                f"expected KEY=VALUE on the command line, got {token!r} (or give a .json, .csv or .mtl file)"
            )
        if key in values:
            raise StraussFitError(f"{key!r} given twice on the command line")
        values[key] = value
    if not values:
        raise StraussFitError("no material given")
    return values


def _looks_like_file(token: str) -> bool:
    return "=" not in token and not token.lstrip().startswith("{")


def _is_file_argument(tokens: list[str]) -> bool:
    """Whether the inputs are files: one token that is no KEY=VALUE, or several tokens
    that all name files (existing, or with a known suffix)."""
    if len(tokens) == 1:
        return _looks_like_file(tokens[0])
    return all(_looks_like_file(t) and (Path(t).exists() or Path(t).suffix.lower() in INPUT_SUFFIXES) for t in tokens)


# --- JSON -------------------------------------------------------------------------------------


def _json_items(path: Path) -> list[Any]:
    try:
        data = json.loads(decode_text(path.read_bytes(), path, "material file"))
    except OSError as exc:
        raise StraussFitError(f"cannot read {path}: {exc.strerror or exc}") from None
    except json.JSONDecodeError as exc:
        raise StraussFitError(f"cannot read {path}: not valid JSON: {exc}") from None
    if isinstance(data, dict) and isinstance(data.get("materials"), list):
        return data["materials"]
    if isinstance(data, list):
        return data
    if isinstance(data, dict):
        return [data]
    raise StraussFitError(f'{path}: expected a material object, a list of them, or {{"materials": [...]}}')


FIT_RESULT_KEYS = {"free", "held", "residual"}


def _from_json(path: Path, kind: Kind) -> list[Entry]:
    entries = []
    make = kind.entry
    for number, item in enumerate(_json_items(path), start=1):
        source = f"{path} #{number}"
        if not isinstance(item, dict):
            entries.append(
                Entry(name=f"material-{number}", source=source, error=f"entry {number} is not a JSON object")
            )
            continue
        name = str(item.get("name", f"material-{number}"))
        if item.get("status") == "error":
            entries.append(
                Entry(
                    name=name,
                    source=source,
                    error=f"the previous conversion failed: {item.get('message', 'no message')}",
                )
            )
            continue
        if isinstance(item.get(kind.name), dict):  # the output of the other direction
            values = dict(item[kind.name])
            values.update({k: item[k] for k in kind.extra if k in item})
            entries.append(make(values, name, source))
        elif kind.fit_results and FIT_RESULT_KEYS <= set(item):  # a `strauss-fit fit` result
            entries.append(make({k: item[k] for k in kind.keys if k in item}, name, source))
        else:
            entries.append(make({k: v for k, v in item.items() if k != "name"}, name, source))
    return entries


# --- CSV --------------------------------------------------------------------------------------


def _from_csv(path: Path, kind: Kind) -> list[Entry]:
    try:
        text = decode_text(path.read_bytes(), path, "material file")
    except OSError as exc:
        raise StraussFitError(f"cannot read {path}: {exc.strerror or exc}") from None
    reader = csv.reader(io.StringIO(text))
    rows = [row for row in reader if any(cell.strip() for cell in row)]
    if not rows:
        raise StraussFitError(f"{path}: the CSV file is empty (expected a header row and one row per material)")
    header = [h.strip() for h in rows[0]]
    aliases, keys = kind.aliases, kind.inputs
    columns: dict[str, list[tuple[int, int | None]]] = {}
    for index, column in enumerate(header):
        lowered = column.lower()
        if lowered == "name" or lowered in RESULT_COLUMNS or lowered.startswith(("sd_", "guess_", "input_")):
            continue
        base, channel = lowered, None
        if lowered[-2:] in ("_r", "_g", "_b"):
            base, channel = lowered[:-2], "rgb".index(lowered[-1])
        key = aliases.get(base, base)
        if key not in keys or (channel is not None and key not in RGB_KEYS | MAYBE_RGB_KEYS):
            raise StraussFitError(
                f"{path}: unknown column {column!r}; expected name, {', '.join(keys)} "
                "(RGB values as NAME_r, NAME_g, NAME_b or one column 'r g b')"
            )
        columns.setdefault(key, []).append((index, channel))
    lowered_header = [h.lower() for h in header]
    name_index = lowered_header.index("name") if "name" in lowered_header else None
    status_index = lowered_header.index("status") if "status" in lowered_header else None
    entries = []
    make = kind.entry
    for number, row in enumerate(rows[1:], start=2):
        source = f"{path} line {number}"
        name = (
            row[name_index].strip()
            if name_index is not None and name_index < len(row) and row[name_index].strip()
            else f"material-{number - 1}"
        )
        if status_index is not None and status_index < len(row) and row[status_index].strip() == "error":
            entries.append(Entry(name=name, source=source, error="the previous conversion failed (status error)"))
            continue
        if len(row) > len(header):
            entries.append(
                Entry(
                    name=name,
                    source=source,
                    error=f"line {number} has {len(row)} cells but the header has {len(header)}",
                )
            )
            continue
        values: dict[str, Any] = {}
        problem = None
        for key, places in columns.items():
            cells = {channel: (row[i].strip() if i < len(row) else "") for i, channel in places}
            if None in cells:
                if cells[None]:
                    values[key] = cells[None]
                continue
            channels = [cells.get(c, "") for c in range(3)]
            if all(not c for c in channels):
                continue
            if not all(channels):
                problem = f"{key} needs all of {key}_r, {key}_g, {key}_b (or none)"
                break
            values[key] = channels
        if problem:
            entries.append(Entry(name=name, source=source, error=f"line {number}: {problem}"))
            continue
        entry = make(values, name, source)
        if entry.error:
            entry.error = f"line {number}: {entry.error}"
        entries.append(entry)
    return entries


# --- entry points -----------------------------------------------------------------------------


def _from_mtl(path: Path, kind: Kind) -> tuple[list[Entry], list[str]]:
    """The materials of a Wavefront ``.mtl`` library (Phong materials) and its notes."""
    library = read_mtl(path)
    entries = [
        Entry(
            name=material.name,
            source=f"{path} line {material.line}",
            opacity=material.opacity,
            ior=material.ior,
            notes=list(material.notes),
            error=material.error,
            values=material.values,
            kind=PHONG.name if material.values is not None else None,
            warnings=list(material.warnings),
        )
        for material in library.materials
    ]
    return entries, list(library.notes)


#: What reads a material file, by its extension: the entries and the file's notes. Which of
#: them a kind of material accepts is its `Kind.suffixes` (a ``.mtl`` library holds
#: Phong materials only).
INPUT_READERS: dict[str, Callable[[Path, Kind], tuple[list[Entry], list[str]]]] = {
    ".json": lambda path, kind: (_from_json(path, kind), []),
    ".csv": lambda path, kind: (_from_csv(path, kind), []),
    ".mtl": _from_mtl,
}


def _read_file(path: Path, kind: Kind) -> tuple[list[Entry], list[str]]:
    if not path.exists():
        raise StraussFitError(f"input not found: {path} (give a {', '.join(kind.suffixes)} file or KEY=VALUE pairs)")
    if path.is_dir():
        raise StraussFitError(f"input is a directory: {path}")
    suffix = path.suffix.lower()
    if suffix not in kind.suffixes:
        raise StraussFitError(
            f"cannot read {path}: unknown input format {suffix or '(no extension)'}; "
            f"expected {describe_suffixes(kind.suffixes)}"
        )
    entries, notes = INPUT_READERS[suffix](path, kind)
    if not entries:
        raise StraussFitError(f"{path} holds no material")
    return entries, notes


def _read(tokens: list[str], kind: Kind) -> tuple[list[Entry], list[str], str]:
    """Entries, file-level notes and a description of the input."""
    if not tokens:
        raise StraussFitError("no input given")
    if _is_file_argument(tokens):
        entries: list[Entry] = []
        notes: list[str] = []
        for token in tokens:
            path = Path(token)
            more, file_notes = _read_file(path, kind)
            entries += more
            notes += [f"{path}: {note}" for note in file_notes] if len(tokens) > 1 else file_notes
        return entries, notes, ", ".join(tokens)
    files = [t for t in tokens if _looks_like_file(t) and Path(t).suffix.lower() in INPUT_SUFFIXES]
    if files:
        raise StraussFitError(
            f"{files[0]!r} is a file but other inputs are not: give material files (one or more), "
            "or one material as KEY=VALUE pairs"
        )
    values = parse_inline(tokens)
    name = str(values.pop("name", "material"))
    entry = kind.entry(values, name, "command line")
    if entry.error:  # a single material given by hand: say what is wrong, once
        raise MaterialError(entry.error)
    return [entry], [], "command line"


def read_phong_input(tokens: list[str]) -> tuple[list[Entry], list[str], str]:
    """Phong materials from the command line, or JSON, CSV and ``.mtl`` files (one or more)."""
    return _read(tokens, PHONG)


def read_strauss_input(tokens: list[str]) -> tuple[list[Entry], list[str], str]:
    """Strauss materials from the command line, or JSON and CSV files (one or more)."""
    return _read(tokens, STRAUSS)


# --- outputs ----------------------------------------------------------------------------------


def output_format(path: str | Path, direction: str) -> str:
    """The name of the output format the extension of ``path`` selects (``json``, ``csv`` or,
    Strauss → Phong only, ``mtl``: `OUTPUT_FORMATS`)."""
    suffix = Path(path).suffix.lower()
    name, directions = OUTPUT_FORMATS.get(suffix, (None, ()))
    if direction not in directions:
        raise StraussFitError(
            f"cannot write {path}: unknown output format {suffix or '(no extension)'}; "
            f"expected {describe_suffixes(output_suffixes(direction))}"
        )
    return name


def _rgb_columns(name: str) -> list[str]:
    return [f"{name}_{c}" for c in "rgb"]


def csv_columns(direction: str) -> list[str]:
    """The CSV header of a conversion's output."""
    head = ["name", "source", "status", "message"]
    tail = ["rms", "max_abs", "delta_e2000_mean", "delta_e2000_p95", "solver_status", "notes"]
    if direction == "phong2strauss":
        return (
            head
            + [column for key in STRAUSS_KEYS for column in (_rgb_columns(key) if key in RGB_KEYS else [key])]
            + _rgb_columns("sd_color")
            + ["sd_smoothness", "sd_metalness"]
            + tail
        )
    return (
        head
        + ["ka", "kd", "ks", "exponent"]
        + _rgb_columns("diffuse_color")
        + _rgb_columns("specular_color")
        + ["blinn", "opacity", "ior"]
        + _rgb_columns("sd_diffuse")
        + _rgb_columns("sd_specular")
        + ["sd_exponent"]
        + tail
    )


def _sd_text(value: float | None) -> str:
    """A deviation as a CSV cell; empty for a held parameter (it has none)."""
    return "" if value is None else f"{value:.3g}"


def _csv_row(result: dict[str, Any], direction: str) -> dict[str, Any]:
    row: dict[str, Any] = {
        "name": result["name"],
        "source": result.get("source", ""),
        "status": result["status"],
        "message": result.get("message", ""),
        "notes": " | ".join(result.get("notes", [])),
    }
    if result["status"] != "ok":
        return row
    residual = result["residual"]
    row.update({k: f"{residual[k]:.6g}" for k in ("rms", "max_abs", "delta_e2000_mean", "delta_e2000_p95")})
    row["solver_status"] = result["solver"]["status"]
    uncertainty = result.get("uncertainty") or {}
    if direction == "phong2strauss":
        values = result["strauss"]
        for key in STRAUSS_KEYS:
            if key in RGB_KEYS:
                row.update({f"{key}_{c}": f"{v:.6g}" for c, v in zip("rgb", values[key])})
            else:
                row[key] = f"{values[key]:.6g}"
        if uncertainty:
            for c, v in zip("rgb", uncertainty["color"]):
                row[f"sd_color_{c}"] = _sd_text(v)
            row["sd_smoothness"] = _sd_text(uncertainty["smoothness"])
            row["sd_metalness"] = _sd_text(uncertainty["metalness"])
    else:
        values = result["phong"]
        for key in ("ka", "kd", "ks", "exponent"):
            row[key] = f"{values[key]:.6g}"
        for key in ("diffuse_color", "specular_color"):
            for c, v in zip("rgb", values[key]):
                row[f"{key}_{c}"] = f"{v:.6g}"
        row["blinn"] = "true" if values["blinn"] else "false"
        row["opacity"] = f"{result['opacity']:.6g}"
        row["ior"] = f"{result['ior']:.6g}"
        if uncertainty:
            for key in ("diffuse", "specular"):
                for c, v in zip("rgb", uncertainty[key]):
                    row[f"sd_{key}_{c}"] = _sd_text(v)
            row["sd_exponent"] = _sd_text(uncertainty["exponent"])
    return row


def format_csv(results: list[dict[str, Any]], direction: str) -> str:
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=csv_columns(direction), lineterminator="\n")
    writer.writeheader()
    for result in results:
        writer.writerow(_csv_row(result, direction))
    return buffer.getvalue()


def _mtl_name(name: str, used: set[str]) -> tuple[str, str | None]:
    """The name under which a material is written to a ``.mtl``: the name itself
    (``newmtl`` takes the rest of the line, spaces and ``#`` included), so that the
    ``usemtl`` lines of the matching ``.obj`` still find it — unless the format cannot
    hold it (empty, control characters, leading or trailing spaces, taken by an earlier
    material); then a replacement and the reason."""
    reason = None
    if not name.strip():
        reason = "it is empty"
    elif CONTROL_CHARACTERS.search(name):
        reason = "it holds control characters"
    elif name != name.strip():
        reason = "it starts or ends with spaces, which a .mtl reader drops"
    elif name in used:
        reason = "an earlier material has the same name"
    if reason is None:
        used.add(name)
        return name, None
    base = CONTROL_CHARACTERS.sub("_", name).strip() or "material"
    candidate, k = base, 2
    while candidate in used:
        candidate, k = f"{base}_{k}", k + 1
    used.add(candidate)
    return candidate, reason


def format_results_mtl(results: list[dict[str, Any]]) -> tuple[str, list[str]]:
    """A ``.mtl`` library of the converted Phong materials (failed ones become comments),
    and a warning for every material written under another name than its own."""
    blocks, used, renamed = [], set(), []
    for result in results:
        if result["status"] != "ok":
            shown, message = escape(result["name"], newlines=True), escape(result.get("message", ""), newlines=True)
            blocks.append(f"# {shown}: not converted: {message}\n")
            continue
        residual = result["residual"]
        name, reason = _mtl_name(result["name"], used)
        comment = (
            f"from Strauss {json.dumps(result['input']['strauss'])}\n"
            f"residual: RMS {residual['rms']:.3g}, CIEDE2000 mean {residual['delta_e2000_mean']:.3g}"
        )
        if reason is not None:
            comment += f"\nrenamed from {escape(repr(result['name']), newlines=True)}: {reason}"
            renamed.append(
                f"material {result['name']!r} is written as {name!r} ({reason}): "
                "usemtl lines naming the old name will not find it"
            )
        blocks.append(format_mtl_material(name, result["phong"], result["opacity"], result["ior"], comment))
    text = format_mtl(blocks, "written by strauss-fit strauss2phong (see docs/conversion.md)")
    return text, renamed


def _format_json(document: dict[str, Any], direction: str) -> tuple[str, list[str]]:
    return json.dumps(document, indent=2, allow_nan=False) + "\n", []


def _format_csv_document(document: dict[str, Any], direction: str) -> tuple[str, list[str]]:
    return format_csv(document["materials"], direction), []


def _format_mtl_document(document: dict[str, Any], direction: str) -> tuple[str, list[str]]:
    return format_results_mtl(document["materials"])


#: What formats a conversion's document (text and warnings about it), by the format's name
#: (`OUTPUT_FORMATS` names the extensions).
OUTPUT_WRITERS: dict[str, Callable[[dict[str, Any], str], tuple[str, list[str]]]] = {
    "json": _format_json,
    "csv": _format_csv_document,
    "mtl": _format_mtl_document,
}


def format_results(document: dict[str, Any], direction: str, fmt: str) -> tuple[str, list[str]]:
    """The text of a conversion's output in format ``fmt`` (`OUTPUT_WRITERS`) and
    warnings about it."""
    return OUTPUT_WRITERS[fmt](document, direction)


def write_results(
    path: str | Path, document: dict[str, Any], direction: str, *, force: bool = False, final: bool = False
) -> list[str]:
    """Write a conversion's document in the format the extension names (atomic, no
    overwrite without ``force``); returns warnings (materials renamed in a ``.mtl``)."""
    fmt = output_format(path, direction)
    text, warnings = format_results(document, direction, fmt)
    with Outputs(force=force) as out:
        out.add_text(path, text)
        out.commit(final=final)
    return warnings
