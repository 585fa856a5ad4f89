"""The dataset spec: a TOML file saying what to render (see docs/datasets.md and docs/formats.md).

.. code-block:: toml

    seed = 1990                       # integer >= 0; every random choice derives from it
    description = "optional text"

    [[group]]                         # one or more groups; each is a set of samples
    name = "strauss-extremes"         # letters, digits, '-', '_', '.'; unique; names the files
    model = "strauss"                 # a name of data_synth.params.MODELS: "strauss", "phong" (classic),
                                      # or a registry model ("lambert", "blinn-phong", "cook-torrance", ...)
    scenes = ["../scenes/key_light.toml"]  # scene files, relative to this spec file
    size = [64, 64]                   # optional: override the scenes' camera width, height
    depth = 2                         # optional (strauss; the local models ignore it): override [render] depth
    sampling = "grid"                 # "grid" (default) or "random"
    count = 10                        # random only: number of draws (besides the extremes)
    formats = ["exr", "png"]          # any of exr (linear float32) and png (8-bit sRGB + clip mask)

    [group.parameters]                # see data_synth.params: fixed value, set or range
    smoothness = [0.0, 0.5, 1.0]
    metalness = { low = 0.0, high = 1.0, steps = 3 }
    color = [0.8, 0.3, 0.2]
    # extremes = ["smoothness"]       # random only: corners to include (default: s, m, t)

    [group.sensor]                    # optional; see data_synth.sensor
    exposure = 1.0
    gain = 0.0                        # photons per unit radiance (0: no shot noise)
    read_noise = 0.0                  # Gaussian sigma (0: none)

Every sample of a group is one parameter set rendered in one scene: the group has
(number of parameter sets) × (number of scenes) samples, each parameter set rendered in
every scene. Loading is strict: unknown keys, wrong types and values outside a model's
ranges, a scene file that is missing or not TOML, are one-line
`SpecError` messages naming the file, the group and the key. A
scene file that is TOML but not a usable scene (see `SceneRef`) fails only its own
samples.
"""

from __future__ import annotations

import copy
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from strauss_fit.errors import StraussFitError
from strauss_fit.scene.loading import Scene, parse_scene

from .params import MAX_SAMPLES, MODELS, Axis, Fixed, SpecError, Values, grid_size, parse_axis
from .sensor import Sensor

FORMATS = ("exr", "png")
SAMPLINGS = ("grid", "random")
_TOP_KEYS = {"seed", "description", "group"}
_GROUP_KEYS = {"name", "model", "scenes", "size", "depth", "sampling", "count", "formats", "parameters", "sensor"}
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")


@dataclass(frozen=True)
class SceneRef:
    """A scene of a group: ``file`` as written in the spec, ``definition`` the scene's TOML
    mapping as rendered (camera size and depth overrides applied, ``[material]`` removed:
    the sample's parameters replace it), ``scene`` the parsed `Scene`, or None and
    ``error`` the one-line reason when the file is valid TOML but not a usable scene (an
    environment map holding NaN, a value out of range): its samples are reported as failed
    and the rest of the dataset is produced."""

    name: str
    file: str
    path: Path
    definition: dict[str, Any]
    scene: Scene | None = field(repr=False, compare=False)
    error: str | None = field(default=None, compare=False)


@dataclass(frozen=True)
class Group:
    """One ``[[group]]`` of a spec."""

    name: str
    model: str
    scenes: tuple[SceneRef, ...]
    sampling: str
    count: int
    axes: dict[str, Axis]
    extremes: tuple[str, ...]
    sensor: Sensor
    formats: tuple[str, ...]


@dataclass(frozen=True)
class DatasetSpec:
    """A parsed dataset spec; ``source`` names it in messages and in the index."""

    seed: int
    groups: tuple[Group, ...]
    description: str = ""
    source: str = "spec"


class _Where:
    def __init__(self, text: str):
        self.text = text

    def error(self, message: str) -> SpecError:
        return SpecError(f"{self.text}: {message}")


def _integer(w: _Where, value: Any, key: str, low: int, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise w.error(f"{key} must be an integer in [{low}, {high}], got {value!r}")
    return value


def _is_scalar_axis(axis: Axis) -> bool:
    """Whether every value of the axis is a number (not an RGB triple or a bool)."""
    if isinstance(axis, Fixed):
        values = [axis.value]
    elif isinstance(axis, Values):
        values = list(axis.values)
    else:
        values = [axis.low, axis.high]
    return all(isinstance(v, float) for v in values)


def _load_scene(w: _Where, file: Any, base_dir: Path, size: list[int] | None, depth: int | None) -> SceneRef:
    if not isinstance(file, str) or not file:
        raise w.error(f"scenes must be a list of scene file paths, got {file!r}")
    path = Path(file) if Path(file).is_absolute() else base_dir / file
    if not path.is_file():
        raise w.error(f"scene file not found: {path}")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise w.error(f"cannot read scene file {path}: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise w.error(f"{path}: not valid TOML: {exc}") from None
    definition = copy.deepcopy(data)
    definition.pop("material", None)
    if size is not None and isinstance(definition.get("camera"), dict):
        definition["camera"]["width"], definition["camera"]["height"] = size
    if depth is not None:
        render = definition.setdefault("render", {})
        if isinstance(render, dict):
            render["depth"] = depth
    try:
        scene = parse_scene(copy.deepcopy(definition), source=str(path), base_dir=path.parent)
    except StraussFitError as exc:  # a bad item of the batch, not a broken spec
        return SceneRef(path.stem, file, path, definition, None, str(exc))
    return SceneRef(path.stem, file, path, definition, scene)


def _parse_group(table: Any, number: int, source: str, base_dir: Path, seen: set[str]) -> Group:
    w = _Where(f"{source}: [[group]] #{number}")
    if not isinstance(table, dict):
        raise w.error("must be a table")
    name = table.get("name", f"group{number}")
    if not isinstance(name, str) or not _NAME.match(name):
        raise w.error(f"name must be letters, digits, '-', '_' or '.', got {name!r}")
    if name in seen:
        raise w.error(f"name {name!r} is used by another group")
    seen.add(name)
    w = _Where(f"{source}: [[group]] {name!r}")
    unknown = sorted(set(table) - _GROUP_KEYS)
    if unknown:
        raise w.error(f"unknown key(s) {', '.join(unknown)}; allowed: {', '.join(sorted(_GROUP_KEYS))}")
    model_name = table.get("model")
    if model_name is None:
        raise w.error(f"missing key 'model'; one of {', '.join(MODELS)}")
    if model_name not in MODELS:
        raise w.error(f"unknown model {model_name!r}; expected one of {', '.join(MODELS)}")
    model = MODELS[model_name]
    sampling = table.get("sampling", "grid")
    if sampling not in SAMPLINGS:
        raise w.error(f"sampling must be 'grid' or 'random', got {sampling!r}")
    count = 0
    if sampling == "random":
        if "count" not in table:
            raise w.error('sampling = "random" needs count = N')
        count = _integer(w, table["count"], "count", 0, MAX_SAMPLES)
    elif "count" in table:
        raise w.error('count only applies to sampling = "random"')
    formats = table.get("formats", ["exr"])
    if (
        not isinstance(formats, list)
        or not formats
        or any(f not in FORMATS for f in formats)
        or len(set(formats)) != len(formats)
    ):
        raise w.error(f"formats must be a non-empty list of distinct values from {', '.join(FORMATS)}, got {formats!r}")
    size = table.get("size")
    if size is not None:
        if not isinstance(size, list) or len(size) != 2:
            raise w.error(f"size must be [width, height], got {size!r}")
        size = [_integer(w, s, "size", 1, 8192) for s in size]
    depth = table.get("depth")
    if depth is not None:
        depth = _integer(w, depth, "depth", 1, 64)
    scenes = table.get("scenes")
    if isinstance(scenes, str):
        scenes = [scenes]
    if not isinstance(scenes, list) or not scenes:
        raise w.error("scenes must be a non-empty list of scene files (relative to the spec)")
    refs = tuple(_load_scene(w, s, base_dir, size, depth) for s in scenes)

    raw = table.get("parameters", {})
    if not isinstance(raw, dict):
        raise w.error("[group.parameters] must be a table")
    raw = dict(raw)
    extremes_raw = raw.pop("extremes", None)
    unknown = sorted(set(raw) - set(model.names))
    if unknown:
        raise w.error(f"unknown {model.name} parameter(s) {', '.join(unknown)}; expected {', '.join(model.names)}")
    pw = f"{w.text}: parameters"
    axes = {
        p.name: parse_axis(p, raw[p.name], sampling, pw) if p.name in raw else Fixed(p.default)
        for p in model.parameters
    }
    if sampling == "grid":
        if extremes_raw is not None:
            raise w.error('extremes only applies to sampling = "random" (a grid lists its own values)')
        extremes: tuple[str, ...] = ()
        total = grid_size(axes)
    else:
        if extremes_raw is None:
            extremes = tuple(n for n in model.default_extremes if not isinstance(axes[n], Fixed))
        else:
            if not isinstance(extremes_raw, list) or not all(isinstance(e, str) for e in extremes_raw):
                raise w.error(f"extremes must be a list of parameter names, got {extremes_raw!r}")
            for e in extremes_raw:
                if e not in model.names or not _is_scalar_axis(axes[e]):
                    raise w.error(f"extremes: {e!r} is not a scalar-valued {model.name} parameter")
            if len(set(extremes_raw)) != len(extremes_raw):
                raise w.error(f"extremes lists a parameter twice: {extremes_raw!r}")
            extremes = tuple(extremes_raw)
        total = count + 2 ** len(extremes) * bool(extremes)
    if total * len(refs) > MAX_SAMPLES:
        raise w.error(f"{total * len(refs)} samples is more than the limit of {MAX_SAMPLES}")
    if total == 0:
        raise w.error("the group has no samples (count = 0 and no extremes)")
    sensor_table = table.get("sensor", {})
    if not isinstance(sensor_table, dict):
        raise w.error("[group.sensor] must be a table")
    sensor = Sensor.from_dict(sensor_table, w.text)
    return Group(name, model.name, refs, sampling, count, axes, extremes, sensor, tuple(formats))


def parse_spec(
    data: dict[str, Any], source: str = "spec", base_dir: str | Path = ".", seed: int | None = None
) -> DatasetSpec:
    """Build a `DatasetSpec` from a parsed TOML mapping; ``seed`` overrides the spec's."""
    unknown = sorted(set(data) - _TOP_KEYS)
    if unknown:
        raise SpecError(f"{source}: unknown key(s) {', '.join(unknown)}; allowed: {', '.join(sorted(_TOP_KEYS))}")
    w = _Where(source)
    spec_seed = _integer(w, data.get("seed", 0), "seed", 0, 2**63 - 1)
    if seed is not None:
        spec_seed = _integer(w, seed, "--seed", 0, 2**63 - 1)
    description = data.get("description", "")
    if not isinstance(description, str):
        raise w.error(f"description must be a string, got {description!r}")
    groups = data.get("group")
    if not isinstance(groups, list) or not groups:
        raise w.error("the spec has no samples; add at least one [[group]] table")
    seen: set[str] = set()
    parsed = tuple(_parse_group(g, i, source, Path(base_dir), seen) for i, g in enumerate(groups, start=1))
    return DatasetSpec(spec_seed, parsed, description, source)


def load_spec(path: str | Path, seed: int | None = None) -> DatasetSpec:
    """Read and validate a TOML dataset spec; scene paths are relative to its folder."""
    path = Path(path)
    if not path.is_file():
        raise SpecError(
            f"dataset spec not found: {path}" if not path.is_dir() else f"dataset spec is a directory: {path}"
        )
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise SpecError(f"cannot read dataset spec {path}: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"{path}: not valid TOML: {exc}") from None
    return parse_spec(data, source=str(path), base_dir=path.parent, seed=seed)
