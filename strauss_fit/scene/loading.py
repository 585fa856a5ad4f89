"""Scenes: camera, lights, background and material, and the TOML scene file.

The file format is documented in ``docs/formats.md`` (scene files). Loading is strict:
unknown sections or keys, wrong types, values out of range, a scene without any light and
an environment image holding NaN or infinite values are reported as one-line
`SceneError` messages that name the file, the place and the
problem — before any work is done.

The renderer's range (`check_radiance_range`, also run by
`strauss_fit.rendering.strauss.render` on scenes built in code): every light intensity,
light colour component and background radiance is at most `MAX_RADIANCE` (10^30), and
so is the scene's *radiance scale*, the sum of every light's peak irradiance at the sphere
(`light_peaks`), the ambient intensity and the brightest background radiance. Each
weight of the Strauss model is at most 1, so no pixel exceeds 3 × 10^30, far below
float32's largest value (3.4 × 10^38); the margin covers the renderer's intermediate
products and a fit's (Jacobians, squared residuals, in float64). A scene outside it is a
`RadianceRangeError` naming the light (or the background) and its value, instead of
an image of infinities found only when writing it.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..errors import MaterialError, SceneError, StraussFitError
from ..io.files import check_input_file
from ..models.material import Material
from ..numerics import device_array
from ..precision import uses_float64
from .background import BACKGROUND_KINDS, Background
from .camera import Camera
from .lights import DirectionalLights, Lights, PointLights

#: Default recursion depth of the global model (see `strauss_fit.rendering.strauss.render`).
DEFAULT_DEPTH = 4
MAX_IMAGE_SIDE = 8192
#: The largest radiance scale the renderer guarantees finite images for (module docstring).
MAX_RADIANCE = 1e30


class RadianceRangeError(SceneError):
    """A light or the background is brighter than the renderer's range
    (`MAX_RADIANCE`): its radiance could overflow to infinity."""


_SECTIONS = {"camera", "material", "light", "background", "render"}
_CAMERA_KEYS = {"projection", "width", "height", "position", "look_at", "fov_deg", "up"}
_LIGHT_KEYS = {
    "directional": {"kind", "direction", "intensity", "color"},
    "point": {"kind", "position", "intensity", "color", "attenuation"},
    "ambient": {"kind", "intensity"},
}
_BACKGROUND_KEYS = {
    "color": {"kind", "color"},
    "checkerboard": {"kind", "color", "point", "normal", "square_size", "colors", "sharpness"},
    "environment": {"kind", "image", "scale"},
}
_RENDER_KEYS = {"depth"}


class Scene(eqx.Module):
    """Everything but the material being fitted: camera, lights, background, and the
    scene file's material (the truth when rendering, the starting point when fitting).

    ``depth`` is the recursion depth of the global model: the number of surface
    interactions a ray may undergo, counting the first hit (1 = local model only).
    """

    camera: Camera
    lights: Lights
    background: Background = eqx.field(default_factory=Background)
    material: Material = eqx.field(default_factory=Material)
    depth: int = eqx.field(static=True, default=DEFAULT_DEPTH)

    @uses_float64
    def astype(self, dtype: Any) -> Scene:
        """The same scene with every floating-point array cast to ``dtype``."""

        def cast(x):
            if isinstance(x, jax.Array) and jnp.issubdtype(x.dtype, jnp.floating):
                return x.astype(dtype)
            return x

        return jax.tree_util.tree_map(cast, self)

    def resized(self, width: int, height: int) -> Scene:
        """The same scene rendered at another image size."""
        return eqx.tree_at(lambda s: s.camera, self, self.camera.resized(width, height))

    @property
    def shape(self) -> tuple[int, int]:
        """Image shape (height, width)."""
        return self.camera.height, self.camera.width


# --- parsing ----------------------------------------------------------------------------


class _Where:
    """Formats the location of a value for error messages."""

    def __init__(self, source: str, section: str):
        self.source, self.section = source, section

    def error(self, message: str) -> SceneError:
        return SceneError(f"{self.source}: {self.section}: {message}")

    def keys(self, table: Any, allowed: set[str]) -> dict[str, Any]:
        if not isinstance(table, dict):
            raise self.error("must be a table")
        unknown = sorted(set(table) - allowed)
        if unknown:
            raise self.error(
                f"unknown key(s) {', '.join(repr(k) for k in unknown)}; allowed: {', '.join(sorted(allowed))}"
            )
        return table

    def number(
        self,
        table: dict,
        key: str,
        default: float | None = None,
        *,
        low: float | None = None,
        high: float | None = None,
        open_low: bool = False,
    ) -> float:
        if key not in table:
            if default is None:
                raise self.error(f"missing required key {key!r}")
            return default
        value = table[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.error(f"{key} must be a finite number, got {value!r}")
        if low is not None and (value < low or (open_low and value == low)):
            raise self.error(f"{key} = {value} must be {'>' if open_low else '>='} {low}")
        if high is not None and value > high:
            raise self.error(f"{key} = {value} must be <= {high}")
        return float(value)

    def integer(self, table: dict, key: str, default: int | None = None, *, low: int, high: int) -> int:
        if key not in table:
            if default is None:
                raise self.error(f"missing required key {key!r}")
            return default
        value = table[key]
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(f"{key} must be an integer, got {value!r}")
        if not low <= value <= high:
            raise self.error(f"{key} = {value} must be in [{low}, {high}]")
        return value

    def vector(
        self,
        table: dict,
        key: str,
        default: list[float] | None = None,
        *,
        length: int = 3,
        low: float | None = None,
        high: float | None = None,
        nonzero: bool = False,
    ) -> list[float]:
        if key not in table:
            if default is None:
                raise self.error(f"missing required key {key!r}")
            return list(default)
        value = table[key]
        if (
            not isinstance(value, list)
            or len(value) != length
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)
        ):
            raise self.error(f"{key} must be a list of {length} finite numbers, got {value!r}")
        if low is not None and min(value) < low or high is not None and max(value) > high:
            raise self.error(f"{key} = {value} must lie in [{low}, {high}] per component")
        if nonzero and not any(value):
            raise self.error(f"{key} must not be the zero vector")
        return [float(v) for v in value]


def _parse_camera(table: Any, source: str) -> Camera:
    w = _Where(source, "[camera]")
    table = w.keys(table, _CAMERA_KEYS)
    projection = table.get("projection", "orthographic")
    if projection not in ("orthographic", "perspective"):
        raise w.error(f"projection must be 'orthographic' or 'perspective', got {projection!r}")
    width = w.integer(table, "width", low=1, high=MAX_IMAGE_SIDE)
    height = w.integer(table, "height", low=1, high=MAX_IMAGE_SIDE)
    if projection == "orthographic":
        extra = sorted(set(table) & {"position", "look_at", "fov_deg", "up"})
        if extra:
            raise w.error(f"{', '.join(extra)} only apply to projection = 'perspective'")
        return Camera("orthographic", width, height)
    position = w.vector(table, "position", [0.0, 0.0, 4.0])
    look_at = w.vector(table, "look_at", [0.0, 0.0, 0.0])
    up = w.vector(table, "up", [0.0, 1.0, 0.0], nonzero=True)
    fov = w.number(table, "fov_deg", 30.0, low=0.0, high=179.0, open_low=True)
    if float(np.dot(position, position)) <= 1.0:
        raise w.error(f"position {position} is inside the unit sphere")
    forward = np.subtract(look_at, position)
    if not forward.any():
        raise w.error("look_at must differ from position")
    if np.linalg.norm(np.cross(forward, up)) < 1e-9 * np.linalg.norm(forward) * np.linalg.norm(up):
        raise w.error("up must not be parallel to the viewing direction")
    return Camera(
        "perspective", width, height, device_array(position), device_array(look_at), device_array(up), device_array(fov)
    )


def _parse_lights(items: Any, source: str) -> tuple[Lights, dict[tuple[str, int], str]]:
    """The lights, and the name of each in the file (``("point", 0)`` → ``"[[light]] #3"``)."""
    if not isinstance(items, list):
        raise SceneError(f"{source}: lights must be given as [[light]] tables")
    directional: list[tuple] = []
    point: list[tuple] = []
    ambient: list[float] = []
    numbers: dict[str, list[int]] = {"directional": [], "point": [], "ambient": []}
    for number, table in enumerate(items, start=1):
        w = _Where(source, f"[[light]] #{number}")
        if not isinstance(table, dict):
            raise w.error("must be a table")
        kind = table.get("kind")
        if kind not in _LIGHT_KEYS:
            raise w.error(f"kind must be one of {', '.join(_LIGHT_KEYS)}, got {kind!r}")
        w.keys(table, _LIGHT_KEYS[kind])
        intensity = w.number(table, "intensity", low=0.0)
        numbers[kind].append(number)
        if kind == "ambient":
            ambient.append(intensity)
            continue
        color = w.vector(table, "color", [1.0, 1.0, 1.0], low=0.0)
        if kind == "directional":
            direction = np.asarray(w.vector(table, "direction", nonzero=True))
            directional.append((direction / np.linalg.norm(direction), intensity, color))
        else:
            position = w.vector(table, "position")
            if float(np.dot(position, position)) <= 1.0:
                raise w.error(f"position {position} is inside the unit sphere")
            attenuation = w.vector(table, "attenuation", [1.0, 0.0, 0.0], low=0.0)
            if not any(attenuation):
                raise w.error("attenuation (c0, c1, c2) must not be all zero")
            point.append((position, intensity, color, attenuation))
    if not items:
        raise SceneError(f"{source}: the scene has no light; add at least one [[light]] table")
    names = {(kind, i): f"[[light]] #{n}" for kind in ("directional", "point") for i, n in enumerate(numbers[kind])}
    if numbers["ambient"]:  # the ambient lights are added into one intensity
        several = len(numbers["ambient"]) > 1
        listed = ", ".join(f"#{n}" for n in numbers["ambient"])
        names[("ambient", 0)] = f"[[light]] {listed} (ambient, added)" if several else f"[[light]] {listed}"
    lights = Lights(
        directional=DirectionalLights(
            direction=device_array(np.array([d[0] for d in directional])),
            intensity=device_array([d[1] for d in directional]),
            color=device_array([d[2] for d in directional]),
        )
        if directional
        else None,
        point=PointLights(
            position=device_array([p[0] for p in point]),
            intensity=device_array([p[1] for p in point]),
            color=device_array([p[2] for p in point]),
            attenuation=device_array([p[3] for p in point]),
        )
        if point
        else None,
        ambient=device_array(sum(ambient)) if ambient else None,
    )
    return lights, names


def _parse_background(table: Any, source: str, base_dir: Path) -> Background:
    w = _Where(source, "[background]")
    if not isinstance(table, dict):
        raise w.error("must be a table")
    kind = table.get("kind", "color")
    if kind not in BACKGROUND_KINDS:
        raise w.error(f"kind must be one of {', '.join(BACKGROUND_KINDS)}, got {kind!r}")
    w.keys(table, _BACKGROUND_KEYS[kind])
    color = device_array(w.vector(table, "color", [0.0, 0.0, 0.0], low=0.0))
    if kind == "color":
        return Background("color", color)
    if kind == "checkerboard":
        colors = table.get("colors", [[0.9, 0.9, 0.9], [0.1, 0.1, 0.1]])
        if not isinstance(colors, list) or len(colors) != 2:
            raise w.error(f"colors must be a list of two RGB colours, got {colors!r}")
        pair = [w.vector({"colors": c}, "colors", low=0.0) for c in colors]
        return Background(
            "checkerboard",
            color,
            point=device_array(w.vector(table, "point", [0.0, 0.0, -2.0])),
            normal=device_array(w.vector(table, "normal", [0.0, 0.0, 1.0], nonzero=True)),
            square_size=device_array(w.number(table, "square_size", 0.5, low=0.0, open_low=True)),
            colors=device_array(pair),
            sharpness=device_array(w.number(table, "sharpness", 20.0, low=0.0, open_low=True)),
        )
    if "image" not in table or not isinstance(table["image"], str):
        raise w.error('an environment background needs image = "PATH" (latitude-longitude)')
    from ..io.images import read_image  # local import: it pulls in OpenImageIO

    path = Path(table["image"])
    if not path.is_absolute():
        path = base_dir / path
    scale = w.number(table, "scale", 1.0, low=0.0)
    try:
        image = read_image(path, encoding="auto").pixels
    except StraussFitError as exc:
        raise w.error(str(exc)) from None
    bad = int(np.sum(~np.all(np.isfinite(image), axis=-1)))
    if bad:  # checked here, before any work: a NaN would spread through every render and fit
        raise w.error(f"environment image {path} has {bad} pixel(s) with NaN or infinite values")
    image = image * scale
    if not np.all(np.isfinite(image)):
        raise w.error(f"scale = {scale:g} makes environment image {path} overflow to infinity")
    return Background("environment", color, image=device_array(image))


# --- the renderer's range ------------------------------------------------------------------


def background_peak(background: Background) -> float | None:
    """The largest radiance (absolute value, any channel) that a ray can see in
    ``background``, or None if its values are traced. Every kind interpolates between its
    colours or pixels with weights in [0, 1], so nothing it shows exceeds this."""
    if background.kind == "color":
        parts = [background.color]
    elif background.kind == "checkerboard":
        parts = [background.color, background.colors]
    else:
        parts = [background.image]
    try:
        values = [np.asarray(part) for part in parts if part is not None]
    except jax.errors.TracerArrayConversionError:
        return None
    return max((float(np.max(np.abs(v))) for v in values if v.size), default=0.0)


class LightPeak(NamedTuple):
    """One light's share of the radiance scale (`light_peaks`)."""

    kind: str  #: "directional", "point" or "ambient" (all ambient lights added)
    index: int  #: position among the lights of its kind
    intensity: float
    color: float  #: brightest colour component (1 for ambient light)
    distance: float  #: from a point light to the sphere's nearest point (0 otherwise)
    attenuation: float  #: c0 + c1 d + c2 d^2 at that distance (1 otherwise)
    peak: float  #: intensity × max(1, color) / attenuation (inf where it overflows)


def _peak(intensity: float, color: float, attenuation: float) -> float:
    scaled = intensity * max(1.0, color)  # Python floats: inf on overflow, no exception
    if scaled == 0:
        return 0.0
    return scaled / attenuation if attenuation > 0 else math.inf


def light_peaks(lights: Lights) -> list[LightPeak]:
    """Every light's peak irradiance at the sphere: its intensity × max(1, brightest colour
    component), divided for a point light by its attenuation at the sphere's nearest point
    (distance `d = |p| - 1`; the attenuation grows with d). One light adds at most 3
    × its peak to a pixel: the diffuse, specular and metallic-tint weights are each at most
    1, and the tint, `w (C - C_L)`, is non-zero even for a black light colour (hence
    max(1, ·)). Concrete values only."""
    peaks: list[LightPeak] = []
    if lights.directional is not None:
        d = lights.directional
        for i, (intensity, color) in enumerate(zip(np.asarray(d.intensity).tolist(), np.asarray(d.color).tolist())):
            brightest = max(color)
            peaks.append(LightPeak("directional", i, intensity, brightest, 0.0, 1.0, _peak(intensity, brightest, 1.0)))
    if lights.point is not None:
        p = lights.point
        rows = zip(
            np.asarray(p.intensity).tolist(),
            np.asarray(p.color).tolist(),
            np.asarray(p.position).tolist(),
            np.asarray(p.attenuation).tolist(),
        )
        for i, (intensity, color, position, (c0, c1, c2)) in enumerate(rows):
            distance = max(math.hypot(*position) - 1.0, 0.0)
            falloff = c0 + c1 * distance + c2 * distance * distance
            brightest = max(color)
            peaks.append(
                LightPeak("point", i, intensity, brightest, distance, falloff, _peak(intensity, brightest, falloff))
            )
    if lights.ambient is not None:
        ambient = float(np.asarray(lights.ambient))
        peaks.append(LightPeak("ambient", 0, ambient, 1.0, 0.0, 1.0, ambient))
    return peaks


def _light_name(kind: str, index: int, names: dict[tuple[str, int], str] | None) -> str:
    if names and (kind, index) in names:
        return names[(kind, index)]
    return "the ambient light" if kind == "ambient" else f"{kind} light #{index + 1}"


def check_radiance_range(scene: Scene, source: str = "scene", names: dict[tuple[str, int], str] | None = None) -> None:
    """Raise a one-line `RadianceRangeError` if the scene is outside the renderer's
    range (module docstring): a light's intensity, colour component or peak irradiance
    (`light_peaks`), a background radiance (`background_peak`), or their sum,
    above `MAX_RADIANCE`. ``names`` names the lights by ``(kind, index)`` (a scene
    file's ``[[light]] #n``). Does nothing for traced lights or background (the values are
    read with ``np.asarray``, which a tracer refuses)."""
    try:
        peaks = light_peaks(scene.lights)
    except jax.errors.TracerArrayConversionError:
        return
    background = background_peak(scene.background)
    if background is None:
        return
    total = sum(light.peak for light in peaks) + background  # (inf or NaN fail every test below)
    parts = [background] + [value for light in peaks for value in (light.intensity, light.color, light.peak)]
    if total <= MAX_RADIANCE and all(value <= MAX_RADIANCE for value in parts):
        return
    limit = f"{MAX_RADIANCE:g}"
    for light in peaks:
        name = _light_name(light.kind, light.index, names)
        where = f"{source}: {name}"
        if not light.intensity <= MAX_RADIANCE:
            raise RadianceRangeError(
                f"{where}: intensity {light.intensity:g} overflows the renderer's range: a light's intensity "
                f"must be at most {limit}"
            )
        if not light.color <= MAX_RADIANCE:
            raise RadianceRangeError(
                f"{where}: color component {light.color:g} overflows the renderer's range: a light's colour "
                f"components must be at most {limit}"
            )
        if not light.peak <= MAX_RADIANCE:
            if light.kind == "point":
                detail = (
                    f"intensity {light.intensity:g} × max(1, color {light.color:g}) ÷ attenuation "
                    f"{light.attenuation:.3g} at the sphere's nearest point (distance {light.distance:.3g})"
                )
            else:
                detail = f"intensity {light.intensity:g} × max(1, color {light.color:g})"
            raise RadianceRangeError(
                f"{where}: peak irradiance {detail} = {light.peak:.3g} overflows the renderer's range (at most {limit})"
            )
    if not background <= MAX_RADIANCE:
        raise RadianceRangeError(
            f"{source}: [background]: radiance {background:g} overflows the renderer's range: background "
            f"colours (an environment image × scale) must be at most {limit}"
        )
    if not total <= MAX_RADIANCE:
        largest = max(peaks, key=lambda light: light.peak)
        raise RadianceRangeError(
            f"{source}: the lights' peak irradiances and the background's radiance add up to {total:.3g}, "
            f"more than the renderer's range ({limit}); the largest: "
            f"{_light_name(largest.kind, largest.index, names)} ({largest.peak:.3g})"
        )


@uses_float64
def parse_scene(data: dict[str, Any], source: str = "scene", base_dir: Path | str = ".") -> Scene:
    """Build a `Scene` from a parsed TOML mapping (see docs/formats.md, scene files)."""
    unknown = sorted(set(data) - _SECTIONS)
    if unknown:
        raise SceneError(f"{source}: unknown section(s) {', '.join(unknown)}; allowed: {', '.join(sorted(_SECTIONS))}")
    if "camera" not in data:
        raise SceneError(f"{source}: missing [camera] section")
    if "light" not in data:
        raise SceneError(f"{source}: the scene has no light; add at least one [[light]] table")
    camera = _parse_camera(data["camera"], source)
    lights, light_names = _parse_lights(data["light"], source)
    background = _parse_background(data.get("background", {}), source, Path(base_dir))
    material_table = data.get("material", {})
    if not isinstance(material_table, dict):
        raise SceneError(f"{source}: [material] must be a table")
    try:
        material = Material.from_dict(material_table)
    except MaterialError as exc:
        raise SceneError(f"{source}: [material]: {exc}") from None
    render_table = _Where(source, "[render]").keys(data.get("render", {}), _RENDER_KEYS)
    depth = _Where(source, "[render]").integer(render_table, "depth", DEFAULT_DEPTH, low=1, high=64)
    scene = Scene(camera=camera, lights=lights, background=background, material=material, depth=depth)
    check_radiance_range(scene, source, light_names)
    return scene


@uses_float64
def load_scene(path: str | Path) -> Scene:
    """Read and validate a TOML scene file (its format: docs/formats.md).

    Examples:
        >>> import strauss_fit as sf
        >>> scene = sf.load_scene("data_synth/scenes/key_and_fill.toml")
        >>> scene.camera.width, scene.lights.count, float(scene.material.smoothness)
        (40, 2, 0.5)
    """
    path = Path(path)
    if path.is_dir():
        raise SceneError(f"scene file is a directory: {path}")
    check_input_file(path, "scene file", SceneError)  # a FIFO would block the read
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise SceneError(f"cannot read scene file {path}: {exc}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{path}: not valid TOML: {exc}") from None
    return parse_scene(data, source=str(path), base_dir=path.parent)
