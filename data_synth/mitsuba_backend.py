r"""Physically based reference targets: the canonical scene rendered by Mitsuba 3.

Until now every target of strauss-fit was rendered by strauss-fit itself. This module renders
the *same scene* (a scene definition mapping, as a synth sidecar stores it under
``scene.definition``) with a physically based BSDF in Mitsuba 3, so that fits can be tested on
images a Strauss material cannot reproduce exactly (GGX highlights, measured metals,
Fresnel-weighted plastic coats, refraction by real glass).

Mitsuba is optional and imported only when rendering (`render_mitsuba`); everything
else here — the BSDF schema (`validate_bsdf`), the scene translation
(`translate_scene`), the sphere coverage and the directly seen background
(`coverage_and_background`) — is numpy only. strauss-fit is used only to validate a
definition (`strauss_fit.parse_scene`, when importable) and for its error base class.

Radiometric correspondence (docs/datasets.md has the derivation and what cannot correspond):

- directional light of intensity I, colour c, direction L (toward the light): Mitsuba
  ``directional`` with ``direction = -L`` and ``irradiance = π·I·c``. A white Lambertian
  (albedo ρ) then has radiance ρ·I·cos α, Strauss's diffuse term for s = m = t = 0.
- point light at p: Mitsuba ``point`` at p with ``intensity = π·I·c / c2``. Only the
  physical falloff, attenuation (0, 0, c2), has a counterpart; any c0 or c1 is refused.
- ambient intensity I_a (summed): a constant environment of radiance I_a (Mitsuba allows one
  environment emitter, so with an environment background it is added to the map). A
  Lambertian sphere under it has radiance ρ·I_a, Strauss's ambient term; but the sphere also
  *reflects* it (Strauss reflects the background instead) and a rough or glossy surface
  receives it through its whole BRDF, not through r_d·C.
- background: what the camera sees directly where it misses the sphere is not rendered by
  Mitsuba (``hide_emitters``) but composited exactly as strauss-fit defines it, weighted by
  the uncovered fraction of each pixel. What the *sphere* sees (reflection, refraction,
  indirect light) is Mitsuba's world: the ambient environment for a colour background; the
  checkerboard as an emitting (unlit) plane of half-size `BOARD_HALF_SIZE` with the
  same softened squares; an environment map resampled so that Mitsuba's lookup equals
  strauss-fit's bilinear lookup exactly (plus ambient).
- camera: strauss-fit's pixel grid (orthographic: the image spans x, y ∈ [−1, 1], pixel
  (i, k) centred at x = (k + ½)/W·2 − 1, y = 1 − (i + ½)/H·2 as in ``docs/formats.md``;
  perspective: vertical ``fov_deg``); box pixel filter, so a silhouette pixel is the area
  average of sphere and background, and `sphere_coverage` says how much is sphere.
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

try:  # one-line user errors, printed by the CLI like every other strauss-fit error
    from strauss_fit.errors import StraussFitError as _ErrorBase
except ImportError:  # pragma: no cover - strauss-fit is always installed in practice
    _ErrorBase = ValueError


class MitsubaBackendError(_ErrorBase):
    """A BSDF or scene cannot be rendered by the Mitsuba backend (one-line message)."""


class MitsubaUnavailableError(MitsubaBackendError):
    """Mitsuba 3 is not installed, or the requested variant cannot be loaded."""


#: Variants the backend knows; ``scalar_rgb`` needs nothing else, ``llvm_ad_rgb`` needs
#: libLLVM (Debian: ``apt-get install libllvm19``).
VARIANTS = ("scalar_rgb", "llvm_ad_rgb")
#: Minimum Mitsuba version. Checkerboard backgrounds need `MIN_VERSION_BOARD`: before
#: 3.8 the path tracer's ``hide_emitters`` hid only the environment, so the camera would see
#: the emitting board directly and the composited background would count it twice. Tested:
#: 3.9.1 (the envmap lookup convention used by `environment_for_mitsuba` is the same
#: from 3.5 to 3.9).
MIN_VERSION = (3, 5, 0)
MIN_VERSION_BOARD = (3, 8, 0)

#: Named conductors of Mitsuba 3.9 (``data/ior/<name>.eta.spd``) plus ``none`` (a perfect
#: mirror). Checked without Mitsuba; `named_metals` reads the installed list.
NAMED_METALS = frozenset(
    """
    a-C Ag Al AlAs AlAs_palik AlSb AlSb_palik Au Be Be_palik Cr CsI CsI_palik Cu Cu2O
    Cu2O_palik CuO CuO_palik Cu_palik d-C d-C_palik Hg HgTe HgTe_palik Hg_palik Ir Ir_palik K
    K_palik Li Li_palik MgO MgO_palik Mo Mo_palik Na_palik Nb Nb_palik Ni_palik Rh Rh_palik Se
    Se-e Se-e_palik Se_palik SiC SiC_palik SnTe SnTe_palik Ta Ta_palik Te Te-e Te-e_palik
    Te_palik ThF4 ThF4_palik TiC TiC_palik TiN TiN_palik TiO2 TiO2-e TiO2-e_palik TiO2_palik
    V_palik VC VC_palik VN VN_palik W none
""".split()
)

#: Half-size of the emitting plane that stands in for strauss-fit's infinite checkerboard.
BOARD_HALF_SIZE = 1000.0
#: Texels per side of one checkerboard tile (2 × 2 squares) baked for Mitsuba.
BOARD_TILE_TEXELS = 1024
#: Height of the orthographic camera's ray origins (strauss-fit: ORTHOGRAPHIC_ORIGIN_Z).
ORTHOGRAPHIC_ORIGIN_Z = 2.0
#: strauss-fit's horizon fade of the checkerboard (background.HORIZON_FADE).
HORIZON_FADE = 100.0
#: Default path depth and Russian-roulette start (glass needs many internal bounces).
DEFAULT_MAX_DEPTH = 32
DEFAULT_RR_DEPTH = 32


# --- BSDF schema --------------------------------------------------------------------------


@dataclass(frozen=True)
class _Param:
    kind: str  # "rgb01", "unit", "alpha", "ior", "positive", "choice", "bool", "rgb_pos"
    default: Any = None  # None: optional without default (left to Mitsuba or forbidden)
    choices: tuple[str, ...] = ()
    doc: str = ""


_DIST = ("ggx", "beckmann")
_COMMON_IOR = {
    "int_ior": _Param("ior", 1.5, doc="interior index of refraction"),
    "ext_ior": _Param("ior", 1.0, doc="exterior index of refraction (vacuum, as in Strauss)"),
}
_ROUGH = {
    "distribution": _Param("choice", "ggx", _DIST, "microfacet distribution"),
    "alpha": _Param("alpha", 0.1, doc="roughness (RMS slope for Beckmann, GGX α)"),
}

#: The BSDFs the backend renders and their parameters (Mitsuba's names and meanings).
BSDF_SCHEMA: dict[str, dict[str, _Param]] = {
    "diffuse": {"reflectance": _Param("rgb01", 0.5, doc="albedo")},
    "plastic": {
        "diffuse_reflectance": _Param("rgb01", 0.5),
        **_COMMON_IOR,
        "nonlinear": _Param("bool", False),
        "specular_reflectance": _Param("rgb01", 1.0, doc="scale of the coat's reflection (0: the body alone)"),
    },
    "roughplastic": {
        "diffuse_reflectance": _Param("rgb01", 0.5),
        **_COMMON_IOR,
        **_ROUGH,
        "nonlinear": _Param("bool", False),
        "specular_reflectance": _Param("rgb01", 1.0, doc="scale of the coat's reflection (0: the body alone)"),
    },
    "conductor": {
        "material": _Param("choice", "none", tuple(sorted(NAMED_METALS)), "named metal"),
        "eta": _Param("rgb_pos"),
        "k": _Param("rgb_pos"),
        "specular_reflectance": _Param("rgb01", 1.0),
    },
    "roughconductor": {
        "material": _Param("choice", "none", tuple(sorted(NAMED_METALS))),
        "eta": _Param("rgb_pos"),
        "k": _Param("rgb_pos"),
        "specular_reflectance": _Param("rgb01", 1.0),
        **_ROUGH,
    },
    "principled": {
        "base_color": _Param("rgb01", 0.5),
        "roughness": _Param("unit", 0.5),
        "metallic": _Param("unit", 0.0),
        "specular": _Param("unit"),
        "eta": _Param("ior"),
        "spec_tint": _Param("unit", 0.0),
        "spec_trans": _Param("unit", 0.0),
        "anisotropic": _Param("unit", 0.0),
        "sheen": _Param("unit", 0.0),
        "sheen_tint": _Param("unit", 0.0),
        "clearcoat": _Param("unit", 0.0),
        "clearcoat_gloss": _Param("unit", 0.0),
    },
    "dielectric": {**_COMMON_IOR},
    "roughdielectric": {**_COMMON_IOR, **_ROUGH},
}


def named_metals() -> frozenset[str]:
    """The conductor names the installed Mitsuba knows (its ``data/ior`` folder), or
    `NAMED_METALS` if Mitsuba is not installed."""
    try:
        import importlib.util

        spec = importlib.util.find_spec("mitsuba")
    except (ImportError, ValueError):
        spec = None
    if spec is None or not spec.submodule_search_locations:
        return NAMED_METALS
    folder = Path(list(spec.submodule_search_locations)[0]) / "data" / "ior"
    names = {p.name[: -len(".eta.spd")] for p in folder.glob("*.eta.spd")}
    return frozenset(names | {"none"}) if names else NAMED_METALS


def _is_number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _check_param(where: str, name: str, p: _Param, value: Any) -> Any:
    def fail(expected: str) -> MitsubaBackendError:
        return MitsubaBackendError(f"{where}: {name} must be {expected}, got {value!r}")

    if p.kind in ("rgb01", "rgb_pos"):
        numbers = [value] if _is_number(value) else value
        if not (isinstance(numbers, list) and len(numbers) in (1, 3) and all(_is_number(v) for v in numbers)):
            raise fail("a number or a list of 3 numbers")
        if p.kind == "rgb01" and not all(0.0 <= v <= 1.0 for v in numbers):
            raise fail("in [0, 1] (per channel)")
        if p.kind == "rgb_pos" and not all(v >= 0.0 for v in numbers):
            raise fail(">= 0 (per channel)")
        numbers = [float(v) for v in numbers]
        return numbers * 3 if len(numbers) == 1 else numbers
    if p.kind == "unit":
        if not _is_number(value) or not 0.0 <= value <= 1.0:
            raise fail("a number in [0, 1]")
        return float(value)
    if p.kind == "alpha":
        if not _is_number(value) or not 1e-4 <= value <= 1.0:
            raise fail("a number in [0.0001, 1]")
        return float(value)
    if p.kind == "ior":
        if not _is_number(value) or not 1.0 <= value <= 4.0:
            raise fail("a number in [1, 4]")
        return float(value)
    if p.kind == "choice":
        if value not in p.choices:
            shown = ", ".join(p.choices) if len(p.choices) <= 8 else ", ".join(p.choices[:8]) + ", ..."
            raise fail(f"one of {shown}")
        return value
    if p.kind == "bool":
        if not isinstance(value, bool):
            raise fail("true or false")
        return value
    raise AssertionError(p.kind)  # pragma: no cover


def validate_bsdf(bsdf: Mapping[str, Any], where: str = "bsdf") -> dict[str, Any]:
    """Check a BSDF table (``{"type": NAME, PARAM: VALUE, ...}``) and return it complete:
    defaults filled in, colours as 3-lists of floats. Raises `MitsubaBackendError`
    with one line naming the problem (unknown type or key, wrong type, out of range, a
    metal Mitsuba does not know)."""
    if not isinstance(bsdf, Mapping):
        raise MitsubaBackendError(f"{where}: must be a table with a 'type', got {bsdf!r}")
    kind = bsdf.get("type")
    if kind not in BSDF_SCHEMA:
        raise MitsubaBackendError(f"{where}: unknown BSDF type {kind!r}; expected one of {', '.join(BSDF_SCHEMA)}")
    schema = BSDF_SCHEMA[kind]
    unknown = sorted(set(bsdf) - set(schema) - {"type"})
    if unknown:
        raise MitsubaBackendError(
            f"{where}: unknown key(s) {', '.join(unknown)} for type {kind!r}; allowed: {', '.join(schema)}"
        )
    out: dict[str, Any] = {"type": kind}
    for name, p in schema.items():
        if name in bsdf:
            if name == "material" and bsdf[name] not in NAMED_METALS:
                raise MitsubaBackendError(
                    f"{where}: unknown metal {bsdf[name]!r} for material; Mitsuba knows "
                    f"{', '.join(sorted(m for m in NAMED_METALS if '_' not in m))} "
                    "(and *_palik variants)"
                )
            out[name] = _check_param(f"{where} ({kind})", name, p, bsdf[name])
        elif p.default is not None:
            out[name] = copy.deepcopy(p.default)
            if p.kind in ("rgb01", "rgb_pos") and _is_number(p.default):
                out[name] = [float(p.default)] * 3
    if kind in ("conductor", "roughconductor"):
        given = [k for k in ("eta", "k") if k in bsdf]
        if given and "material" in bsdf:
            raise MitsubaBackendError(f"{where} ({kind}): give either material or eta and k, not both")
        if len(given) == 1:
            raise MitsubaBackendError(f"{where} ({kind}): eta and k must be given together")
        if given:
            out.pop("material")
    if kind == "principled":
        if "eta" in out and "specular" in out:
            raise MitsubaBackendError(f"{where} (principled): give either specular or eta, not both")
        if "eta" not in out and "specular" not in out:
            out["specular"] = 0.5
    if "int_ior" in out and out["int_ior"] == out["ext_ior"] and kind in ("plastic", "roughplastic"):
        raise MitsubaBackendError(f"{where} ({kind}): int_ior and ext_ior must differ")
    return out


def _rgb(value: list[float]) -> dict[str, Any]:
    return {"type": "rgb", "value": [float(v) for v in value]}


def bsdf_to_mitsuba(bsdf: Mapping[str, Any]) -> dict[str, Any]:
    """The Mitsuba ``load_dict`` entry of a validated BSDF table (no Mitsuba import)."""
    b = validate_bsdf(bsdf)
    out: dict[str, Any] = {"type": b["type"]}
    for name, value in b.items():
        if name == "type":
            continue
        p = BSDF_SCHEMA[b["type"]][name]
        out[name] = _rgb(value) if p.kind in ("rgb01", "rgb_pos") else value
    return out


# --- scene translation --------------------------------------------------------------------


@dataclass
class Translation:
    """A scene definition translated for Mitsuba, as plain data (JSON-able via
    `to_dict`): the camera, the emitters with their radiometric values, the ambient
    radiance, the background, and ``notes`` on what does not correspond."""

    camera: dict[str, Any]
    emitters: list[dict[str, Any]]
    ambient: float
    background: dict[str, Any]
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {
            "camera": self.camera,
            "emitters": self.emitters,
            "ambient_radiance": self.ambient,
            "background": {k: v for k, v in self.background.items() if k != "image_data"},
            "notes": list(self.notes),
        }


def _vec(table: Mapping[str, Any], key: str, default: list[float]) -> list[float]:
    return [float(v) for v in table.get(key, default)]


def _normalise(v: list[float]) -> list[float]:
    n = math.sqrt(sum(x * x for x in v))
    return [x / n for x in v]


def translate_scene(definition: Mapping[str, Any], base_dir: str | Path = ".", *, validate: bool = True) -> Translation:
    """Translate a strauss-fit scene definition (the TOML mapping) for Mitsuba.

    With ``validate`` (default) the definition is first checked by strauss-fit's own
    `strauss_fit.parse_scene` when strauss-fit is importable. Raises
    `MitsubaBackendError` for what has no physical counterpart: a point light whose
    attenuation is not (0, 0, c2).
    """
    definition = copy.deepcopy(dict(definition))
    base_dir = Path(base_dir)
    if validate:
        try:
            from strauss_fit import parse_scene
        except ImportError:  # pragma: no cover
            parse_scene = None
        if parse_scene is not None:
            parse_scene(copy.deepcopy(definition), source="scene", base_dir=base_dir)
    notes: list[str] = []
    cam = dict(definition.get("camera", {}))
    projection = cam.get("projection", "orthographic")
    camera: dict[str, Any] = {"projection": projection, "width": int(cam["width"]), "height": int(cam["height"])}
    if projection == "perspective":
        camera.update(
            position=_vec(cam, "position", [0.0, 0.0, 4.0]),
            look_at=_vec(cam, "look_at", [0.0, 0.0, 0.0]),
            up=_vec(cam, "up", [0.0, 1.0, 0.0]),
            fov_deg=float(cam.get("fov_deg", 30.0)),
            fov_axis="y",
        )
    emitters: list[dict[str, Any]] = []
    ambient = 0.0
    for number, light in enumerate(definition.get("light", []), start=1):
        kind = light.get("kind")
        intensity = float(light.get("intensity", 0.0))
        if kind == "ambient":
            ambient += intensity
            continue
        color = _vec(light, "color", [1.0, 1.0, 1.0])
        if kind == "directional":
            to_light = _normalise(_vec(light, "direction", [0.0, 0.0, 1.0]))
            emitters.append(
                {
                    "type": "directional",
                    "direction": [-x for x in to_light],
                    "irradiance": [math.pi * intensity * c for c in color],
                    "light": number,
                }
            )
        elif kind == "point":
            attenuation = _vec(light, "attenuation", [1.0, 0.0, 0.0])
            c0, c1, c2 = attenuation
            if c0 != 0.0 or c1 != 0.0 or c2 <= 0.0:
                raise MitsubaBackendError(
                    f"[[light]] #{number}: point light attenuation {attenuation} has no physical counterpart; "
                    "a physical point light falls off as 1/d^2, so use attenuation = [0.0, 0.0, c2] "
                    "(intensity/c2 becomes the radiant intensity/π)"
                )
            emitters.append(
                {
                    "type": "point",
                    "position": _vec(light, "position", [0.0, 0.0, 0.0]),
                    "intensity": [math.pi * intensity * c / c2 for c in color],
                    "light": number,
                }
            )
        else:  # pragma: no cover - parse_scene refuses it first
            raise MitsubaBackendError(f"[[light]] #{number}: unknown kind {kind!r}")
    bg = dict(definition.get("background", {}))
    kind = bg.get("kind", "color")
    background: dict[str, Any] = {"kind": kind, "color": _vec(bg, "color", [0.0, 0.0, 0.0])}
    if kind == "checkerboard":
        background.update(
            point=_vec(bg, "point", [0.0, 0.0, -2.0]),
            normal=_normalise(_vec(bg, "normal", [0.0, 0.0, 1.0])),
            square_size=float(bg.get("square_size", 0.5)),
            colors=[[float(c) for c in pair] for pair in bg.get("colors", [[0.9, 0.9, 0.9], [0.1, 0.1, 0.1]])],
            sharpness=float(bg.get("sharpness", 20.0)),
        )
        n = np.asarray(background["normal"])
        side = float(np.dot(-np.asarray(background["point"]), n))  # > 0: the sphere is on the normal's side
        toward_sphere = n if side >= 0 else -n
        for e in emitters:
            blocked = (
                np.dot(-np.asarray(e["direction"]), toward_sphere) < 0
                if e["type"] == "directional"
                else np.dot(np.asarray(e["position"]) - np.asarray(background["point"]), toward_sphere) < 0
            )
            if blocked:
                notes.append(
                    f"light #{e['light']} is behind the checkerboard plane: Mitsuba's plane shadows it, "
                    "strauss-fit's does not"
                )
        notes.append(
            "the checkerboard is an emitting plane of half-size "
            f"{BOARD_HALF_SIZE:g}: it also lights the sphere (strauss-fit shows it only in reflection and "
            "refraction), its far squares average out by pixel sampling instead of strauss-fit's horizon fade, "
            "and rays that miss it see the ambient environment, not background.color"
        )
    elif kind == "environment":
        if "image" not in bg:
            raise MitsubaBackendError('[background]: an environment background needs image = "PATH"')
        path = Path(bg["image"])
        background.update(image=str(path if path.is_absolute() else base_dir / path), scale=float(bg.get("scale", 1.0)))
        notes.append(
            "the environment map lights the sphere diffusely and glossily (image-based lighting); "
            "strauss-fit shows it only in the mirror reflection and refraction of the global model"
        )
    if ambient > 0:
        notes.append(
            f"ambient {ambient:g} is a constant environment of that radiance: the sphere also reflects it "
            "(strauss-fit's global model reflects the background colour instead) and glossy lobes receive it"
        )
    return Translation(camera, emitters, ambient, background, notes)


# --- geometry, coverage and the directly seen background (numpy, no Mitsuba) ---------------


def _subpixel_rays(camera: Mapping[str, Any], sub: int) -> tuple[np.ndarray, np.ndarray]:
    """Origins and directions (H, W, sub·sub, 3) of a stratified sub-pixel grid, strauss-fit's
    pixel convention (pixel (i, k) covers x ∈ [k, k+1]/W·2 − 1, y ∈ 1 − [i, i+1]/H·2)."""
    width, height = camera["width"], camera["height"]
    offsets = (np.arange(sub) + 0.5) / sub
    xs = ((np.arange(width)[:, None] + offsets[None, :]) / width * 2 - 1).reshape(width, sub)
    ys = (1 - (np.arange(height)[:, None] + offsets[None, :]) / height * 2).reshape(height, sub)
    x = np.broadcast_to(xs[None, :, None, :], (height, width, sub, sub)).reshape(height, width, sub * sub)
    y = np.broadcast_to(ys[:, None, :, None], (height, width, sub, sub)).reshape(height, width, sub * sub)
    return _rays_at(camera, x, y)


def _rays_at(camera: Mapping[str, Any], x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    if camera["projection"] == "orthographic":
        origin = np.stack([x, y, np.full_like(x, ORTHOGRAPHIC_ORIGIN_Z)], axis=-1)
        direction = np.broadcast_to(np.array([0.0, 0.0, -1.0]), origin.shape)
        return origin, direction
    position = np.asarray(camera["position"], dtype=float)
    forward = np.asarray(camera["look_at"], dtype=float) - position
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, np.asarray(camera["up"], dtype=float))
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    half = math.tan(math.radians(camera["fov_deg"]) / 2)
    aspect = camera["width"] / camera["height"]
    d = forward + (x * half * aspect)[..., None] * right + (y * half)[..., None] * up
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return np.broadcast_to(position, d.shape), d


def _hits_sphere(origin: np.ndarray, direction: np.ndarray) -> np.ndarray:
    b = np.sum(origin * direction, axis=-1)
    c = np.sum(origin * origin, axis=-1) - 1
    disc = b * b - c
    return (disc > 0) & (-b - np.sqrt(np.maximum(disc, 0)) > 0)


def _orthographic_coverage(width: int, height: int, samples: int = 2048) -> np.ndarray:
    """Exact (to ~1e-7) fraction of each pixel inside the unit disk: the area integral
    ∫ |[y0, y1] ∩ [−√(1−x²), √(1−x²)]| dx by the midpoint rule on ``samples`` columns per pixel."""
    dx, dy = 2.0 / width, 2.0 / height
    xs = -1 + (np.arange(width * samples) + 0.5) * dx / samples  # fine midpoints
    half = np.sqrt(np.clip(1 - xs**2, 0, None))
    y_top = 1 - np.arange(height) * dy  # row i spans [y_top - dy, y_top]
    lo = np.maximum(y_top[:, None] - dy, -half[None, :])
    hi = np.minimum(y_top[:, None], half[None, :])
    length = np.clip(hi - lo, 0, None)  # (H, W·samples)
    return length.reshape(height, width, samples).mean(axis=-1) / dy


def _corner_hits(camera: Mapping[str, Any]) -> np.ndarray:
    """Whether the ray through each pixel corner hits the sphere, (H+1, W+1)."""
    width, height = camera["width"], camera["height"]
    x = np.arange(width + 1) / width * 2 - 1
    y = 1 - np.arange(height + 1) / height * 2
    xx, yy = np.meshgrid(x, y)
    return _hits_sphere(*_rays_at(camera, xx, yy))


def sphere_coverage(camera: Mapping[str, Any], sub: int = 32) -> np.ndarray:
    """Fraction (H, W) of each pixel's area in which the sphere is seen.

    Orthographic: the exact disk–square overlap. Perspective: a ``sub`` × ``sub`` stratified
    sub-pixel grid (error ≲ 1/sub² per pixel); pixels whose four corners all see the sphere
    are exactly 1 (the silhouette is convex), others are kept below 1.
    """
    corners = _corner_hits(camera)
    full = corners[:-1, :-1] & corners[1:, :-1] & corners[:-1, 1:] & corners[1:, 1:]
    if camera["projection"] == "orthographic":
        cover = _orthographic_coverage(camera["width"], camera["height"])
    else:
        origin, direction = _subpixel_rays(camera, sub)
        cover = _hits_sphere(origin, direction).mean(axis=-1)
    cover = np.where(full, 1.0, np.minimum(cover, 1.0 - 1e-9))
    return np.clip(cover, 0.0, 1.0)


def _plane_axes(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    helper = np.array([0.0, 1.0, 0.0]) if abs(normal[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(helper, normal)
    u /= np.linalg.norm(u)
    return u, np.cross(normal, u)


def checker_weight(u: np.ndarray, v: np.ndarray, sharpness: float) -> np.ndarray:
    """strauss-fit's softened checker weight of colours[0] at square coordinates (u, v)."""
    return 0.5 + 0.5 * np.tanh(sharpness * np.sin(np.pi * u) * np.sin(np.pi * v))


def _checkerboard_radiance(bg: Mapping[str, Any], origin: np.ndarray, direction: np.ndarray) -> np.ndarray:
    normal = np.asarray(bg["normal"], dtype=float)
    point = np.asarray(bg["point"], dtype=float)
    facing = direction @ normal
    with np.errstate(divide="ignore", invalid="ignore"):
        distance = np.where(facing != 0, ((point - origin) @ normal) / np.where(facing != 0, facing, 1), 0)
    hits = (facing != 0) & (distance > 0)
    where = origin + distance[..., None] * direction
    u_axis, v_axis = _plane_axes(normal)
    size = bg["square_size"]
    u = (where - point) @ u_axis / size
    v = (where - point) @ v_axis / size
    height = abs(point @ normal)
    with np.errstate(divide="ignore"):
        inverse_rate = np.where(height > 0, size * facing**2 * HORIZON_FADE / max(height, 1e-300), np.inf)
    contrast = np.exp(-((1.0 / np.maximum(inverse_rate, 1.0 / 3.0)) ** 8))
    w = 0.5 + 0.5 * contrast * np.tanh(bg["sharpness"] * np.sin(np.pi * u) * np.sin(np.pi * v))
    c0, c1 = (np.asarray(c, dtype=float) for c in bg["colors"])
    board = c1 + w[..., None] * (c0 - c1)
    return np.where(hits[..., None], board, np.asarray(bg["color"], dtype=float))


def read_environment(path: str | Path) -> np.ndarray:
    """A latitude–longitude image as linear RGB float64 (H, W, 3), read as strauss-fit does
    (HDR formats linear, 8-bit formats sRGB-decoded; grey replicated, alpha dropped)."""
    import OpenImageIO as oiio

    path = Path(path)
    image_input = oiio.ImageInput.open(str(path))
    if image_input is None:
        raise MitsubaBackendError(f"cannot read environment image {path}")
    try:
        spec = image_input.spec()
        raw = np.asarray(image_input.read_image(0, 0, 0, spec.nchannels, "float"), dtype=np.float64)
        integer = spec.format.basetype not in (oiio.FLOAT, oiio.HALF, oiio.DOUBLE)
    finally:
        image_input.close()
    if raw.ndim == 2:
        raw = raw[..., None]
    raw = np.repeat(raw[..., :1], 3, axis=-1) if raw.shape[-1] < 3 else raw[..., :3]
    if integer and path.suffix.lower() in (".png", ".jpg", ".jpeg", ".bmp", ".tga"):
        raw = np.where(raw <= 0.04045, raw / 12.92, ((raw + 0.055) / 1.055) ** 2.4)
    return raw


def environment_lookup(image: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """strauss-fit's bilinear latitude–longitude lookup (rows: polar angle from +y; columns:
    azimuth, the centre column toward −z, increasing toward +x)."""
    height, width = image.shape[:2]
    d = direction / np.linalg.norm(direction, axis=-1, keepdims=True)
    ok = (d[..., 0] != 0) | (d[..., 2] != 0)
    azimuth = np.arctan2(np.where(ok, d[..., 0], 0.0), np.where(ok, -d[..., 2], 1.0))
    u = (azimuth / (2 * np.pi) + 0.5) * width - 0.5
    v = np.clip(np.arccos(np.clip(d[..., 1], -1, 1)) / np.pi * height - 0.5, 0.0, height - 1.0)
    u0 = np.floor(u)
    v0 = np.clip(np.floor(v), 0, max(height - 2, 0))
    fu, fv = (u - u0)[..., None], (v - v0)[..., None]
    iu0 = u0.astype(int) % width
    iu1 = (iu0 + 1) % width
    iv0 = v0.astype(int)
    iv1 = np.minimum(iv0 + 1, height - 1)
    top = image[iv0, iu0] * (1 - fu) + image[iv0, iu1] * fu
    bottom = image[iv1, iu0] * (1 - fu) + image[iv1, iu1] * fu
    return top * (1 - fv) + bottom * fv


def background_radiance(
    background: Mapping[str, Any], origin: np.ndarray, direction: np.ndarray, environment: np.ndarray | None = None
) -> np.ndarray:
    """strauss-fit's background radiance along rays (…, 3), in numpy."""
    kind = background["kind"]
    if kind == "color":
        return np.broadcast_to(np.asarray(background["color"], dtype=float), direction.shape).copy()
    if kind == "checkerboard":
        return _checkerboard_radiance(background, origin, direction)
    if environment is None:
        environment = read_environment(background["image"]) * background.get("scale", 1.0)
    return environment_lookup(environment, direction)


def coverage_and_background(
    translation: Translation, sub: int = 8, environment: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Sphere coverage (H, W) and the directly seen background's share of each pixel
    (H, W, 3): ∫ over the pixel of background radiance where the sphere is missed, divided by
    the pixel area. Colour backgrounds are exact ((1 − coverage)·colour); the others average
    the background over the missed points of a ``sub`` × ``sub`` sub-pixel grid."""
    camera, background = translation.camera, translation.background
    coverage = sphere_coverage(camera)
    if background["kind"] == "color":
        return coverage, (1 - coverage)[..., None] * np.asarray(background["color"], dtype=float)
    origin, direction = _subpixel_rays(camera, sub)
    miss = ~_hits_sphere(origin, direction)
    radiance = background_radiance(background, origin, direction, environment)
    count = miss.sum(axis=-1)
    mean_missed = (radiance * miss[..., None]).sum(axis=-2) / np.maximum(count, 1)[..., None]
    if np.any((count == 0) & (coverage < 1)):  # a sliver the grid missed: take the pixel centre
        centre_o, centre_d = _subpixel_rays(camera, 1)
        centre = background_radiance(background, centre_o, centre_d, environment)[..., 0, :]
        mean_missed = np.where(((count == 0) & (coverage < 1))[..., None], centre, mean_missed)
    return coverage, (1 - coverage)[..., None] * mean_missed


# --- Mitsuba scene ---------------------------------------------------------------------------


def _version(mi) -> tuple[int, ...]:
    return tuple(int(x) for x in mi.__version__.split(".")[:3] if x.isdigit())


def _mitsuba(variant: str | None):
    """Import Mitsuba and set ``variant`` (default: ``scalar_rgb``)."""
    try:
        import mitsuba as mi
    except ImportError:
        raise MitsubaUnavailableError(
            "Mitsuba 3 is not installed; install it with pip install -e '.[mitsuba]'"
        ) from None
    if _version(mi) < MIN_VERSION:
        raise MitsubaUnavailableError(
            f"Mitsuba {mi.__version__} is too old; the backend needs >= {'.'.join(map(str, MIN_VERSION))}"
        )
    variant = variant or "scalar_rgb"
    if variant not in VARIANTS:
        raise MitsubaBackendError(f"unknown Mitsuba variant {variant!r}; expected one of {', '.join(VARIANTS)}")
    if mi.variant() != variant:
        try:
            mi.set_variant(variant)
        except Exception as exc:  # missing libLLVM, unknown variant in this build
            message = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise MitsubaUnavailableError(
                f"cannot use Mitsuba variant {variant!r}: {message}"
                + (" (llvm_ad_rgb needs libLLVM, e.g. apt-get install libllvm19)" if variant.startswith("llvm") else "")
            ) from None
    return mi


def environment_for_mitsuba(image: np.ndarray, ambient: float = 0.0, refine: tuple[int, int] = (3, 2)) -> np.ndarray:
    """Resample a strauss-fit latitude–longitude image so that Mitsuba 3.9's ``envmap``
    lookup reproduces strauss-fit's bilinear lookup (see `environment_lookup`).

    Mitsuba (3.9) puts column c's centre at azimuth 2π(c + ½)/W′ (measured from −z toward
    +x, like strauss-fit, but without its half-turn offset) and row r at polar angle
    π·r/(H′ − 1) (rows at the poles). With W′ = m·W (m odd) and H′ = 2·H·k + 1 the new texel
    centres include every original one, so bilinear interpolation on the finer grid equals
    the original interpolant exactly (for even W; otherwise to within the refinement).
    ``ambient`` is added (one environment emitter per Mitsuba scene).
    """
    m, k = refine
    height, width = image.shape[:2]
    w2, h2 = m * width, 2 * height * k + 1
    azimuth = 2 * np.pi * (np.arange(w2) + 0.5) / w2
    polar = np.pi * np.arange(h2) / (h2 - 1)
    # strauss-fit is constant in the polar angle within half a row of each pole (it clamps),
    # but not in azimuth: evaluate the pole rows just inside that cap, not at the pole itself
    # (whose azimuth is undefined)
    cap = 0.25 * np.pi / height
    polar = np.clip(polar, cap, np.pi - cap)
    phi, theta = np.meshgrid(azimuth, polar)
    direction = np.stack([np.sin(phi) * np.sin(theta), np.cos(theta), -np.cos(phi) * np.sin(theta)], axis=-1)
    return environment_lookup(image, direction) + ambient


def checker_tile(colors: list[list[float]], sharpness: float, texels: int = BOARD_TILE_TEXELS) -> np.ndarray:
    """One period (2 × 2 squares) of strauss-fit's softened checkerboard, (texels, texels, 3):
    texel (row r, column c) at square coordinates u = 2(c + ½)/texels, v = 2(r + ½)/texels."""
    t = 2 * (np.arange(texels) + 0.5) / texels
    w = checker_weight(t[None, :], t[:, None], sharpness)
    c0, c1 = (np.asarray(c, dtype=float) for c in colors)
    return (c1 + w[..., None] * (c0 - c1)).astype(np.float32)


def mitsuba_scene_dict(
    translation: Translation,
    bsdf: Mapping[str, Any],
    *,
    spp: int,
    max_depth: int,
    rr_depth: int,
    mi: Any,
    environment: np.ndarray | None = None,
) -> dict[str, Any]:
    """The ``mi.load_dict`` mapping of a translated scene with the sphere's ``bsdf``."""
    T = mi.ScalarTransform4f
    cam = translation.camera
    film = {
        "type": "hdrfilm",
        "width": cam["width"],
        "height": cam["height"],
        "rfilter": {"type": "box"},
        "pixel_format": "rgb",
        "component_format": "float32",
    }
    sampler = {"type": "stratified", "sample_count": spp, "jitter": True}
    if cam["projection"] == "orthographic":
        aspect = cam["width"] / cam["height"]
        # Mitsuba's orthographic film spans camera x ∈ [−1, 1], y ∈ [−1/aspect, 1/aspect], image
        # left at camera +x; look_at(…, up = +y) maps camera +x to world −x, so the image
        # spans world x, y ∈ [−1, 1] with +x right and +y up, like strauss-fit.
        sensor = {
            "type": "orthographic",
            "near_clip": 1e-3,
            "far_clip": 1e5,
            "to_world": T().look_at(origin=[0, 0, ORTHOGRAPHIC_ORIGIN_Z], target=[0, 0, 0], up=[0, 1, 0])
            @ T().scale([1.0, aspect, 1.0]),
        }
    else:
        sensor = {
            "type": "perspective",
            "fov": cam["fov_deg"],
            "fov_axis": "y",
            "near_clip": 1e-3,
            "far_clip": 1e5,
            "to_world": T().look_at(origin=cam["position"], target=cam["look_at"], up=cam["up"]),
        }
    sensor.update(film=film, sampler=sampler)
    scene: dict[str, Any] = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": max_depth, "rr_depth": rr_depth, "hide_emitters": True},
        "sensor": sensor,
        "sphere": {"type": "sphere", "center": [0.0, 0.0, 0.0], "radius": 1.0, "bsdf": bsdf_to_mitsuba(bsdf)},
    }
    for i, e in enumerate(translation.emitters):
        if e["type"] == "directional":
            scene[f"light{i}"] = {
                "type": "directional",
                "direction": e["direction"],
                "irradiance": _rgb(e["irradiance"]),
            }
        else:
            scene[f"light{i}"] = {"type": "point", "position": e["position"], "intensity": _rgb(e["intensity"])}
    bg = translation.background
    if bg["kind"] == "environment":
        image = environment if environment is not None else read_environment(bg["image"]) * bg["scale"]
        resampled = environment_for_mitsuba(image, translation.ambient)
        scene["environment"] = {"type": "envmap", "bitmap": mi.Bitmap(resampled.astype(np.float32))}
    elif translation.ambient > 0:
        scene["environment"] = {"type": "constant", "radiance": _rgb([translation.ambient] * 3)}
    if bg["kind"] == "checkerboard":
        normal = np.asarray(bg["normal"], dtype=float)
        point = np.asarray(bg["point"], dtype=float)
        u_axis, v_axis = _plane_axes(normal)
        # the rectangle's normal (local +z = e1 × e2) must face the sphere: area lights emit
        # on their front side only; w is symmetric in (u, v), so swapping the axes is free
        e1, e2 = (u_axis, v_axis) if float(np.dot(-point, normal)) >= 0 else (v_axis, u_axis)
        e3 = np.cross(e1, e2)
        L = BOARD_HALF_SIZE
        matrix = np.eye(4)
        matrix[:3, 0], matrix[:3, 1], matrix[:3, 2], matrix[:3, 3] = L * e1, L * e2, e3, point
        size = bg["square_size"]
        # rectangle uv s ∈ [0, 1] ↔ offset L(2s − 1) along e1 ↔ L(2s − 1)/size squares ↔ half that in tiles
        scale, shift = L / size, -L / (2 * size)
        to_uv = mi.ScalarTransform3f().translate([shift, shift]) @ mi.ScalarTransform3f().scale([scale, scale])
        tile = checker_tile(bg["colors"], bg["sharpness"])
        scene["board"] = {
            "type": "rectangle",
            "to_world": T(mi.ScalarMatrix4f(matrix.tolist())),
            "bsdf": {"type": "diffuse", "reflectance": _rgb([0.0, 0.0, 0.0])},
            "emitter": {
                "type": "area",
                "radiance": {
                    "type": "bitmap",
                    "bitmap": mi.Bitmap(tile),
                    "raw": True,
                    "filter_type": "bilinear",
                    "wrap_mode": "repeat",
                    "to_uv": to_uv,
                },
            },
        }
    return scene


def split_emitters(scene: dict[str, Any]) -> list[dict[str, Any]]:
    """One scene per emitter (lights, environment, checkerboard), the others removed (the
    board stays as black, non-emitting geometry so that it still occludes).

    Light transport is linear in the emitters, so the sum of the passes is an unbiased
    estimate of the full image; it has far less noise than one pass with the same spp,
    because a pass with a single delta light has no emitter-selection noise and no noise
    from next-event estimation at all (a Lambertian sphere under a directional light is
    then exact up to the pixel-area integration).
    """
    keys = [k for k in scene if k.startswith("light") or k == "environment"]
    board = scene.get("board")
    if board is not None:
        keys.append("board")
    passes = []
    for key in keys:
        one = {k: v for k, v in scene.items() if not (k.startswith("light") or k == "environment" or k == "board")}
        if key == "board":
            one["board"] = board
        else:
            one[key] = scene[key]
            if board is not None:
                one["board"] = {k: v for k, v in board.items() if k != "emitter"}
        passes.append(one)
    return passes or [scene]


@dataclass
class MitsubaRender:
    """What `render_mitsuba_full` returns: the composited ``image`` (H, W, 3) float32,
    the sphere ``coverage`` (H, W) in [0, 1], the ``sphere_part`` (Mitsuba's render: the
    sphere's radiance times coverage), the ``background_part``, the Mitsuba ``variant`` and
    ``version``, the ``translation`` and the render ``seconds``."""

    image: np.ndarray
    coverage: np.ndarray
    sphere_part: np.ndarray
    background_part: np.ndarray
    variant: str
    version: str
    translation: Translation
    seconds: float


def render_mitsuba_full(
    definition: Mapping[str, Any],
    bsdf: Mapping[str, Any],
    *,
    spp: int,
    seed: int,
    variant: str | None = None,
    base_dir: str | Path = ".",
    max_depth: int = DEFAULT_MAX_DEPTH,
    rr_depth: int = DEFAULT_RR_DEPTH,
    split: bool = True,
) -> MitsubaRender:
    """Render the canonical sphere of ``definition`` with ``bsdf`` in Mitsuba 3 (see
    `render_mitsuba`), keeping every part of the result. ``split`` renders one pass
    per emitter and sums them (see `split_emitters`)."""
    if isinstance(spp, bool) or not isinstance(spp, int) or not 1 <= spp <= 1 << 20:
        raise MitsubaBackendError(f"spp must be an integer in [1, 1048576], got {spp!r}")
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**32:
        raise MitsubaBackendError(f"seed must be an integer in [0, 2^32), got {seed!r}")
    bsdf = validate_bsdf(bsdf)
    translation = translate_scene(definition, base_dir)
    mi = _mitsuba(variant)
    if translation.background["kind"] == "checkerboard" and _version(mi) < MIN_VERSION_BOARD:
        raise MitsubaUnavailableError(
            f"a checkerboard background needs Mitsuba >= 3.8 (found {mi.__version__}): "
            "older path tracers do not hide area emitters from the camera"
        )
    environment = None
    if translation.background["kind"] == "environment":
        environment = read_environment(translation.background["image"]) * translation.background["scale"]
    full = mitsuba_scene_dict(
        translation, bsdf, spp=spp, max_depth=max_depth, rr_depth=rr_depth, mi=mi, environment=environment
    )
    start = time.perf_counter()
    sphere_part = np.zeros((translation.camera["height"], translation.camera["width"], 3))
    for scene_dict in split_emitters(full) if split else [full]:
        scene = mi.load_dict(scene_dict)
        sphere_part += np.array(mi.render(scene, seed=seed, spp=spp), dtype=np.float64)[..., :3]
    seconds = time.perf_counter() - start
    coverage, background_part = coverage_and_background(translation, environment=environment)
    image = (sphere_part + background_part).astype(np.float32)
    return MitsubaRender(
        image, coverage, sphere_part, background_part, mi.variant(), mi.__version__, translation, seconds
    )


def render_mitsuba(
    definition: Mapping[str, Any],
    bsdf: Mapping[str, Any],
    *,
    spp: int,
    seed: int,
    variant: str | None = None,
    base_dir: str | Path = ".",
) -> tuple[np.ndarray, np.ndarray]:
    """Render the unit sphere of a strauss-fit scene ``definition`` with a Mitsuba ``bsdf``.

    Returns the linear RGB radiance (H, W, 3) float32 — box-filtered pixels: a silhouette
    pixel is the area average of sphere and background — and the sphere coverage (H, W),
    the fraction of each pixel's area that sees the sphere (1 inside, 0 outside). ``spp``
    samples per pixel, ``seed`` Mitsuba's sampler seed (same seed, variant and version: same
    image), ``variant`` one of `VARIANTS` (default ``scalar_rgb``), ``base_dir``
    resolves a relative environment image path.
    """
    result = render_mitsuba_full(definition, bsdf, spp=spp, seed=seed, variant=variant, base_dir=base_dir)
    return result.image, result.coverage


def measure_noise(first: np.ndarray, second: np.ndarray, coverage: np.ndarray) -> dict[str, Any]:
    """Monte Carlo noise from two renders with different seeds, on fully covered pixels:
    per channel, the standard deviation of one render (std(a − b)/√2) and of their mean
    (std(a − b)/2), absolute and relative to the mean radiance."""
    full = coverage >= 1.0
    diff = (np.asarray(first, dtype=np.float64) - np.asarray(second, dtype=np.float64))[full]
    mean = 0.5 * (np.asarray(first, dtype=np.float64) + np.asarray(second, dtype=np.float64))[full]
    single = diff.std(axis=0) / math.sqrt(2)
    level = np.maximum(mean.mean(axis=0), 1e-12)
    return {
        "per_render": [float(x) for x in single],
        "of_mean": [float(x) for x in single / math.sqrt(2)],
        "relative_per_render": [float(x) for x in single / level],
        "pixels": int(full.sum()),
    }
