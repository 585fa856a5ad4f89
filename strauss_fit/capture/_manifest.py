"""Reading a capture: a TOML manifest, a lights file, or a folder in the DiLiGenT layout.

A capture is many photographs of one sample sphere, each under its own lights, taken by one
camera that does not move (docs/captures.md states the format and the conventions). This
module only reads and checks the description; the pixels are read by
`strauss_fit.capture._samples`.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from ..errors import CaptureError
from ..io.files import check_input_file

#: The files that make a folder a DiLiGenT capture (``light_intensities.txt`` and
#: ``mask.png`` are optional).
DILIGENT_FILES = ("filenames.txt", "light_directions.txt")
#: The manifest a folder may hold.
MANIFEST_NAME = "capture.toml"
ENCODINGS = ("linear", "srgb")


@dataclass(frozen=True)
class CaptureLight:
    """One light of one image: a ``direction`` (unit, toward the light, camera frame) or a
    ``position`` (a point light, in sphere radii from the sphere's centre), and a per-channel
    ``intensity`` that scales the radiance of a white light of unit intensity (for a point
    light: the irradiance at the sphere's centre)."""

    direction: tuple[float, float, float] | None = None
    position: tuple[float, float, float] | None = None
    intensity: tuple[float, float, float] = (1.0, 1.0, 1.0)
    #: The direction's angular standard deviation in degrees, when measured (a lights file).
    direction_sd_deg: float | None = None
    #: False where the intensity was not given (a lights file that could not measure it).
    intensity_known: bool = True


@dataclass(frozen=True)
class CaptureImage:
    """One photograph of the capture and the lights it was taken under."""

    path: Path
    lights: tuple[CaptureLight, ...]
    #: A known relative exposure (the image is divided by it before fitting).
    exposure: float = 1.0


@dataclass(frozen=True)
class CameraSpec:
    """The camera as the manifest states it (see docs/captures.md)."""

    kind: str = "orthographic"
    focal_px: float | None = None
    principal_point: tuple[float, float] | None = None


@dataclass(frozen=True)
class Capture:
    """A capture as described: images with their lights, the camera, how values are stored."""

    images: tuple[CaptureImage, ...]
    camera: CameraSpec = field(default_factory=CameraSpec)
    #: "linear", "srgb", or None (by file: 8-bit files sRGB, the rest linear).
    encoding: str | None = None
    #: Subtracted from every decoded value (fraction of full scale).
    black_level: float = 0.0
    #: Stored values at or above this are saturated (per channel); None = the format's maximum
    #: code for integer files, nothing for float files.
    saturation: float | None = None
    #: Decoded values (after the black level) below this are under-exposed; None = only
    #: integer code 0 (clipped at black).
    dark: float | None = None
    mask: Path | None = None
    #: The circle as given (``{"center": [cx, cy], "radius": r}``), or None to find it.
    circle: dict[str, Any] | None = None
    #: Where the description came from, and in which layout ("manifest", "diligent", "images").
    source: Path | None = None
    layout: str = "manifest"

    @property
    def files(self) -> list[str]:
        return [str(image.path) for image in self.images]

    def select(self, indices: Sequence[int]) -> Capture:
        """The same capture with only the images at ``indices`` (0-based, in order)."""
        return replace(self, images=tuple(self.images[i] for i in indices))


def _where(source: Path, key: str) -> str:
    return f"{source}: {key}"


def _number(
    value: Any, where: str, *, low: float | None = None, high: float | None = None, open_low: bool = False
) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise CaptureError(f"{where} must be a number, not {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise CaptureError(f"{where} must be finite, not {value!r}")
    if low is not None and (value <= low if open_low else value < low):
        raise CaptureError(f"{where} must be {'>' if open_low else '≥'} {low:g}, not {value:g}")
    if high is not None and value > high:
        raise CaptureError(f"{where} must be ≤ {high:g}, not {value:g}")
    return value


def _vector(value: Any, where: str, size: int = 3) -> tuple[float, ...]:
    if not isinstance(value, (list, tuple)) or len(value) != size:
        raise CaptureError(f"{where} must be a list of {size} numbers, not {value!r}")
    return tuple(_number(v, where) for v in value)


def _rgb(value: Any, where: str) -> tuple[float, float, float]:
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = [value] * 3
    rgb = _vector(value, where)
    if any(v < 0 for v in rgb):
        raise CaptureError(f"{where} must not be negative, not {list(rgb)}")
    return rgb  # type: ignore[return-value]


def _unit(vector: tuple[float, ...], where: str) -> tuple[float, float, float]:
    norm = math.sqrt(sum(v * v for v in vector))
    if not norm > 1e-12:
        raise CaptureError(f"{where} must not be the zero vector")
    return tuple(v / norm for v in vector)  # type: ignore[return-value]


def _check_keys(table: dict[str, Any], allowed: Sequence[str], where: str) -> None:
    unknown = sorted(set(table) - set(allowed))
    if unknown:
        raise CaptureError(f"{where}: unknown key {unknown[0]!r} (expected {', '.join(allowed)})")


def parse_light(table: Any, where: str) -> CaptureLight:
    """One ``[[image.light]]`` table."""
    if not isinstance(table, dict):
        raise CaptureError(f"{where} must be a table")
    _check_keys(table, ("direction", "position", "intensity", "direction_sd_deg"), where)
    has_direction, has_position = "direction" in table, "position" in table
    if has_direction == has_position:
        raise CaptureError(f"{where} needs exactly one of direction and position")
    direction = position = None
    if has_direction:
        direction = _unit(_vector(table["direction"], f"{where}.direction"), f"{where}.direction")
    else:
        position = _vector(table["position"], f"{where}.position")
        if math.sqrt(sum(v * v for v in position)) <= 1.0:
            raise CaptureError(f"{where}.position must lie outside the sphere (more than 1 radius from its centre)")
    intensity = _rgb(table.get("intensity", 1.0), f"{where}.intensity")
    sd = table.get("direction_sd_deg")
    sd = None if sd is None else _number(sd, f"{where}.direction_sd_deg", low=0.0)
    return CaptureLight(direction, position, intensity, sd, "intensity" in table)  # type: ignore[arg-type]


def _read_toml(path: Path, what: str) -> dict[str, Any]:
    path = check_input_file(path, what, CaptureError)
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise CaptureError(f"cannot read {what} {path}: it is not UTF-8 text") from None
    except tomllib.TOMLDecodeError as exc:
        raise CaptureError(f"cannot read {what} {path}: {exc}") from None
    except OSError as exc:
        raise CaptureError(f"cannot read {what} {path}: {exc.strerror or exc}") from None


def _image_tables(data: dict[str, Any], source: Path, required: bool) -> list[dict[str, Any]]:
    images = data.get("image", [])
    if not isinstance(images, list) or not all(isinstance(t, dict) for t in images):
        raise CaptureError(f"{source}: 'image' must be an array of tables ([[image]])")
    if required and not images:
        raise CaptureError(f"{source}: no [[image]] tables: a capture needs at least one image")
    return images


def read_lights_file(path: str | Path) -> list[tuple[CaptureLight, ...]]:
    """Every image's lights from a lights file (what ``strauss-fit lights`` writes), in order."""
    path = Path(path)
    data = _read_toml(path, "lights file")
    lights = []
    for i, table in enumerate(_image_tables(data, path, required=True), 1):
        entries = table.get("light", [])
        if not isinstance(entries, list) or not entries:
            raise CaptureError(f"{path}: image {i} has no [[image.light]]")
        lights.append(tuple(parse_light(t, f"{path}: image {i}, light {k}") for k, t in enumerate(entries, 1)))
    return lights


def _camera(table: Any, source: Path) -> CameraSpec:
    if table is None:
        return CameraSpec()
    where = _where(source, "capture.camera")
    if not isinstance(table, dict):
        raise CaptureError(f"{where} must be a table")
    _check_keys(table, ("type", "focal_px", "principal_point"), where)
    kind = table.get("type", "orthographic")
    if kind not in ("orthographic", "perspective"):
        raise CaptureError(f"{where}.type must be orthographic or perspective, not {kind!r}")
    focal = table.get("focal_px")
    if kind == "perspective":
        if focal is None:
            raise CaptureError(f"{where}: a perspective camera needs focal_px (the focal length in pixels)")
        focal = _number(focal, f"{where}.focal_px", low=0.0, open_low=True)
    elif focal is not None:
        raise CaptureError(f"{where}.focal_px is for a perspective camera only")
    point = table.get("principal_point")
    point = None if point is None else _vector(point, f"{where}.principal_point", 2)
    return CameraSpec(kind, focal, point)  # type: ignore[arg-type]


def _circle(table: Any, source: Path) -> dict[str, Any] | None:
    if table is None:
        return None
    where = _where(source, "capture.circle")
    if not isinstance(table, dict):
        raise CaptureError(f"{where} must be a table")
    _check_keys(table, ("center", "radius"), where)
    if "center" not in table or "radius" not in table:
        raise CaptureError(f"{where} needs center = [cx, cy] and radius")
    return {
        "center": list(_vector(table["center"], f"{where}.center", 2)),
        "radius": _number(table["radius"], f"{where}.radius", low=0.0, open_low=True),
    }


def read_manifest(path: str | Path) -> Capture:
    """Read a capture manifest (TOML, docs/captures.md); file names are relative to it."""
    path = Path(path)
    data = _read_toml(path, "capture manifest")
    _check_keys(data, ("capture", "image"), str(path))
    settings = data.get("capture", {})
    if not isinstance(settings, dict):
        raise CaptureError(f"{path}: 'capture' must be a table")
    keys = ("encoding", "black_level", "saturation", "dark", "mask", "lights", "camera", "circle")
    _check_keys(settings, keys, _where(path, "capture"))
    folder = path.parent
    encoding = settings.get("encoding")
    if encoding is not None and encoding not in ENCODINGS:
        raise CaptureError(f"{path}: capture.encoding must be linear or srgb, not {encoding!r}")
    black = _number(settings.get("black_level", 0.0), _where(path, "capture.black_level"), low=0.0, high=1.0)
    saturation = settings.get("saturation")
    if saturation is not None:
        saturation = _number(saturation, _where(path, "capture.saturation"), low=0.0, open_low=True)
    dark = settings.get("dark")
    if dark is not None:
        dark = _number(dark, _where(path, "capture.dark"))
    mask = settings.get("mask")
    if mask is not None:
        if not isinstance(mask, str) or not mask:
            raise CaptureError(f"{path}: capture.mask must be a file name")
        mask = folder / mask
    shared_lights = None
    if settings.get("lights") is not None:
        name = settings["lights"]
        if not isinstance(name, str) or not name:
            raise CaptureError(f"{path}: capture.lights must be a file name")
        shared_lights = read_lights_file(folder / name)
    tables = _image_tables(data, path, required=True)
    if shared_lights is not None and len(shared_lights) != len(tables):
        raise CaptureError(
            f"{path}: the lights file {settings['lights']} has {len(shared_lights)} images, the manifest {len(tables)}"
        )
    images = []
    for i, table in enumerate(tables, 1):
        where = f"{path}: image {i}"
        _check_keys(table, ("file", "exposure", "light"), where)
        name = table.get("file")
        if not isinstance(name, str) or not name:
            raise CaptureError(f'{where} needs file = "NAME"')
        exposure = _number(table.get("exposure", 1.0), f"{where}.exposure", low=0.0, open_low=True)
        entries = table.get("light")
        if entries is not None:
            if not isinstance(entries, list) or not entries:
                raise CaptureError(f"{where}: light must be an array of tables ([[image.light]])")
            lights = tuple(parse_light(t, f"{where}, light {k}") for k, t in enumerate(entries, 1))
        elif shared_lights is not None:
            lights = shared_lights[i - 1]
        else:
            raise CaptureError(f"{where} has no [[image.light]] and the manifest names no lights file")
        images.append(CaptureImage(folder / name, lights, exposure))
    return Capture(
        images=tuple(images),
        camera=_camera(settings.get("camera"), path),
        encoding=encoding,
        black_level=black,
        saturation=saturation,
        dark=dark,
        mask=mask,
        circle=_circle(settings.get("circle"), path),
        source=path,
        layout="manifest",
    )


def _table_rows(path: Path, columns: int, what: str) -> list[tuple[float, ...]]:
    path = check_input_file(path, what, CaptureError)
    rows = []
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise CaptureError(f"cannot read {what} {path}: {exc}") from None
    for number, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        parts = line.replace(",", " ").split()
        if len(parts) != columns:
            raise CaptureError(f"{path}, line {number}: expected {columns} numbers, found {len(parts)}")
        try:
            values = tuple(float(p) for p in parts)
        except ValueError:
            raise CaptureError(f"{path}, line {number}: not a number in {line.strip()[:60]!r}") from None
        if not all(math.isfinite(v) for v in values):
            raise CaptureError(f"{path}, line {number}: not finite")
        rows.append(values)
    return rows


def is_diligent_folder(folder: str | Path) -> bool:
    folder = Path(folder)
    return folder.is_dir() and all((folder / name).is_file() for name in DILIGENT_FILES)


def read_diligent(folder: str | Path) -> Capture:
    """A folder in the DiLiGenT layout, as distributed: ``filenames.txt`` (one image per
    line), ``light_directions.txt`` (one unit vector per line, camera frame),
    ``light_intensities.txt`` (R G B per line; optional, default 1) and ``mask.png``
    (optional). Orthographic, linear 16-bit images."""
    folder = Path(folder)
    names_path = check_input_file(folder / "filenames.txt", "DiLiGenT file list", CaptureError)
    try:
        names = [line.strip() for line in names_path.read_text(encoding="utf-8").splitlines() if line.strip()]
    except (OSError, UnicodeDecodeError) as exc:
        raise CaptureError(f"cannot read {names_path}: {exc}") from None
    if not names:
        raise CaptureError(f"{names_path} lists no images")
    directions = _table_rows(folder / "light_directions.txt", 3, "DiLiGenT light directions")
    if len(directions) != len(names):
        raise CaptureError(
            f"{folder}: filenames.txt lists {len(names)} images, light_directions.txt {len(directions)} lights"
        )
    intensity_path = folder / "light_intensities.txt"
    if intensity_path.exists():
        intensities = _table_rows(intensity_path, 3, "DiLiGenT light intensities")
        if len(intensities) != len(names):
            raise CaptureError(
                f"{folder}: filenames.txt lists {len(names)} images, light_intensities.txt {len(intensities)}"
            )
    else:
        intensities = [(1.0, 1.0, 1.0)] * len(names)
    images = []
    for i, (name, direction, intensity) in enumerate(zip(names, directions, intensities), 1):
        where = f"{folder}: light {i}"
        light = CaptureLight(direction=_unit(direction, where), intensity=_rgb(list(intensity), f"{where} intensity"))
        images.append(CaptureImage(folder / name, (light,)))
    mask = folder / "mask.png"
    return Capture(
        images=tuple(images),
        encoding="linear",
        mask=mask if mask.exists() else None,
        source=folder,
        layout="diligent",
    )


def read_capture(path: str | Path) -> Capture:
    """A capture from a manifest file, a folder holding ``capture.toml``, or a folder in the
    DiLiGenT layout."""
    path = Path(path)
    if path.is_dir():
        if (path / MANIFEST_NAME).is_file():
            return read_manifest(path / MANIFEST_NAME)
        if is_diligent_folder(path):
            return read_diligent(path)
        raise CaptureError(
            f"{path} is not a capture: it holds neither {MANIFEST_NAME} nor the DiLiGenT files "
            f"({', '.join(DILIGENT_FILES)})"
        )
    if not path.exists():
        raise CaptureError(f"capture not found: {path}")
    return read_manifest(path)


def capture_from_images(
    paths: Sequence[str | Path],
    lights: str | Path,
    *,
    mask: str | Path | None = None,
    camera: CameraSpec | None = None,
    encoding: str | None = None,
) -> Capture:
    """A capture from image files and a lights file whose i-th image lights the i-th file."""
    per_image = read_lights_file(lights)
    if len(per_image) != len(paths):
        raise CaptureError(f"{len(paths)} images but the lights file {lights} describes {len(per_image)}")
    images = tuple(CaptureImage(Path(p), image_lights) for p, image_lights in zip(paths, per_image))
    return Capture(
        images=images,
        camera=camera or CameraSpec(),
        encoding=encoding,
        mask=None if mask is None else Path(mask),
        source=Path(lights),
        layout="images",
    )


def open_capture(
    paths: Sequence[str | Path],
    lights: str | Path | None = None,
    mask: str | Path | None = None,
    encoding: str | None = None,
) -> Capture:
    """The capture the command line names: one manifest or folder (`read_capture`), or
    image files with a lights file (`capture_from_images`); ``mask`` replaces none
    given, ``encoding`` ("linear" or "srgb") replaces the capture's. The one rule of
    ``fit --capture``, ``sample`` and ``report``."""
    paths = [str(p) for p in paths]
    if not paths:
        raise CaptureError("no capture given")
    if len(paths) == 1 and lights is None:
        capture = read_capture(paths[0])
    else:
        if lights is None:
            raise CaptureError("several --capture images need --lights LIGHTS.toml (their lights, in order)")
        capture = capture_from_images(paths, lights, mask=mask)
    if mask is not None and capture.mask is None:
        capture = replace(capture, mask=Path(mask))
    if encoding is not None:
        if encoding not in ENCODINGS:
            raise CaptureError(f"unknown encoding {encoding!r}; expected one of {', '.join(ENCODINGS)}")
        capture = replace(capture, encoding=encoding)
    return capture


def capture_inputs(
    paths: Sequence[str | Path], lights: str | Path | None, mask: str | Path | None, encoding: str | None = None
) -> dict[str, Any]:
    """The inputs a capture's result records, so that ``sample`` and ``report`` can read the
    capture again (`open_capture`)."""
    return {
        "capture": [str(p) for p in paths],
        "lights": None if lights is None else str(lights),
        "mask": None if mask is None else str(mask),
        "encoding": encoding,
    }
