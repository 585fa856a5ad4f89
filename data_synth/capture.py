r"""Synthetic captures with known truth: many photographs of one sphere, a manifest, the answer.

A *capture* (docs/captures.md) is a set of photographs of one sample sphere under known
lights, taken by a camera that does not move, with the sphere anywhere in a larger frame.
`write_capture` renders one from a `CaptureSpec` into a folder:

- ``001.png``, ``002.png``, … (``.jpg`` for ``srgb8-jpeg``): the stored images;
- ``mask.png``: 8-bit grey, 255 on the pixels whose *centre* ray hits the sphere (exact,
  from the geometry, not from thresholding the images);
- ``capture.toml``: the manifest in the format of docs/captures.md — the encoding, the black
  level, the mask, the camera, and each image's file and lights. It states neither the
  circle (the library must find the sphere) nor the exposures (a real user does not know
  them);
- ``truth.json``: everything the manifest leaves out (see `render_capture_images`).

Conventions (those of docs/captures.md). Pixel (row i, column k) covers [k, k+1) × [i, i+1)
in pixel units; the camera frame has +x to the image's right, +y **up** and +z toward the
camera. A light's ``direction`` points from the sphere toward the light; a ``position`` is
a point light in sphere radii from the sphere's centre, in the camera frame's axes.

Geometry. Each pixel is sampled at S × S sub-pixel positions
`x = k + (a + \tfrac12)/S`, `y = i + (b + \tfrac12)/S` (S = ``supersample``);
a ray is cast through each and intersected with the sphere here, independently of the
library's own sphere geometry (so that tests of that geometry are a real check):

- orthographic: the ray is the line through `(x, -y, z_c)` along `w = (0, 0, -1)`,
  the sphere has centre `(c_x, -c_y, z_c)` and radius r, all in pixel units;
  `V = (0, 0, 1)`;
- perspective: a pinhole at the origin, focal length f and principal point `(p_x, p_y)`;
  the ray through (x, y) has direction `w = \mathrm{normalise}((x - p_x)/f, -(y - p_y)/f, -1)`
  and `V = -w`; the sphere has radius R = 1 and centre `C = u / \sin\rho`, the
  cone of half-angle ρ around the unit direction u.

The first intersection `P = o + t w`, `t = w\cdot(C - o) - \sqrt{(w\cdot(C - o))^2 - |C - o|^2 + R^2}`,
gives the normal `n = (P - C)/R`; a sample whose discriminant is not positive sees
the background. For a perspective spec, u and ρ are chosen so that the silhouette — an
ellipse elongated along the radial direction from the principal point — has its centre at
``center_px`` and the area of a circle of radius ``radius_px`` (`perspective_silhouette`).

Shading, per sample (float64, inside `strauss_fit.float64`; ``shade`` compiled with
``jax.jit``, which agrees with its eager evaluation to about 1e-16). A light of per-channel
intensity `I` contributes `I_c \cdot \mathrm{shade}_c(N, L, V; C_L = \text{white})`
with the library's Strauss model (`strauss_fit.models.strauss.shade`): a per-channel
intensity scales the radiance of a white light of unit intensity, channel by channel (the
DiLiGenT convention; for a grey light it is the library's scalar intensity exactly). A
directional light has the same L everywhere; a point light at `p` (sphere radii) has
`L = \mathrm{normalise}(p - P)` and its intensity scaled by `(|p| / |p - P|)^2`,
so that ``intensity`` is the irradiance at the sphere's centre. The room's ambient light
adds `A_c\, r_d\, C_c` (Strauss's ambient term, `r_d = 1 - s^3` for an opaque
material). Background samples take ``background``.

A mirror ball (``chrome=True``) replaces the material: the radiance of a sample is
`\rho_c \sum_\ell [R\cdot L_\ell \ge \cos\delta_\ell]\, I_{\ell,c}/\Omega` with
`R = 2(N\cdot V)N - V`, ρ the ``mirror_reflectance`` and each light a uniform disc of
angular radius δ = ``light_radius_deg`` and solid angle `\Omega = 2\pi(1 - \cos\delta)`,
so that its radiance integrated over the disc is its intensity (the irradiance it gives a
surface facing it is `I\,(1 + \cos\delta)/2 \approx I`). Where R meets no light the
mirror shows ``background`` (times ρ). A point light is a spherical lamp seen from the
sphere's centre at angular radius δ: from the surface point P its direction is
`\mathrm{normalise}(p - P)` and its angular radius `\arcsin(\sin\delta\,|p|/|p - P|)`,
with the same radiance. Ambient light adds nothing to a mirror (its `r_d` is 0).

Sensor, per image and pixel (channel c): the sub-samples are averaged (an anti-aliased
silhouette and highlight), then

```text
v = e\,\bar L + s_c, \qquad
o = \mathrm{clip}\big(v + \sqrt{\sigma^2 + k \max(v, 0)}\;\varepsilon + b,\ 0,\ 1\big),
\quad \varepsilon \sim \mathcal N(0, 1),
```

with e the image's exposure, `s` the ``stray`` light (veiling glare: added to every
pixel, not scaled by the exposure), σ = ``noise_sd``, k = ``shot_slope`` and b the
``black_level``. o is the stored value as a fraction of full scale; ``linear16`` stores the
code round(65535·o) in a 16-bit PNG, ``srgb8`` the code round(255·sRGB(o)) in an 8-bit
PNG, ``srgb8-jpeg`` the same codes in a JPEG of quality 95 (lossy: the decoded codes differ
from them by a few units). The noise of image j comes from
``np.random.default_rng(seed).spawn(n)[j]`` (one standard normal per value, in C order), so
a seed fixes every byte.

``python -m data_synth.capture KIND OUTDIR [--force] [--seed N]`` writes one of the ready-made
specs of `example_capture_spec`.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from strauss_fit.color import srgb_encode
from strauss_fit.errors import ImageError, StraussFitError
from strauss_fit.io.files import Outputs, check_writable

from .files import encoded_bytes, mask_bytes
from .params import SpecError

#: The manifest's name (what the library's reader looks for in a folder).
MANIFEST_NAME = "capture.toml"
#: The truth file's name.
TRUTH_NAME = "truth.json"
#: The mask's name.
MASK_NAME = "mask.png"
#: The truth file's ``format``.
TRUTH_FORMAT = "strauss-fit synthetic capture"
CAMERAS = ("orthographic", "perspective")
#: Encodings: 16-bit linear PNG, 8-bit sRGB PNG, 8-bit sRGB JPEG (quality `JPEG_QUALITY`).
ENCODINGS = ("linear16", "srgb8", "srgb8-jpeg")
JPEG_QUALITY = 95
#: The ready-made specs of `example_capture_spec`.
EXAMPLES = ("plastic", "perspective", "srgb8", "chrome")
#: How a light's per-channel intensity enters (recorded in the truth).
LIGHT_MODEL = (
    "each light adds I_c * shade_c(N, L, V; light colour white), I its per-channel intensity "
    "(for a point light times (|p|/|p - P|)^2: the intensity is the irradiance at the sphere's centre)"
)
#: Sub-pixel samples processed at once (bounds the memory of the ray casting).
_BLOCK_SAMPLES = 1 << 20


@dataclass(frozen=True)
class CaptureSpec:
    """What to render: the material, every image's lights, the camera, the sphere's place in
    the frame and the sensor. Values are checked on construction (`SpecError`, one
    line naming the field).

    - ``material``: ``{"color": [r, g, b], "smoothness": s, "metalness": m}`` (opaque:
      ``transparency`` may be given only as 0; ``ior`` is allowed and unused); ignored, and
      may be empty, when ``chrome`` is true.
    - ``lights``: per image, a non-empty list of lights, each ``{"direction": [x, y, z]}``
      (toward the light; normalised) or ``{"position": [x, y, z]}`` (a point light, sphere
      radii from the centre, more than 1 away), with ``"intensity"``: one number or
      ``[r, g, b]`` (default 1).
    - ``frame`` (width, height) in pixels; ``camera`` ``"orthographic"`` or ``"perspective"``.
    - ``center_px``, ``radius_px``: orthographic, the sphere's circle in pixel units;
      perspective, the centre and equal-area radius of its elliptic silhouette.
    - ``focal_px``, ``principal_point`` (default the image centre (W/2, H/2)): perspective only.
    - ``exposure``: per image (default 1 each); scales everything but ``stray``.
    - ``ambient``: the room's light on the sphere, per channel (Strauss's I_a · r_d · C).
    - ``stray``: added to every pixel of the frame after the exposure (veiling glare).
    - ``background``: the radiance of the distant, constant background around the sphere.
    - ``black_level``, ``noise_sd``, ``shot_slope``: the sensor (fractions of full scale; the
      noise variance is noise_sd² + shot_slope · value).
    - ``encoding``: one of `ENCODINGS`.
    - ``chrome``: a mirror ball of reflectance ``mirror_reflectance`` instead of the
      material, each light a disc of angular radius ``light_radius_deg`` (module docstring).
    - ``supersample``: sub-pixels per axis; ``seed``: the noise; ``write_mask``: whether
      `write_capture` writes ``mask.png`` and names it in the manifest.
    """

    material: dict
    lights: list
    frame: tuple[int, int] = (320, 240)
    camera: str = "orthographic"
    center_px: tuple[float, float] = (171.3, 118.6)
    radius_px: float = 62.4
    focal_px: float = 600.0
    principal_point: tuple[float, float] | None = None
    exposure: list[float] | None = None
    ambient: tuple = (0.0, 0.0, 0.0)
    stray: tuple = (0.0, 0.0, 0.0)
    background: tuple = (0.0, 0.0, 0.0)
    black_level: float = 0.0
    noise_sd: float = 0.0
    shot_slope: float = 0.0
    encoding: str = "linear16"
    chrome: bool = False
    mirror_reflectance: tuple = (1.0, 1.0, 1.0)
    light_radius_deg: float = 1.0
    supersample: int = 4
    seed: int = 0
    write_mask: bool = True

    def __post_init__(self) -> None:
        _checked(self)

    @property
    def width(self) -> int:
        return int(self.frame[0])

    @property
    def height(self) -> int:
        return int(self.frame[1])

    @property
    def image_count(self) -> int:
        return len(self.lights)

    @property
    def extension(self) -> str:
        """The images' file extension."""
        return ".jpg" if self.encoding == "srgb8-jpeg" else ".png"

    def file_names(self) -> list[str]:
        """``001.png``, ``002.png``, … (as many as images)."""
        return [f"{k:03d}{self.extension}" for k in range(1, self.image_count + 1)]

    def exposures(self) -> list[float]:
        """Every image's exposure (1 where none is given)."""
        return [1.0] * self.image_count if self.exposure is None else [float(e) for e in self.exposure]

    def principal(self) -> tuple[float, float]:
        """The principal point, (W/2, H/2) unless given."""
        if self.principal_point is None:
            return (self.width / 2.0, self.height / 2.0)
        return (float(self.principal_point[0]), float(self.principal_point[1]))


# --- checking ---------------------------------------------------------------------------


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)


def _finite(value: Any, where: str, *, low: float | None = None, positive: bool = False) -> float:
    if not _is_number(value) or not math.isfinite(float(value)):
        raise SpecError(f"capture {where} must be a finite number, got {value!r}")
    value = float(value)
    if positive and value <= 0:
        raise SpecError(f"capture {where} = {value:g} must be > 0")
    if low is not None and value < low:
        raise SpecError(f"capture {where} = {value:g} must be >= {low:g}")
    return value


def _triple(value: Any, where: str, *, low: float | None = None, allow_scalar: bool = False) -> list[float]:
    if allow_scalar and _is_number(value):
        value = [value] * 3
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise SpecError(f"capture {where} must be {'a number or ' if allow_scalar else ''}3 numbers, got {value!r}")
    return [_finite(v, where, low=low) for v in value]


def _normalised_lights(spec: CaptureSpec) -> list[list[dict[str, Any]]]:
    """Every image's lights as ``{"direction": unit} | {"position": p}`` plus an RGB
    ``"intensity"`` (the form written to the manifest and the truth)."""
    if not isinstance(spec.lights, (list, tuple)) or not spec.lights:
        raise SpecError("capture lights must be a non-empty list (one list of lights per image)")
    images = []
    for i, lights in enumerate(spec.lights, 1):
        if not isinstance(lights, (list, tuple)) or not lights:
            raise SpecError(f"capture image {i}: its lights must be a non-empty list of tables")
        out = []
        for k, light in enumerate(lights, 1):
            where = f"image {i}, light {k}"
            if not isinstance(light, dict):
                raise SpecError(f"capture {where} must be a table, got {light!r}")
            unknown = sorted(set(light) - {"direction", "position", "intensity"})
            if unknown:
                raise SpecError(
                    f"capture {where}: unknown key {unknown[0]!r} (expected direction, position, intensity)"
                )
            if ("direction" in light) == ("position" in light):
                raise SpecError(f"capture {where} needs exactly one of direction and position")
            intensity = _triple(light.get("intensity", 1.0), f"{where} intensity", low=0.0, allow_scalar=True)
            if "direction" in light:
                vector = np.asarray(_triple(light["direction"], f"{where} direction"))
                norm = float(np.linalg.norm(vector))
                if not norm > 1e-12:
                    raise SpecError(f"capture {where} direction must not be the zero vector")
                out.append({"direction": (vector / norm).tolist(), "intensity": intensity})
            else:
                position = _triple(light["position"], f"{where} position")
                if not math.hypot(*position) > 1.0:
                    raise SpecError(f"capture {where} position must lie outside the sphere (more than 1 radius away)")
                out.append({"position": position, "intensity": intensity})
        images.append(out)
    return images


def _material_values(spec: CaptureSpec) -> dict[str, Any] | None:
    """The material as `Material` keyword arguments,
    checked (None for a mirror ball)."""
    if spec.chrome:
        return None
    from strauss_fit.models.material import OPAQUE_NAMES, PARAMETER_NAMES, check_values

    material = spec.material
    if not isinstance(material, dict):
        raise SpecError(f"capture material must be a table, got {material!r}")
    unknown = sorted(set(material) - set(PARAMETER_NAMES))
    if unknown:
        raise SpecError(f"capture material: unknown key {unknown[0]!r} (expected {', '.join(OPAQUE_NAMES)})")
    missing = [key for key in OPAQUE_NAMES if key not in material]
    if missing:
        raise SpecError(f"capture material needs {', '.join(missing)}")
    if material.get("transparency", 0.0) != 0:
        raise SpecError("capture material must be opaque (transparency 0): a capture's sphere is a solid sample")
    values = {
        "color": _triple(material["color"], "material color"),
        "smoothness": _finite(material["smoothness"], "material smoothness"),
        "metalness": _finite(material["metalness"], "material metalness"),
        "transparency": 0.0,
        "ior": _finite(material.get("ior", 1.5), "material ior"),
    }
    try:
        check_values(**values)
    except StraussFitError as exc:
        raise SpecError(f"capture {exc}") from None
    return values


def _checked(spec: CaptureSpec) -> None:
    """Every check of a spec (run on construction)."""
    frame = spec.frame
    if (
        not isinstance(frame, (list, tuple))
        or len(frame) != 2
        or not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= 1 for v in frame)
    ):
        raise SpecError(f"capture frame must be (width, height), two positive integers, got {frame!r}")
    if spec.camera not in CAMERAS:
        raise SpecError(f"capture camera must be one of {', '.join(CAMERAS)}, got {spec.camera!r}")
    if spec.encoding not in ENCODINGS:
        raise SpecError(f"capture encoding must be one of {', '.join(ENCODINGS)}, got {spec.encoding!r}")
    if not isinstance(spec.center_px, (list, tuple)) or len(spec.center_px) != 2:
        raise SpecError(f"capture center_px must be (cx, cy), got {spec.center_px!r}")
    for value in spec.center_px:
        _finite(value, "center_px")
    _finite(spec.radius_px, "radius_px", positive=True)
    _finite(spec.focal_px, "focal_px", positive=True)
    if spec.principal_point is not None:
        if not isinstance(spec.principal_point, (list, tuple)) or len(spec.principal_point) != 2:
            raise SpecError(f"capture principal_point must be (px, py), got {spec.principal_point!r}")
        for value in spec.principal_point:
            _finite(value, "principal_point")
    lights = _normalised_lights(spec)
    if spec.exposure is not None:
        if not isinstance(spec.exposure, (list, tuple)) or len(spec.exposure) != len(lights):
            raise SpecError(f"capture exposure must list one value per image ({len(lights)}), got {spec.exposure!r}")
        for value in spec.exposure:
            _finite(value, "exposure", positive=True)
    _triple(spec.ambient, "ambient", low=0.0, allow_scalar=True)
    _triple(spec.stray, "stray", low=0.0, allow_scalar=True)
    _triple(spec.background, "background", low=0.0, allow_scalar=True)
    _triple(spec.mirror_reflectance, "mirror_reflectance", low=0.0, allow_scalar=True)
    black = _finite(spec.black_level, "black_level", low=0.0)
    if black >= 1:
        raise SpecError(f"capture black_level = {black:g} must be below 1 (full scale)")
    _finite(spec.noise_sd, "noise_sd", low=0.0)
    _finite(spec.shot_slope, "shot_slope", low=0.0)
    radius = _finite(spec.light_radius_deg, "light_radius_deg", positive=True)
    if radius >= 90:
        raise SpecError(f"capture light_radius_deg = {radius:g} must be below 90")
    if not isinstance(spec.supersample, (int, np.integer)) or isinstance(spec.supersample, bool):
        raise SpecError(f"capture supersample must be a positive integer, got {spec.supersample!r}")
    if not 1 <= spec.supersample <= 64:
        raise SpecError(f"capture supersample = {spec.supersample} must be in [1, 64]")
    if not isinstance(spec.seed, (int, np.integer)) or isinstance(spec.seed, bool) or spec.seed < 0:
        raise SpecError(f"capture seed must be a non-negative integer, got {spec.seed!r}")
    _material_values(spec)
    if spec.camera == "perspective":
        perspective_silhouette(spec)  # refuses a sphere the pinhole cannot see whole


# --- geometry ---------------------------------------------------------------------------


def _ellipse(theta: float, rho: float, focal: float) -> tuple[float, float, float]:
    r"""The silhouette of a cone of half-angle ρ whose axis is θ off the optical axis, on the
    image plane at distance f: (c, a, b) = the centre's distance from the principal point,
    the radial and the tangential semi-axes, in pixels.

    The radial extremes are the rays at θ ∓ ρ, at `f\tan(\theta \mp \rho)`, so
    `c = f(\tan(\theta + \rho) + \tan(\theta - \rho))/2` and
    `a = f(\tan(\theta + \rho) - \tan(\theta - \rho))/2 = f\sin\rho\cos\rho/(\cos^2\theta - \sin^2\rho)`;
    the tangential semi-axis is `b = f\sin\rho/\sqrt{\cos^2\theta - \sin^2\rho}`
    (a ≥ b: the ellipse is elongated radially)."""
    upper, lower = math.tan(theta + rho), math.tan(theta - rho)
    b = focal * math.sin(rho) / math.sqrt(math.cos(theta) ** 2 - math.sin(rho) ** 2)
    return focal * (upper + lower) / 2.0, focal * (upper - lower) / 2.0, b


def perspective_silhouette(spec: CaptureSpec) -> dict[str, Any]:
    r"""Where a perspective spec puts the sphere: the cone (``direction`` u, unit, camera
    frame; ``angular_radius_deg`` ρ) whose elliptic silhouette has its centre at
    ``center_px`` and the area of the circle of radius ``radius_px``; also that ellipse
    (``center``, ``semi_axes`` [radial a, tangential b], ``major_axis``: the unit radial
    direction in pixel axes, x right and y down), the equal-area circle (``center``,
    ``radius`` = √(ab)), the sphere's centre for R = 1 (``sphere_center`` = u / sin ρ) and
    the off-axis angle θ (``off_axis_deg``).

    u and ρ are found by a fixed-point iteration from θ = atan(c*/f), ρ = atan(r*/f):
    θ moves by atan(c*/f) − atan(c/f) and ρ is scaled by r*/√(ab), until both change by less
    than 1e-15 (a few dozen steps for any sphere the camera sees whole)."""
    focal = float(spec.focal_px)
    px, py = spec.principal()
    dx, dy_up = float(spec.center_px[0]) - px, -(float(spec.center_px[1]) - py)
    target_c, target_r = math.hypot(dx, dy_up), float(spec.radius_px)
    phi = math.atan2(dy_up, dx)
    theta, rho = math.atan2(target_c, focal), math.atan2(target_r, focal)
    for _ in range(500):
        if not theta + rho < math.pi / 2 - 1e-6:
            raise SpecError(
                f"capture: a sphere centred at {list(spec.center_px)} with radius {target_r:g} px is not "
                f"seen whole by a pinhole of focal length {focal:g} px (it reaches 90° off the axis)"
            )
        c, a, b = _ellipse(theta, rho, focal)
        step_theta = math.atan2(target_c, focal) - math.atan2(c, focal)
        scale = target_r / math.sqrt(a * b)
        theta, rho = theta + step_theta, rho * scale
        if abs(step_theta) < 1e-15 and abs(scale - 1.0) < 1e-15:
            break
    if not theta + rho < math.pi / 2 - 1e-6:
        raise SpecError(f"capture: the sphere is not seen whole by a pinhole of focal length {focal:g} px")
    c, a, b = _ellipse(theta, rho, focal)
    u = [math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), -math.cos(theta)]
    center = [px + c * math.cos(phi), py - c * math.sin(phi)]
    return {
        "direction": u,
        "angular_radius_deg": math.degrees(rho),
        "center": center,
        "radius": math.sqrt(a * b),
        "ellipse": {"center": center, "semi_axes": [a, b], "major_axis": [math.cos(phi), -math.sin(phi)]},
        "sphere_center": [v / math.sin(rho) for v in u],
        "off_axis_deg": math.degrees(theta),
    }


@dataclass(frozen=True)
class _Geometry:
    """The sphere as the camera sees it, shared by every image of a capture: one row per
    sub-pixel sample that hits the sphere."""

    pixel: np.ndarray  # (N,) flat pixel index row·W + column of each hit sample
    normal: np.ndarray  # (N, 3) unit normals, camera frame
    view: np.ndarray  # (N, 3) unit vectors toward the camera
    hits: np.ndarray  # (H·W,) hit samples per pixel
    mask: np.ndarray  # (H, W) bool: the pixel's centre ray hits the sphere
    circle: dict[str, Any]  # the true circle or cone (truth)


def _intersect(origin: np.ndarray, direction: np.ndarray, centre: np.ndarray, radius: float):
    """The first intersection of lines ``origin + t·direction`` (unit directions, (..., 3))
    with a sphere: (hit, normal), hit where the discriminant is positive."""
    offset = centre - origin
    along = np.sum(direction * offset, axis=-1)
    disc = along * along - np.sum(offset * offset, axis=-1) + radius * radius
    hit = disc > 0
    t = along - np.sqrt(np.where(hit, disc, 0.0))
    point = origin + t[..., None] * direction
    normal = (point - centre) / radius
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)  # unit to rounding, exactly unit after
    return hit, normal


def _rays(spec: CaptureSpec, x: np.ndarray, y: np.ndarray, perspective: dict[str, Any] | None):
    """Lines through pixel positions (x, y) (pixel units): (origin, direction, centre, radius)."""
    if perspective is None:
        # Orthographic, in pixel units with image y flipped to +y up. The line's point is
        # taken in the sphere centre's plane z = 0, so that the discriminant r² − dx² − dy²
        # carries no cancellation of a large camera distance: the hit test then agrees with
        # the analytic disc (x − cx)² + (y − cy)² < r² to the last bit or so.
        origin = np.stack([x, -y, np.zeros_like(x)], axis=-1)
        direction = np.broadcast_to(np.array([0.0, 0.0, -1.0]), origin.shape)
        centre = np.array([float(spec.center_px[0]), -float(spec.center_px[1]), 0.0])
        return origin, direction, centre, float(spec.radius_px)
    px, py = spec.principal()
    f = float(spec.focal_px)
    direction = np.stack([(x - px) / f, -(y - py) / f, -np.ones_like(x)], axis=-1)
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    centre = np.asarray(perspective["sphere_center"], dtype=np.float64)
    return np.zeros_like(direction), direction, centre, 1.0


def _geometry(spec: CaptureSpec) -> _Geometry:
    """Cast every sub-pixel ray (in blocks of rows, to bound the memory) and keep the hits."""
    width, height, s = spec.width, spec.height, int(spec.supersample)
    perspective = perspective_silhouette(spec) if spec.camera == "perspective" else None
    offsets = (np.arange(s) + 0.5) / s
    sub_x = (np.arange(width)[:, None] + offsets[None, :]).reshape(-1)  # column-major in a pixel
    sub_col = np.repeat(np.arange(width), s)
    rows_per_block = max(1, _BLOCK_SAMPLES // (width * s * s))
    pixels, normals, views = [], [], []
    for start in range(0, height, rows_per_block):
        rows = np.arange(start, min(height, start + rows_per_block))
        sub_y = (rows[:, None] + offsets[None, :]).reshape(-1)
        sub_row = np.repeat(rows, s)
        y, x = np.meshgrid(sub_y, sub_x, indexing="ij")
        origin, direction, centre, radius = _rays(spec, x, y, perspective)
        hit, normal = _intersect(origin, direction, centre, radius)
        index = (sub_row[:, None] * width + sub_col[None, :])[hit]
        pixels.append(index)
        normals.append(normal[hit])
        views.append(-direction[hit])
    pixel = np.concatenate(pixels)
    # the mask: the pixel-centre rays, cast the same way
    cy, cx = np.meshgrid(np.arange(height) + 0.5, np.arange(width) + 0.5, indexing="ij")
    origin, direction, centre, radius = _rays(spec, cx, cy, perspective)
    mask, _ = _intersect(origin, direction, centre, radius)
    if perspective is None:
        circle = {"center": [float(spec.center_px[0]), float(spec.center_px[1])], "radius": float(spec.radius_px)}
    else:
        circle = perspective
    return _Geometry(
        pixel=pixel,
        normal=np.concatenate(normals),
        view=np.concatenate(views),
        hits=np.bincount(pixel, minlength=width * height),
        mask=mask,
        circle=circle,
    )


# --- radiance ---------------------------------------------------------------------------


def _light_at(light: dict[str, Any], point: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(L, distance ratio |p|/|p − P|) of one light at surface points P (sphere radii,
    relative to the centre); the ratio is 1 for a directional light."""
    if "direction" in light:
        direction = np.broadcast_to(np.asarray(light["direction"], dtype=np.float64), point.shape)
        return direction, np.ones(point.shape[:-1])
    position = np.asarray(light["position"], dtype=np.float64)
    offset = position - point
    distance = np.linalg.norm(offset, axis=-1)
    return offset / distance[:, None], np.linalg.norm(position) / distance


@functools.cache
def _compiled_shade():
    """`strauss_fit.models.strauss.shade`, compiled once per array size (the material is
    an argument, so every material shares the compilation): eager evaluation compiles each
    of its few dozen operations anew for every new number of samples, seconds per capture."""
    import jax

    from strauss_fit.models.strauss import shade

    return jax.jit(shade)


def _padded(rows: np.ndarray, size: int) -> np.ndarray:
    """``rows`` (N, 3) followed by copies of (0, 0, 1) up to ``size`` rows (any unit vector
    would do: the padding is shaded and dropped)."""
    padding = np.broadcast_to(np.array([0.0, 0.0, 1.0]), (size - rows.shape[0], 3))
    return np.concatenate([rows, padding])


def _strauss_radiance(geometry: _Geometry, material: dict[str, Any], lights: list[dict[str, Any]], ambient):
    """Per hit sample, Σ_lights I_c · shade_c(N, L, V; white) + A_c r_d C_c (float64)."""
    from strauss_fit.models.material import Material
    from strauss_fit.models.strauss import diffuse_reflectivity
    from strauss_fit.precision import float64

    count = geometry.normal.shape[0]
    # sizes rounded up to a power of two, so that captures of similar size share a compilation
    size = max(1024, 1 << max(0, count - 1).bit_length())
    shade = _compiled_shade()
    with float64():
        model = Material(**material)
        # On the unit sphere the surface point relative to the centre, in radii, is the normal.
        point = geometry.normal
        normal, view = _padded(geometry.normal, size), _padded(geometry.view, size)
        radiance = np.zeros_like(point)
        for light in lights:
            to_light, ratio = _light_at(light, point)
            shaded = np.asarray(shade(model, normal, _padded(to_light, size), view), dtype=np.float64)[:count]
            radiance += shaded * (np.asarray(light["intensity"]) * (ratio * ratio)[:, None])
        r_d = float(np.asarray(diffuse_reflectivity(model)))
    return radiance + np.asarray(ambient) * r_d * np.asarray(material["color"])


def _mirror_radiance(geometry: _Geometry, spec: CaptureSpec, lights: list[dict[str, Any]], background):
    """Per hit sample, what a mirror ball shows: the light discs its reflected ray meets,
    else the background, times the reflectance (module docstring)."""
    normal, view = geometry.normal, geometry.view
    reflected = 2.0 * np.sum(normal * view, axis=-1)[:, None] * normal - view
    delta = math.radians(float(spec.light_radius_deg))
    solid_angle = 2.0 * math.pi * (1.0 - math.cos(delta))
    radiance = np.zeros_like(normal)
    covered = np.zeros(normal.shape[0], dtype=bool)
    for light in lights:
        to_light, ratio = _light_at(light, normal)
        # a lamp of angular radius δ from the centre subtends arcsin(sin δ · |p|/|p − P|) from P
        cos_radius = np.sqrt(1.0 - np.minimum(1.0, (math.sin(delta) * ratio) ** 2))
        inside = np.sum(reflected * to_light, axis=-1) >= cos_radius
        radiance[inside] += np.asarray(light["intensity"]) / solid_angle
        covered |= inside
    radiance[~covered] = background
    return radiance * np.asarray(_triple(spec.mirror_reflectance, "mirror_reflectance", allow_scalar=True))


# --- rendering --------------------------------------------------------------------------


def _codes(stored: np.ndarray, encoding: str) -> np.ndarray:
    """The integer codes a file holds for stored values o in [0, 1]."""
    if encoding == "linear16":
        return np.round(stored * 65535.0).astype(np.uint16)
    return np.round(srgb_encode(stored) * 255.0).astype(np.uint8)


def render_capture_images(spec: CaptureSpec) -> tuple[list[np.ndarray], np.ndarray, dict[str, Any]]:
    """Render a capture: (images, mask, truth).

    ``images``: per image the stored values o (H, W, 3) float64 in [0, 1], before the
    encoding's rounding (module docstring); ``mask``: (H, W) bool, the pixels whose centre
    ray hits the sphere; ``truth``: a JSON-ready dict with the keys

    - ``format``, ``version``;
    - ``files``, ``mask`` (``{"file", "pixels"}``), ``frame`` (``{"width", "height"}``);
    - ``material`` (the Strauss material: color, smoothness, metalness, transparency, ior;
      None for a mirror ball) and ``mirror`` (None, or ``reflectance``, ``light_radius_deg``,
      ``light_solid_angle_sr``);
    - ``lights`` (per image, each light normalised as in the manifest) and ``light_model``;
    - ``exposure`` (per image);
    - ``camera`` (``type``, ``focal_px`` and ``principal_point`` for a perspective camera);
    - ``circle``: orthographic ``{"center", "radius"}`` in pixel units; perspective also
      ``direction``, ``angular_radius_deg``, ``ellipse``, ``sphere_center``, ``off_axis_deg``
      (`perspective_silhouette`), where ``center``/``radius`` are the equal-area circle;
    - ``ambient``, ``stray``, ``background``, ``black_level`` (RGB triples, the last a number);
    - ``noise``: ``{"sd", "shot_slope", "variance"}`` (the variance's formula);
    - ``encoding`` (the spec's), ``manifest_encoding`` (``linear`` or ``srgb``), ``bits``;
    - ``saturated_pixels`` (per image, pixels with any channel at the top code),
      ``saturated_channels`` (per image, [r, g, b] counts), ``peak`` (per image, the largest
      noise-free stored value e·L̄ + s + b before clipping: above 1 means saturation by
      the light, not by the noise);
    - ``supersample``, ``seed``, and ``spec`` (every field of the spec, as given).
    """
    lights = _normalised_lights(spec)
    material = _material_values(spec)
    ambient = _triple(spec.ambient, "ambient", allow_scalar=True)
    stray = np.asarray(_triple(spec.stray, "stray", allow_scalar=True))
    background = np.asarray(_triple(spec.background, "background", allow_scalar=True))
    width, height, samples = spec.width, spec.height, int(spec.supersample) ** 2
    geometry = _geometry(spec)
    exposures = spec.exposures()
    generators = np.random.default_rng(int(spec.seed)).spawn(len(lights))
    images, saturated, channels, peaks = [], [], [], []
    for image_lights, exposure, rng in zip(lights, exposures, generators):
        if spec.chrome:
            radiance = _mirror_radiance(geometry, spec, image_lights, background)
        else:
            radiance = _strauss_radiance(geometry, material, image_lights, ambient)
        # the pixel's mean over its S² samples: the hits' sum plus the background's share
        missed = (samples - geometry.hits).astype(np.float64)
        mean = np.stack(
            [
                (np.bincount(geometry.pixel, weights=radiance[:, c], minlength=width * height) + background[c] * missed)
                / samples
                for c in range(3)
            ],
            axis=-1,
        ).reshape(height, width, 3)
        value = exposure * mean + stray
        peaks.append(float(value.max()) + float(spec.black_level))  # the noise-free stored maximum
        if spec.noise_sd > 0 or spec.shot_slope > 0:
            sd = np.sqrt(float(spec.noise_sd) ** 2 + float(spec.shot_slope) * np.maximum(value, 0.0))
            value = value + sd * rng.standard_normal(value.shape)
        stored = np.clip(value + float(spec.black_level), 0.0, 1.0)
        codes = _codes(stored, spec.encoding)
        top = np.iinfo(codes.dtype).max
        saturated.append(int(np.count_nonzero(np.any(codes == top, axis=-1))))
        channels.append([int(v) for v in np.count_nonzero(codes == top, axis=(0, 1))])
        images.append(stored)
    truth = _truth(spec, lights, material, geometry, saturated, channels, peaks)
    return images, geometry.mask, truth


def _truth(spec, lights, material, geometry, saturated, channels, peaks) -> dict[str, Any]:
    delta = math.radians(float(spec.light_radius_deg))
    camera: dict[str, Any] = {"type": spec.camera}
    if spec.camera == "perspective":
        camera.update(focal_px=float(spec.focal_px), principal_point=list(spec.principal()))
    return {
        "format": TRUTH_FORMAT,
        "version": 1,
        "files": spec.file_names(),
        "mask": {"file": MASK_NAME if spec.write_mask else None, "pixels": int(np.count_nonzero(geometry.mask))},
        "frame": {"width": spec.width, "height": spec.height},
        "material": None if material is None else material,
        "mirror": None
        if not spec.chrome
        else {
            "reflectance": _triple(spec.mirror_reflectance, "mirror_reflectance", allow_scalar=True),
            "light_radius_deg": float(spec.light_radius_deg),
            "light_solid_angle_sr": 2.0 * math.pi * (1.0 - math.cos(delta)),
        },
        "lights": lights,
        "light_model": LIGHT_MODEL,
        "exposure": spec.exposures(),
        "camera": camera,
        "circle": geometry.circle,
        "ambient": _triple(spec.ambient, "ambient", allow_scalar=True),
        "stray": _triple(spec.stray, "stray", allow_scalar=True),
        "background": _triple(spec.background, "background", allow_scalar=True),
        "black_level": float(spec.black_level),
        "noise": {
            "sd": float(spec.noise_sd),
            "shot_slope": float(spec.shot_slope),
            "variance": "sd^2 + shot_slope * max(exposure * radiance + stray, 0), before the black level",
        },
        "encoding": spec.encoding,
        "manifest_encoding": _manifest_encoding(spec),
        "bits": 16 if spec.encoding == "linear16" else 8,
        "saturated_pixels": saturated,
        "saturated_channels": channels,
        "peak": peaks,
        "supersample": int(spec.supersample),
        "seed": int(spec.seed),
        "spec": _plain(dataclasses.asdict(spec)),
    }


def _plain(value: Any) -> Any:
    """Tuples as lists and NumPy scalars as Python numbers (for JSON)."""
    if isinstance(value, dict):
        return {key: _plain(v) for key, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


# --- files ------------------------------------------------------------------------------


def _manifest_encoding(spec: CaptureSpec) -> str:
    return "linear" if spec.encoding == "linear16" else "srgb"


def _toml_float(value: float) -> str:
    # repr of a finite float is a valid TOML float (1.0, 0.1, 1e-05, -0.0)
    return repr(float(value))


def _toml_list(values: Sequence[float]) -> str:
    return "[" + ", ".join(_toml_float(v) for v in values) + "]"


def manifest_text(spec: CaptureSpec) -> str:
    """The capture manifest (TOML, docs/captures.md) of a spec: ``[capture]`` (encoding,
    black level, mask), ``[capture.camera]`` and one ``[[image]]`` per image with its file
    and its ``[[image.light]]`` tables. Neither the circle nor the exposures: finding the
    first is the library's job, and a real user does not know the second."""
    lines = [
        "# A synthetic capture written by data_synth.capture; the truth is in truth.json.",
        "",
        "[capture]",
        f'encoding = "{_manifest_encoding(spec)}"',
        f"black_level = {_toml_float(spec.black_level)}",
    ]
    if spec.write_mask:
        lines.append(f'mask = "{MASK_NAME}"')
    lines += ["", "[capture.camera]", f'type = "{spec.camera}"']
    if spec.camera == "perspective":
        lines += [f"focal_px = {_toml_float(spec.focal_px)}", f"principal_point = {_toml_list(spec.principal())}"]
    for name, lights in zip(spec.file_names(), _normalised_lights(spec)):
        lines += ["", "[[image]]", f'file = "{name}"']
        for light in lights:
            key = "direction" if "direction" in light else "position"
            lines += [
                "[[image.light]]",
                f"{key} = {_toml_list(light[key])}",
                f"intensity = {_toml_list(light['intensity'])}",
            ]
    return "\n".join(lines) + "\n"


def encode_codes(codes: np.ndarray, name: str, *, quality: int | None = None) -> bytes:
    """Integer codes (H, W, C), uint8 or uint16, as the bytes of the image file ``name``
    (its extension picks the format), unchanged (no colour conversion, no timestamp: the
    same codes give the same bytes); ``quality``: a JPEG's quality."""
    import OpenImageIO as oiio

    data = np.ascontiguousarray(codes)
    if data.ndim != 3 or data.dtype not in (np.uint8, np.uint16):
        raise ImageError(f"cannot write codes of shape {data.shape} and type {data.dtype} to {name}")
    pixel_type = oiio.UINT16 if data.dtype == np.uint16 else oiio.UINT8
    spec = oiio.ImageSpec(data.shape[1], data.shape[0], data.shape[2], pixel_type)
    spec.attribute("DateTime", "")  # an empty value drops OpenImageIO's timestamp
    if quality is not None:
        spec.attribute("compression", f"jpeg:{int(quality)}")
    return encoded_bytes(data, spec, name, name)


def write_capture(spec: CaptureSpec, folder: str | Path, *, force: bool = False) -> dict[str, Any]:
    """Render ``spec`` and write it to ``folder`` (created if missing): the images, ``mask.png``
    (unless ``write_mask`` is false), ``capture.toml`` and ``truth.json``; returns the truth.

    All files are written together (temporaries renamed at once, `strauss_fit.io.files.Outputs`):
    either all appear or none. An existing file is not replaced unless ``force`` is true;
    with ``force``, files of an earlier capture that this one does not write (more images)
    are left as they were."""
    folder = Path(folder)
    names = [*spec.file_names(), *([MASK_NAME] if spec.write_mask else []), MANIFEST_NAME, TRUTH_NAME]
    if folder.is_dir():
        for name in names:  # refuse before rendering, not after it
            check_writable(folder / name, force)
    images, mask, truth = render_capture_images(spec)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise StraussFitError(f"cannot create the capture folder {folder}: {exc.strerror or exc}") from None
    quality = JPEG_QUALITY if spec.encoding == "srgb8-jpeg" else None
    with Outputs(force=force) as out:
        for name, stored in zip(spec.file_names(), images):
            out.add_bytes(folder / name, encode_codes(_codes(stored, spec.encoding), name, quality=quality))
        if spec.write_mask:
            out.add_bytes(folder / MASK_NAME, mask_bytes(mask))
        out.add_text(folder / MANIFEST_NAME, manifest_text(spec))
        out.add_json(folder / TRUTH_NAME, truth)
        out.commit()
    return truth


# --- ready-made specs -------------------------------------------------------------------


def cone_directions(count: int, max_polar_deg: float = 45.0) -> list[list[float]]:
    """``count`` unit directions spread evenly over the cap within ``max_polar_deg`` of the
    view axis +z (a Fibonacci spiral: equal-area rings, azimuths by the golden angle), which
    keeps photometric normal estimation well conditioned."""
    golden = math.pi * (3.0 - math.sqrt(5.0))
    cos_max = math.cos(math.radians(max_polar_deg))
    out = []
    for k in range(count):
        cos_theta = 1.0 - (1.0 - cos_max) * (k + 0.5) / count
        sin_theta = math.sqrt(1.0 - cos_theta * cos_theta)
        phi = k * golden
        out.append([sin_theta * math.cos(phi), sin_theta * math.sin(phi), cos_theta])
    return out


def _tinted(strength: float, k: int, spread: float = 0.2) -> list[float]:
    """A coloured intensity: ``strength`` times a tint that turns with k (each channel within
    ±``spread``), so that images differ in colour as real lamps do."""
    return [strength * (1.0 + spread * math.cos(2.0 * math.pi * (k / 5.0 + c / 3.0))) for c in range(3)]


#: The strengths of the "plastic" example's 12 lights: the strongest saturate the highlight.
_PLASTIC_STRENGTHS = (0.9, 1.6, 1.1, 0.8, 1.9, 1.2, 1.0, 2.2, 0.85, 1.4, 1.05, 1.75)


def _plastic_lights() -> list[list[dict[str, Any]]]:
    return [
        [{"direction": direction, "intensity": _tinted(strength, k)}]
        for k, (direction, strength) in enumerate(zip(cone_directions(12, 45.0), _PLASTIC_STRENGTHS))
    ]


def _example_fields(kind: str) -> dict[str, Any]:
    if kind == "plastic":
        return {
            "material": {"color": [0.75, 0.35, 0.18], "smoothness": 0.65, "metalness": 0.0},
            "lights": _plastic_lights(),
        }
    if kind == "perspective":
        directions = cone_directions(6, 40.0)
        lights = [[{"direction": d, "intensity": _tinted(1.0 + 0.1 * k, k)}] for k, d in enumerate(directions[:5])]
        lights += [
            [{"position": [4.0, 3.0, 6.0], "intensity": _tinted(1.2, 5)}],
            [{"position": [-5.0, 1.5, 5.0], "intensity": _tinted(1.0, 6)}],
            [
                {"direction": directions[5], "intensity": _tinted(0.6, 7)},
                {"position": [2.0, -4.0, 7.0], "intensity": _tinted(0.7, 8)},
            ],
        ]
        return {
            "material": {"color": [0.2, 0.45, 0.75], "smoothness": 0.75, "metalness": 0.3},
            "lights": lights,
            "camera": "perspective",
            "focal_px": 260.0,
            "center_px": (236.4, 74.2),
            "radius_px": 44.0,
        }
    if kind == "srgb8":
        return {
            "material": {"color": [0.3, 0.6, 0.25], "smoothness": 0.55, "metalness": 0.0},
            "lights": [
                [{"direction": d, "intensity": _tinted(s, k)}]
                for k, (d, s) in enumerate(
                    zip(cone_directions(10, 45.0), (1.2, 1.8, 1.4, 2.4, 1.0, 1.6, 2.8, 1.3, 1.9, 1.1))
                )
            ],
            "center_px": (148.7, 131.2),
            "radius_px": 55.3,
            "ambient": (0.08, 0.08, 0.1),
            "stray": (0.01, 0.01, 0.012),
            "background": (0.05, 0.05, 0.05),
            "black_level": 0.02,
            "noise_sd": 0.002,
            "shot_slope": 0.0005,
            "encoding": "srgb8",
        }
    if kind == "chrome":
        return {
            "material": {},
            "lights": _plastic_lights(),
            "chrome": True,
            "center_px": (150.2, 125.7),
            "radius_px": 58.3,
            "background": (0.02, 0.02, 0.02),
            "noise_sd": 0.0005,
            # 2° lamps: the reflection of each covers a few whole pixels (1° covers less
            # than one), so that its centre and brightness can be measured
            "light_radius_deg": 2.0,
            "supersample": 8,
        }
    raise SpecError(f"unknown example capture {kind!r}; expected one of {', '.join(EXAMPLES)}")


def example_capture_spec(kind: str = "plastic", **overrides: Any) -> CaptureSpec:
    """A ready-made `CaptureSpec`, with any field replaced by ``overrides``:

    - ``"plastic"``: an orange plastic (C = (0.75, 0.35, 0.18), s = 0.65, m = 0), orthographic,
      the sphere off-centre in 320 × 240 (centre (171.3, 118.6), radius 62.4), 12 images
      each under one coloured directional light, the directions spread evenly within 45° of
      the view axis (`cone_directions`), strengths 0.8 to 2.2: the red channel of the
      highlight saturates in the 16-bit PNGs of the stronger half;
    - ``"perspective"``: a blue metallic paint (s = 0.75, m = 0.3) seen by a wide pinhole
      (f = 260 px) 20° off its axis, so that the silhouette is an ellipse; 8 images: 5
      directional lights, 2 point lights, and one image under a directional and a point light;
    - ``"srgb8"``: a green plastic in 8-bit sRGB PNGs with everything a real camera adds:
      saturated highlights, ambient light, stray light, a grey background, a black level of
      0.02 and noise (σ = 0.002, shot slope 0.0005); 10 images;
    - ``"chrome"``: a mirror ball (reflectance 1) under the same 12 lights as ``"plastic"``,
      each a disc of 2° radius (its reflection covers a few pixels), at one exposure for
      all images chosen so that the brightest light's reflection reaches 0.8 of full scale
      (unsaturated: the lights' relative intensities can be measured); 8 × 8 sub-pixels.
      Unless ``exposure`` is overridden it is recomputed from the final lights, light
      radius and reflectance.
    """
    fields = _example_fields(kind)
    names = {f.name for f in dataclasses.fields(CaptureSpec)}
    unknown = sorted(set(overrides) - names)
    if unknown:
        raise SpecError(f"unknown capture spec field {unknown[0]!r}; expected one of {', '.join(sorted(names))}")
    fields.update(overrides)
    if kind == "chrome" and "exposure" not in overrides:
        # one exposure for all images: the brightest light's reflection at 0.8 of full scale
        probe = CaptureSpec(**fields)
        delta = math.radians(float(probe.light_radius_deg))
        solid_angle = 2.0 * math.pi * (1.0 - math.cos(delta))
        reflectance = max(_triple(probe.mirror_reflectance, "mirror_reflectance", allow_scalar=True))
        brightest = max(max(light["intensity"]) for lights in _normalised_lights(probe) for light in lights)
        level = 0.8 * solid_angle / (max(brightest, 1e-12) * max(reflectance, 1e-12))
        fields["exposure"] = [level] * len(probe.lights)
    return CaptureSpec(**fields)
