r"""The sample sphere found in the frame: its circle (orthographic camera) or cone
(perspective camera), and the normals and view vectors of the pixels it covers.

Conventions (docs/captures.md): pixel (row i, column k) covers [k, k+1) × [i, i+1) and has
its centre at (x, y) = (k + 0.5, i + 0.5); the camera frame has +x right, +y **up**, +z
toward the camera.

- **Orthographic**: the sphere is the circle (cx, cy, r); at an image point (x, y) inside
  it the normal is n = ((x − cx)/r, −(y − cy)/r, √(1 − n_x² − n_y²)) and V = (0, 0, 1).
- **Perspective**: a pinhole at the origin, focal length f (pixels), principal point
  (px, py); the ray through (x, y) is w = normalise(((x − px)/f, −(y − py)/f, −1)) and
  V = −w. A sphere of radius R at distance d along the unit direction u is the cone of
  rays within ρ of u, sin ρ = R/d, and the normal at a pixel is that of the ray's first
  intersection with the sphere (R = 1, d = 1/sin ρ: the scale does not matter).

**Finding the circle.** The silhouette is a set of pixels (a mask, or the pixels of the
images that stand out from the background). Its *boundary points* are the midpoints
between the centres of 4-neighbour pixels of which one is inside and one outside; for
images each is moved along its pair's axis to where the edge lies (the *area estimate*,
below). Then

1. a robust start: circles (cones) through random triples of boundary points, scored by
   how many points lie within 1 px of them minus three times the points that lie well
   outside (the whole silhouette lies inside the true outline);
2. the geometric fit: Gauss–Newton on the signed distances d_i = |p_i − c| − r
   (orthographic) or on the angles d_i = k_i (∠(w_i, u) − ρ) scaled to pixels by the local
   image scale k_i (perspective), over the *inliers*, the points within
   τ = max(3.5 σ̂, 1 px) of the outline (σ̂ = 1.4826 · median |d_i|); repeated until the
   inliers no longer change. Points on a terminator (the lit crescent of a sphere under one
   light), on an occluder or on a speck lie well inside or outside and drop out.

The algebraic start of the perspective fit is linear: rays on the cone satisfy w · a = 1
with a = u / cos ρ, so u = a/|a| and cos ρ = 1/|a|.

**Standard deviations** come from the fit itself: the covariance
σ̂² (Jᵀ W J)⁻¹ with σ̂² = Σ w_i d_i² / (N − 3) over the inliers, inflated by the
correlation of neighbouring residuals along the outline (neighbouring boundary points share
pixels): by 1 + 2 Σ_{k≤10} (1 − k/11) ρ_k, the Bartlett-windowed sum of the residuals'
autocorrelations ρ_k in the order of their angle around the centre.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..errors import CaptureError

__all__ = [
    "Camera",
    "CaptureError",
    "Circle",
    "SphereGeometry",
    "check_in_frame",
    "circle_from_images",
    "circle_from_mask",
    "sphere_geometry",
    "surface_at",
]

CAMERA_KINDS = ("orthographic", "perspective")
CIRCLE_SOURCES = ("mask", "image", "given")
#: A silhouette of fewer pixels (a disc of radius ≈ 4 px) is no sphere to fit.
MIN_SPHERE_PIXELS = 50
#: Fewest boundary points a circle is fitted to.
MIN_BOUNDARY_POINTS = 12
#: The smallest arc of the outline (degrees) a circle is trusted from.
MIN_ARC_DEG = 120.0
#: A circle may reach this far (pixels) beyond the frame before it counts as cut: a pixel
#: whose centre lies outside the frame is no pixel at all.
FRAME_TOLERANCE_PX = 0.5
#: Inliers lie within max(3.5 σ̂, this) pixels of the outline.
MIN_INLIER_BAND_PX = 1.0
#: Robust start: random triples of boundary points tried.
RANSAC_TRIALS = 256
#: The background threshold: median + this many robust standard deviations of the frame's border.
BACKGROUND_SIGMAS = 6.0
#: ... and at least this fraction of the sphere's typical brightness above the background.
BRIGHTNESS_FRACTION = 0.05
#: A region found in the images may reach this fraction of its pixels beyond its outline
#: (specks and a thin stand touching it); more, and it is no sphere.
MAX_OUTSIDE_FRACTION = 0.05
#: Lags of the residual autocorrelation the standard deviations are inflated by.
CORRELATION_LAGS = 10


# --- the camera --------------------------------------------------------------------------------


@dataclass(frozen=True)
class Camera:
    """The camera the photographs were taken with: ``"orthographic"`` (every pixel looks
    along −z), or ``"perspective"`` with ``focal_px`` (the focal length in pixels) and
    ``principal_point`` (x, y) in pixel units (None: the image centre, (W/2, H/2))."""

    kind: str = "orthographic"
    focal_px: float | None = None
    principal_point: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if self.kind not in CAMERA_KINDS:
            raise CaptureError(f"camera type {self.kind!r} is not one of {', '.join(CAMERA_KINDS)}")
        if self.focal_px is not None:
            focal = _finite_number(self.focal_px, "the camera's focal_px")
            if focal <= 0:
                raise CaptureError(f"the camera's focal_px must be > 0, got {focal:g}")
            object.__setattr__(self, "focal_px", focal)
        if self.kind == "perspective" and self.focal_px is None:
            raise CaptureError("a perspective camera needs focal_px (the focal length in pixels)")
        if self.principal_point is not None:
            point = tuple(self.principal_point)
            if len(point) != 2:
                raise CaptureError(f"the camera's principal_point must be [x, y], got {list(point)!r}")
            object.__setattr__(
                self, "principal_point", tuple(_finite_number(v, "the camera's principal_point") for v in point)
            )

    @property
    def perspective(self) -> bool:
        return self.kind == "perspective"

    def principal(self, shape: Sequence[int]) -> tuple[float, float]:
        """The principal point (px, py) for an image of ``shape`` (H, W, ...)."""
        if self.principal_point is not None:
            return self.principal_point  # type: ignore[return-value]
        return (shape[1] / 2.0, shape[0] / 2.0)

    def rays(self, x: np.ndarray, y: np.ndarray, shape: Sequence[int]) -> np.ndarray:
        """Unit ray directions w (..., 3) through image points (x, y): (0, 0, −1) for the
        orthographic camera, normalise(((x − px)/f, −(y − py)/f, −1)) for the perspective one."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        if not self.perspective:
            out = np.zeros(np.broadcast(x, y).shape + (3,))
            out[..., 2] = -1.0
            return out
        px, py = self.principal(shape)
        f = float(self.focal_px)  # type: ignore[arg-type]
        w = np.stack(np.broadcast_arrays((x - px) / f, -(y - py) / f, -np.ones_like(x)), axis=-1)
        return w / np.linalg.norm(w, axis=-1, keepdims=True)  # |w| ≥ 1: no division by zero

    def project(self, w: np.ndarray, shape: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
        """Image points (x, y) of perspective rays w (..., 3), which must point ahead (w_z < 0)."""
        w = np.asarray(w, dtype=np.float64)
        px, py = self.principal(shape)
        f = float(self.focal_px)  # type: ignore[arg-type]
        depth = np.maximum(-w[..., 2], 1e-300)  # callers pass rays ahead of the camera only
        return px + f * w[..., 0] / depth, py - f * w[..., 1] / depth

    def to_dict(self) -> dict[str, Any]:
        data: dict[str, Any] = {"type": self.kind}
        if self.focal_px is not None:
            data["focal_px"] = self.focal_px
        if self.principal_point is not None:
            data["principal_point"] = list(self.principal_point)
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Camera:
        if not isinstance(data, dict):
            raise CaptureError(f"a camera must be a table, got {type(data).__name__}")
        unknown = set(data) - {"type", "focal_px", "principal_point"}
        if unknown:
            raise CaptureError(f"unknown camera keys: {', '.join(sorted(unknown))}")
        return cls(data.get("type", "orthographic"), data.get("focal_px"), data.get("principal_point"))


def _finite_number(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise CaptureError(f"{what} must be a number, got {value!r}")
    number = float(value)
    if not math.isfinite(number):
        raise CaptureError(f"{what} must be a finite number, got {number}")
    return number


# --- the circle ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Circle:
    """Where the sphere is: the circle (``center`` (cx, cy), ``radius``, pixel units) and
    their standard deviations; for a perspective camera also the cone of rays that sees the
    sphere: ``direction`` u (unit, camera frame) and ``angular_radius`` ρ (radians), with
    ``direction_sd`` (the direction's rms angular error, radians) and ``angular_radius_sd``;
    the circle is then the one that best matches the silhouette in pixels. ``source`` says
    where it came from: ``"mask"``, ``"image"`` or ``"given"``; ``points_used`` of
    ``points_total`` boundary points were fitted."""

    center: tuple[float, float]
    radius: float
    center_sd: tuple[float, float] = (0.0, 0.0)
    radius_sd: float = 0.0
    source: str = "given"
    direction: tuple[float, float, float] | None = None
    angular_radius: float | None = None
    direction_sd: float = 0.0
    angular_radius_sd: float = 0.0
    points_used: int = 0
    points_total: int = 0

    def __post_init__(self) -> None:
        center = tuple(self.center)
        if len(center) != 2:
            raise CaptureError(f"a circle's center must be [x, y], got {list(center)!r}")
        object.__setattr__(self, "center", tuple(_finite_number(v, "the circle's center") for v in center))
        radius = _finite_number(self.radius, "the circle's radius")
        if radius <= 0:
            raise CaptureError(f"the circle's radius must be > 0, got {radius:g}")
        object.__setattr__(self, "radius", radius)
        sds = tuple(self.center_sd)
        if len(sds) != 2:
            raise CaptureError(f"a circle's center_sd must be [sx, sy], got {list(sds)!r}")
        object.__setattr__(self, "center_sd", tuple(_non_negative(v, "center_sd") for v in sds))
        object.__setattr__(self, "radius_sd", _non_negative(self.radius_sd, "radius_sd"))
        object.__setattr__(self, "direction_sd", _non_negative(self.direction_sd, "direction_sd"))
        object.__setattr__(self, "angular_radius_sd", _non_negative(self.angular_radius_sd, "angular_radius_sd"))
        if self.source not in CIRCLE_SOURCES:
            raise CaptureError(f"a circle's source must be one of {', '.join(CIRCLE_SOURCES)}, got {self.source!r}")
        if (self.direction is None) != (self.angular_radius is None):
            raise CaptureError("a circle's cone needs both direction and angular_radius")
        if self.direction is not None:
            u = np.array([_finite_number(v, "the cone's direction") for v in self.direction])
            norm = float(np.linalg.norm(u)) if u.shape == (3,) else 0.0
            if u.shape != (3,) or norm < 1e-12:
                raise CaptureError(f"the cone's direction must be a nonzero [x, y, z], got {list(self.direction)!r}")
            object.__setattr__(self, "direction", tuple(float(v) for v in u / norm))
            rho = _finite_number(self.angular_radius, "the cone's angular radius")
            if not 0.0 < rho < math.pi / 2:
                raise CaptureError(f"the cone's angular radius must lie in (0°, 90°), got {math.degrees(rho):g}°")
            object.__setattr__(self, "angular_radius", rho)

    @property
    def has_cone(self) -> bool:
        return self.direction is not None

    @classmethod
    def given(
        cls,
        center: Sequence[float],
        radius: float,
        camera: Camera | None = None,
        shape: Sequence[int] | None = None,
    ) -> Circle:
        """A circle stated by the user (``source="given"``, no uncertainty). With a
        perspective camera the cone is derived from it (`cone_of_circle`), which needs
        the image ``shape`` when the principal point is the image centre."""
        circle = cls(tuple(center), radius, source="given")  # type: ignore[arg-type]
        if camera is not None and camera.perspective:
            if shape is None and camera.principal_point is None:
                raise CaptureError("a perspective circle needs the image size (or the camera's principal point)")
            circle = cone_of_circle(circle, camera, shape if shape is not None else (0, 0))
        return circle

    def grown(self, pixels: float) -> Circle:
        """The same circle ``pixels`` larger in radius (and, for a cone, larger by the angle
        that many pixels span at its outline); for the background around the sphere."""
        radius = self.radius + pixels
        if radius <= 0:
            raise CaptureError(f"the circle of radius {self.radius:g} px cannot shrink by {-pixels:g} px")
        if not self.has_cone:
            return replace(self, radius=radius)
        # pixels per radian of cone at the outline, exact on the optical axis (r = f tan ρ:
        # dr/dρ = f / cos² ρ = r / (sin ρ cos ρ)) and near enough off it
        rho0 = float(self.angular_radius)  # type: ignore[arg-type]
        per_radian = self.radius / max(math.sin(rho0) * math.cos(rho0), 1e-12)
        rho = float(np.clip(self.angular_radius + pixels / per_radian, 1e-9, math.pi / 2 - 1e-6))  # type: ignore[operator]
        return replace(self, radius=radius, angular_radius=rho)

    def describe(self) -> str:
        """One line: centre, radius (and cone), with standard deviations when known."""
        cx, cy = self.center
        sx, sy = self.center_sd
        text = f"circle centre ({cx:.2f}, {cy:.2f})"
        if sx or sy:
            text += f" ± ({sx:.2g}, {sy:.2g})"
        text += f" px, radius {self.radius:.2f}"
        if self.radius_sd:
            text += f" ± {self.radius_sd:.2g}"
        text += " px"
        if self.has_cone:
            u = self.direction
            text += (
                f", cone direction ({u[0]:.4f}, {u[1]:.4f}, {u[2]:.4f})"  # type: ignore[index]
                f", angular radius {math.degrees(self.angular_radius):.3f}°"  # type: ignore[arg-type]
            )
        return text

    def to_dict(self) -> dict[str, Any]:
        """JSON-able: angles in degrees (``angular_radius_deg``, as docs/captures.md stores the cone)."""
        data: dict[str, Any] = {
            "center": list(self.center),
            "radius": self.radius,
            "center_sd": list(self.center_sd),
            "radius_sd": self.radius_sd,
            "source": self.source,
            "points_used": self.points_used,
            "points_total": self.points_total,
        }
        if self.has_cone:
            data["direction"] = list(self.direction)  # type: ignore[arg-type]
            data["angular_radius_deg"] = math.degrees(self.angular_radius)  # type: ignore[arg-type]
            data["direction_sd_deg"] = math.degrees(self.direction_sd)
            data["angular_radius_sd_deg"] = math.degrees(self.angular_radius_sd)
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Circle:
        """The inverse of `to_dict` (``center`` and ``radius`` are required)."""
        if not isinstance(data, dict):
            raise CaptureError(f"a circle must be a table, got {type(data).__name__}")
        known = {
            "center",
            "radius",
            "center_sd",
            "radius_sd",
            "source",
            "points_used",
            "points_total",
            "direction",
            "angular_radius_deg",
            "direction_sd_deg",
            "angular_radius_sd_deg",
        }
        unknown = set(data) - known
        if unknown:
            raise CaptureError(f"unknown circle keys: {', '.join(sorted(unknown))}")
        for key in ("center", "radius"):
            if key not in data:
                raise CaptureError(f"a circle needs {key}")
        for key in ("center", "center_sd", "direction"):
            if key in data and not isinstance(data[key], list | tuple):
                raise CaptureError(f"a circle's {key} must be a list of numbers, got {data[key]!r}")
        rho = data.get("angular_radius_deg")
        return cls(
            center=tuple(data["center"]),  # type: ignore[arg-type]
            radius=data["radius"],
            center_sd=tuple(data.get("center_sd", (0.0, 0.0))),  # type: ignore[arg-type]
            radius_sd=data.get("radius_sd", 0.0),
            source=data.get("source", "given"),
            direction=tuple(data["direction"]) if "direction" in data else None,  # type: ignore[arg-type]
            angular_radius=None if rho is None else math.radians(_finite_number(rho, "angular_radius_deg")),
            direction_sd=math.radians(_finite_number(data.get("direction_sd_deg", 0.0), "direction_sd_deg")),
            angular_radius_sd=math.radians(
                _finite_number(data.get("angular_radius_sd_deg", 0.0), "angular_radius_sd_deg")
            ),
            points_used=int(data.get("points_used", 0)),
            points_total=int(data.get("points_total", 0)),
        )


def _non_negative(value: Any, what: str) -> float:
    number = _finite_number(value, f"the circle's {what}")
    if number < 0:
        raise CaptureError(f"the circle's {what} must be >= 0, got {number:g}")
    return number


# --- the geometry of the sphere's pixels ------------------------------------------------------


@dataclass(frozen=True)
class SphereGeometry:
    """The pixels whose centre shows the sphere: ``rows``, ``cols`` (int arrays, P), and
    per pixel the unit ``normals`` and ``views`` (P, 3, float64, camera frame)."""

    rows: np.ndarray
    cols: np.ndarray
    normals: np.ndarray
    views: np.ndarray

    @property
    def count(self) -> int:
        return int(self.rows.size)


def _tangent_basis(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to the unit vector u and to each other."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(u, helper)
    e1 /= np.linalg.norm(e1)  # u and helper are never parallel: |e1| ≥ sin(25°)
    return e1, np.cross(u, e1)


def _cone(circle: Circle, camera: Camera, shape: Sequence[int]) -> tuple[np.ndarray, float]:
    """(u, ρ): the circle's cone, or one derived from its pixel circle."""
    if not circle.has_cone:
        circle = cone_of_circle(circle, camera, shape)
    return np.asarray(circle.direction, dtype=np.float64), float(circle.angular_radius)  # type: ignore[arg-type]


def cone_of_circle(circle: Circle, camera: Camera, shape: Sequence[int]) -> Circle:
    """``circle`` with the cone (perspective camera) whose rays best match its pixel
    outline: the small circle fitted to the rays through 180 points of it (algebraic fit,
    then the geometric one). A stated circle only approximates a perspective silhouette
    (an ellipse); the cone is exact for the points it was fitted to."""
    if not camera.perspective:
        raise CaptureError("a cone needs a perspective camera")
    phi = np.linspace(0.0, 2 * math.pi, 180, endpoint=False)
    x = circle.center[0] + circle.radius * np.cos(phi)
    y = circle.center[1] + circle.radius * np.sin(phi)
    rays = camera.rays(x, y, shape)
    start = _cone_algebraic(rays, np.ones(len(rays)))
    if start is None:
        raise CaptureError(f"no cone of rays matches the {circle.describe()} with this camera")
    scale = _cone_scale(start, rays, float(camera.focal_px))  # type: ignore[arg-type]
    params, _, _ = _cone_refine(rays, np.ones(len(rays)), start, scale)
    return replace(circle, direction=tuple(params[:3]), angular_radius=float(params[3]))


def circle_perturbations(circle: Circle, camera: Camera) -> list[tuple[Circle, Circle]]:
    """The circle moved by minus and plus one standard deviation along each of its
    independent uncertain parameters, for propagating where the sphere is into what is
    fitted on it: with a perspective camera the cone (two tilts of its direction, each of sd
    ``direction_sd``/√2, and its angular radius), else the circle (cx, cy, r). Parameters
    known exactly (sd 0, e.g. a circle given by the user) are left out."""
    pairs: list[tuple[Circle, Circle]] = []
    if camera.perspective and circle.has_cone:
        u = np.asarray(circle.direction, dtype=np.float64)
        tilt = circle.direction_sd / math.sqrt(2.0)
        if tilt > 0:
            for e in _tangent_basis(u):
                moved = [u * math.cos(tilt) + sign * e * math.sin(tilt) for sign in (-1.0, 1.0)]
                pairs.append(tuple(replace(circle, direction=tuple(float(v) for v in m)) for m in moved))  # type: ignore[misc]
        if circle.angular_radius_sd > 0:
            rho = float(circle.angular_radius)  # type: ignore[arg-type]
            pairs.append(
                tuple(  # type: ignore[misc]
                    replace(circle, angular_radius=float(np.clip(rho + sign * circle.angular_radius_sd, 1e-9, 1.5)))
                    for sign in (-1.0, 1.0)
                )
            )
        return pairs
    cx, cy = circle.center
    for k, sd in enumerate(circle.center_sd):
        if sd > 0:
            pairs.append(
                tuple(  # type: ignore[misc]
                    replace(circle, center=(cx + sign * sd, cy) if k == 0 else (cx, cy + sign * sd))
                    for sign in (-1.0, 1.0)
                )
            )
    if circle.radius_sd > 0:
        pairs.append(
            tuple(replace(circle, radius=circle.radius + sign * circle.radius_sd) for sign in (-1.0, 1.0))  # type: ignore[misc]
        )
    return pairs


def surface_at(
    x: np.ndarray, y: np.ndarray, circle: Circle, camera: Camera, shape: Sequence[int]
) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals and view vectors (..., 3) of the sphere at image points (x, y), which
    need not be pixel centres. A point outside the silhouette gets the normal of the nearest
    point of the outline (the limb: n ⊥ V)."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if not camera.perspective:
        cx, cy = circle.center
        nx = (x - cx) / circle.radius
        ny = -(y - cy) / circle.radius
        rim = np.hypot(nx, ny)
        outside = rim > 1.0
        # beyond the outline: the limb's normal, (nx, ny) scaled to unit length
        scale = np.where(outside, 1.0 / np.maximum(rim, 1e-300), 1.0)
        nx, ny = nx * scale, ny * scale
        nz = np.sqrt(np.maximum(0.0, 1.0 - nx * nx - ny * ny))
        normals = np.stack([nx, ny, nz], axis=-1)
        views = np.zeros_like(normals)
        views[..., 2] = 1.0
        return normals, views
    u, rho = _cone(circle, camera, shape)
    return _cone_surface(camera.rays(x, y, shape), u, rho)


def _cone_surface(w: np.ndarray, u: np.ndarray, rho: float) -> tuple[np.ndarray, np.ndarray]:
    """Normals and views where the rays w meet the sphere of radius 1 centred at C = d u,
    d = 1/sin ρ: t = d cos γ − √(1 − d² sin² γ) (γ = ∠(w, u)), n = t w − C. Rays that
    miss get the tangent point (the square root's argument clipped at 0)."""
    d = 1.0 / math.sin(rho)
    cos_g = w @ u
    sin_g = np.linalg.norm(np.cross(w, u), axis=-1)
    disc = np.maximum(0.0, 1.0 - (d * sin_g) ** 2)  # written so: b² − |C|² + 1 cancels badly for small ρ
    t = d * cos_g - np.sqrt(disc)
    n = t[..., None] * w - d * u
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-300)  # |n| = 1 up to rounding
    return n, -w


def _outline(circle: Circle, camera: Camera, shape: Sequence[int], count: int = 720) -> np.ndarray | None:
    """Points (count, 2) of the silhouette's outline in pixels; None when a perspective
    outline is unbounded (part of the cone lies at or behind the camera plane)."""
    phi = np.linspace(0.0, 2 * math.pi, count, endpoint=False)
    if not camera.perspective:
        cx, cy = circle.center
        return np.stack([cx + circle.radius * np.cos(phi), cy + circle.radius * np.sin(phi)], axis=-1)
    u, rho = _cone(circle, camera, shape)
    e1, e2 = _tangent_basis(u)
    w = math.cos(rho) * u + math.sin(rho) * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)
    if np.any(w[:, 2] > -1e-6):
        return None
    x, y = camera.project(w, shape)
    return np.stack([x, y], axis=-1)


def check_in_frame(circle: Circle, shape: Sequence[int], camera: Camera) -> None:
    """A one-line `CaptureError` when the circle (for a perspective camera the
    ellipse the cone projects to) reaches beyond the frame by more than half a pixel."""
    height, width = int(shape[0]), int(shape[1])
    outline = _outline(circle, camera, shape)
    if outline is None:
        raise CaptureError(
            f"the sphere ({circle.describe()}) reaches behind the camera's image plane: "
            f"it is not wholly in the {width}×{height} frame"
        )
    tol = FRAME_TOLERANCE_PX
    low = outline.min(axis=0)
    high = outline.max(axis=0)
    if low[0] < -tol or low[1] < -tol or high[0] > width + tol or high[1] > height + tol:
        shape_word = "ellipse" if camera.perspective else "circle"
        raise CaptureError(
            f"the sphere is cut by the frame: its {shape_word} ({circle.describe()}; x {low[0]:.1f} to "
            f"{high[0]:.1f}, y {low[1]:.1f} to {high[1]:.1f}) extends beyond the {width}×{height} image"
        )


def sphere_geometry(
    circle: Circle,
    shape: Sequence[int],
    camera: Camera | None = None,
    *,
    margin: float = 0.0,
    clip: bool = False,
) -> SphereGeometry:
    """The pixels of an image of ``shape`` (H, W) whose centre shows the sphere, at least
    ``margin`` pixels inside its outline, with their normals and view vectors (float64).
    No cropping or resampling: rows and cols index the full frame.

    Orthographic: a pixel centre p is inside when |p − c| < r − margin; normals by the
    formula of docs/captures.md. Perspective: p is inside when its ray lies within the cone
    (w · u > cos ρ) and so do the rays of 16 points around it at distance ``margin``; the
    normal is that of the ray's first intersection with the sphere.

    A circle that reaches beyond the frame is an error (`check_in_frame`) unless
    ``clip``, which keeps the pixels in the frame. No pixel inside is an error too."""
    camera = camera or Camera()
    margin = float(margin)
    if not math.isfinite(margin) or margin < 0:
        raise CaptureError(f"the margin must be a finite number >= 0, got {margin}")
    height, width = int(shape[0]), int(shape[1])
    if not clip:
        check_in_frame(circle, shape, camera)
    outline = _outline(circle, camera, shape)
    if outline is None:  # unbounded perspective outline (only with clip): the whole frame
        i0, i1, k0, k1 = 0, height - 1, 0, width - 1
    else:
        low = outline.min(axis=0)
        high = outline.max(axis=0)
        # pixel centres k + 0.5 within [low, high]
        k0, k1 = max(0, math.ceil(low[0] - 0.5)), min(width - 1, math.floor(high[0] - 0.5))
        i0, i1 = max(0, math.ceil(low[1] - 0.5)), min(height - 1, math.floor(high[1] - 0.5))
    if k1 < k0 or i1 < i0:
        raise CaptureError(f"no pixel of the {width}×{height} image lies inside the sphere ({circle.describe()})")
    rows, cols = np.mgrid[i0 : i1 + 1, k0 : k1 + 1]
    rows, cols = rows.ravel(), cols.ravel()
    x, y = cols + 0.5, rows + 0.5
    if not camera.perspective:
        cx, cy = circle.center
        inside = np.hypot(x - cx, y - cy) < circle.radius - margin
    else:
        u, rho = _cone(circle, camera, shape)
        cos_rho = math.cos(rho)
        inside = camera.rays(x, y, shape) @ u > cos_rho
        if margin > 0:
            # the silhouette is convex: a disc of radius margin lies inside when its rim does
            for phi in np.linspace(0.0, 2 * math.pi, 16, endpoint=False):
                sub = np.flatnonzero(inside)
                ok = camera.rays(x[sub] + margin * math.cos(phi), y[sub] + margin * math.sin(phi), shape) @ u > cos_rho
                inside[sub[~ok]] = False
    rows, cols = rows[inside], cols[inside]
    if rows.size == 0:
        raise CaptureError(f"no pixel of the {width}×{height} image lies inside the sphere ({circle.describe()})")
    normals, views = surface_at(cols + 0.5, rows + 0.5, circle, camera, shape)
    return SphereGeometry(rows.astype(np.intp), cols.astype(np.intp), normals, views)


# --- boundary points ----------------------------------------------------------------------------


def _largest_component(foreground: np.ndarray) -> np.ndarray:
    """The largest 4-connected component of ``foreground``, its holes filled."""
    from scipy import ndimage

    labels, count = ndimage.label(foreground)
    if count == 0:
        return np.zeros_like(foreground, dtype=bool)
    sizes = np.bincount(labels.ravel())[1:]
    return ndimage.binary_fill_holes(labels == (int(np.argmax(sizes)) + 1))


def _boundary_pairs(inside: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every 4-neighbour pair of pixels with one inside and one outside, both in the frame:
    the inside pixel (rows, cols) and the unit step (drow, dcol) to the outside one."""
    rows, cols, drows, dcols = [], [], [], []
    left, right = inside[:, :-1], inside[:, 1:]
    for where, k_shift, step in ((left & ~right, 0, 1), (~left & right, 1, -1)):
        i, k = np.nonzero(where)
        rows.append(i), cols.append(k + k_shift), drows.append(np.zeros_like(i)), dcols.append(np.full_like(k, step))
    top, bottom = inside[:-1, :], inside[1:, :]
    for where, i_shift, step in ((top & ~bottom, 0, 1), (~top & bottom, 1, -1)):
        i, k = np.nonzero(where)
        rows.append(i + i_shift), cols.append(k), drows.append(np.full_like(i, step)), dcols.append(np.zeros_like(k))
    return tuple(np.concatenate(a).astype(np.intp) for a in (rows, cols, drows, dcols))  # type: ignore[return-value]


def _midpoints(rows: np.ndarray, cols: np.ndarray, drows: np.ndarray, dcols: np.ndarray) -> np.ndarray:
    """Boundary points (N, 2) = (x, y) halfway between the pair's pixel centres."""
    return np.stack([cols + 0.5 + 0.5 * dcols, rows + 0.5 + 0.5 * drows], axis=-1).astype(np.float64)


def _edge_points(
    image: np.ndarray,
    component: np.ndarray,
    pairs: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    background: float,
    floor: float,
    extrapolate: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sub-pixel edge points by the area estimate, the edge's brightness, and where it applied.

    Along a pair's axis take six pixels, three inside (t = −2, −1, 0: t = 0 the pair's
    inside pixel) and three outside (t = 1, 2, 3). The sphere's brightness above the
    background b is extrapolated linearly from the two inner pixels, which the sphere
    covers whole: B(t) = B₋₁ + (t + 1)(B₋₁ − B₋₂) for t = 0 and t ≥ 1 (held at B(1)
    beyond), at least ``floor``. Each pixel's coverage is c_t = (v_t − b)/B(t), and a
    straight edge blurred by any kernel that keeps the integral (a box pixel, a lens) lies
    at E = −0.5 + Σ_{t≥0} c_t pixel widths from the inside pixel's centre: exact for a
    box-filtered step of any brightness slope, where a level crossing is not. Pairs whose
    pixels leave the frame or cross the silhouette twice keep their midpoint (E = 0.5).
    The brightness returned is B(0), the edge's contrast. Without ``extrapolate`` the
    brightness is held at the brighter of B₋₁ and B₋₂ (the systematic check of
    `circle_from_images`)."""
    rows, cols, drows, dcols = pairs
    height, width = image.shape
    t = np.arange(-2, 4)
    r = rows[:, None] + t[None, :] * drows[:, None]
    c = cols[:, None] + t[None, :] * dcols[:, None]
    ok = (r >= 0).all(axis=1) & (r < height).all(axis=1) & (c >= 0).all(axis=1) & (c < width).all(axis=1)
    r_safe, c_safe = np.clip(r, 0, height - 1), np.clip(c, 0, width - 1)
    membership = component[r_safe, c_safe]
    ok &= membership[:, :3].all(axis=1) & ~membership[:, 3:].any(axis=1)
    values = image[r_safe, c_safe] - background
    slope = values[:, 1] - values[:, 0]
    if not extrapolate:
        values_inner = np.maximum(values[:, 0], values[:, 1])
        values = np.concatenate([values[:, :1], values_inner[:, None], values[:, 2:]], axis=1)
        slope = np.zeros_like(slope)
    edge_brightness = np.maximum(values[:, 1] + slope, floor)  # floor > 0: no division by zero
    outer_brightness = np.maximum(values[:, 1] + 2.0 * slope, floor)
    coverage = values[:, 2] / edge_brightness + values[:, 3:].sum(axis=1) / outer_brightness
    edge = np.where(ok, np.clip(-0.5 + coverage, -1.5, 3.5), 0.5)
    points = np.stack([cols + 0.5 + edge * dcols, rows + 0.5 + edge * drows], axis=-1)
    return points, np.where(ok, edge_brightness, floor), ok


# --- fitting circles and cones ------------------------------------------------------------------


def _kasa(xy: np.ndarray, weights: np.ndarray) -> np.ndarray | None:
    """Algebraic (Kåsa) circle: least squares of x² + y² + D x + E y + F = 0, weighted;
    centre (−D/2, −E/2), r² = cx² + cy² − F. Points centred first for conditioning."""
    mean = xy.mean(axis=0)
    p = xy - mean
    sw = np.sqrt(weights)
    a = np.stack([p[:, 0], p[:, 1], np.ones(len(p))], axis=-1) * sw[:, None]
    b = -(p**2).sum(axis=1) * sw
    (d, e, f), *_ = np.linalg.lstsq(a, b, rcond=None)
    r2 = (d * d + e * e) / 4.0 - f
    if not np.isfinite(r2) or r2 <= 0:
        return None
    return np.array([mean[0] - d / 2.0, mean[1] - e / 2.0, math.sqrt(r2)])


def _circle_candidates(xy: np.ndarray, triples: np.ndarray, max_radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Circles through point triples (T, 3): circumcentres, (T, 3) params and validity."""
    mean = xy.mean(axis=0)
    a, b, c = (xy[triples[:, j]] - mean for j in range(3))
    d = 2.0 * (a[:, 0] * (b[:, 1] - c[:, 1]) + b[:, 0] * (c[:, 1] - a[:, 1]) + c[:, 0] * (a[:, 1] - b[:, 1]))
    a2, b2, c2 = (a**2).sum(1), (b**2).sum(1), (c**2).sum(1)
    valid = np.abs(d) > 1e-9
    d_safe = np.where(valid, d, 1.0)
    ux = (a2 * (b[:, 1] - c[:, 1]) + b2 * (c[:, 1] - a[:, 1]) + c2 * (a[:, 1] - b[:, 1])) / d_safe
    uy = (a2 * (c[:, 0] - b[:, 0]) + b2 * (a[:, 0] - c[:, 0]) + c2 * (b[:, 0] - a[:, 0])) / d_safe
    radius = np.hypot(a[:, 0] - ux, a[:, 1] - uy)
    valid &= (radius > 2.0) & (radius < max_radius)
    return np.stack([ux + mean[0], uy + mean[1], radius], axis=-1), valid


def _circle_residuals(params: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Signed distances (T, N) of the points from circles (T, 3): positive outside."""
    dx = xy[None, :, 0] - params[:, None, 0]
    dy = xy[None, :, 1] - params[:, None, 1]
    return np.hypot(dx, dy) - params[:, None, 2]


def _circle_refine(
    xy: np.ndarray, weights: np.ndarray, start: np.ndarray, steps: int = 50
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Geometric circle fit: Gauss–Newton on d_i = |p_i − c| − r, weighted, with step
    halving. Returns (cx, cy, r), (Jᵀ W J)⁻¹ at the solution, and d."""
    params = start.astype(np.float64).copy()

    def residual_and_jacobian(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        dx, dy = xy[:, 0] - p[0], xy[:, 1] - p[1]
        dist = np.maximum(np.hypot(dx, dy), 1e-12)  # a point at the very centre has no direction
        jac = np.stack([-dx / dist, -dy / dist, -np.ones_like(dist)], axis=-1)
        return dist - p[2], jac

    d, jac = residual_and_jacobian(params)
    cost = float(np.sum(weights * d * d))
    sw = np.sqrt(weights)
    for _ in range(steps):
        step, *_ = np.linalg.lstsq(jac * sw[:, None], -d * sw, rcond=None)
        scale = 1.0
        while scale > 1e-6:
            trial = params + scale * step
            if trial[2] > 0:
                d_new, jac_new = residual_and_jacobian(trial)
                cost_new = float(np.sum(weights * d_new * d_new))
                if cost_new <= cost:
                    break
            scale /= 2
        else:
            break
        params, d, jac, cost = trial, d_new, jac_new, cost_new
        if np.max(np.abs(scale * step)) < 1e-10:
            break
    normal = (jac * weights[:, None]).T @ jac
    return params, np.linalg.pinv(normal), d


def _cone_algebraic(rays: np.ndarray, weights: np.ndarray) -> np.ndarray | None:
    """The small circle w · a = 1 by weighted least squares: u = a/|a|, cos ρ = 1/|a|.
    (ux, uy, uz, ρ), or None when no cone in front of the camera fits."""
    sw = np.sqrt(weights)
    a, *_ = np.linalg.lstsq(rays * sw[:, None], sw, rcond=None)
    norm = float(np.linalg.norm(a))
    if not np.isfinite(norm) or norm <= 1.0:
        return None
    u = a / norm
    if u[2] >= 0:
        return None
    return np.array([*u, math.acos(1.0 / norm)])


def _cone_candidates(rays: np.ndarray, triples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cones through ray triples: [w1; w2; w3] a = 1 solved by a = (w2×w3 + w3×w1 + w1×w2)
    / (w1 · (w2 × w3)); (T, 4) params and validity."""
    w1, w2, w3 = (rays[triples[:, j]] for j in range(3))
    det = np.einsum("ij,ij->i", w1, np.cross(w2, w3))
    valid = np.abs(det) > 1e-15
    a = (np.cross(w2, w3) + np.cross(w3, w1) + np.cross(w1, w2)) / np.where(valid, det, 1.0)[:, None]
    norm = np.linalg.norm(a, axis=1)
    valid &= norm > 1.0
    norm_safe = np.where(valid, norm, 2.0)
    u = a / norm_safe[:, None]
    rho = np.arccos(np.clip(1.0 / norm_safe, -1.0, 1.0))
    valid &= (u[:, 2] < 0) & (rho < math.radians(89.0))
    return np.concatenate([u, rho[:, None]], axis=1), valid


def _angles(rays: np.ndarray, u: np.ndarray) -> np.ndarray:
    """∠(w, u) as atan2(|w × u|, w · u): accurate for small angles too. u (3,) or (T, 3)."""
    if u.ndim == 1:
        return np.arctan2(np.linalg.norm(np.cross(rays, u), axis=-1), rays @ u)
    cross = np.cross(rays[None, :, :], u[:, None, :])
    return np.arctan2(np.linalg.norm(cross, axis=-1), np.einsum("nk,tk->tn", rays, u))


def _cone_scale(params: np.ndarray, rays: np.ndarray, focal: float) -> np.ndarray:
    """Pixels per radian at each ray, for a change of the ray toward or away from u (the
    outline's normal): the image point q = f (w_x, w_y)/(−w_z) moves by
    f/(−w_z) |t_xy + w_xy t_z/(−w_z)| per radian along the unit tangent t."""
    u = params[:3]
    t = u[None, :] - (rays @ u)[:, None] * rays
    t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-300)  # boundary rays are never along u
    depth = np.maximum(-rays[:, 2], 1e-12)
    moved = t[:, :2] + rays[:, :2] * (t[:, 2] / depth)[:, None]
    return focal / depth * np.linalg.norm(moved, axis=1)


def _cone_residuals(params: np.ndarray, rays: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Pixel-equivalent signed distances (T, N) of rays from cones (T, 4): positive outside."""
    return scale[None, :] * (_angles(rays, params[:, :3]) - params[:, None, 3])


def _cone_refine(
    rays: np.ndarray, weights: np.ndarray, start: np.ndarray, scale: np.ndarray, steps: int = 50
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Geometric cone fit: Gauss–Newton on d_i = k_i (∠(w_i, u) − ρ) over (α, β, ρ), where
    u(α, β) = normalise(u + α e1 + β e2) in a tangent basis at the current u:
    ∂∠/∂α = −(w · e1)/sin ∠. Returns (u, ρ), (Jᵀ W J)⁻¹ in (α, β, ρ) at the solution, and d."""
    u = start[:3] / np.linalg.norm(start[:3])
    rho = float(start[3])

    def residual_and_jacobian(u: np.ndarray, rho: float) -> tuple[np.ndarray, np.ndarray]:
        e1, e2 = _tangent_basis(u)
        angle = _angles(rays, u)
        sin_a = np.maximum(np.sin(angle), 1e-12)  # boundary rays lie ρ > 0 from u
        jac = np.stack([-(rays @ e1) / sin_a, -(rays @ e2) / sin_a, -np.ones_like(angle)], axis=-1)
        return scale * (angle - rho), jac * scale[:, None]

    d, jac = residual_and_jacobian(u, rho)
    cost = float(np.sum(weights * d * d))
    sw = np.sqrt(weights)
    for _ in range(steps):
        step, *_ = np.linalg.lstsq(jac * sw[:, None], -d * sw, rcond=None)
        e1, e2 = _tangent_basis(u)
        factor = 1.0
        while factor > 1e-6:
            u_new = u + factor * (step[0] * e1 + step[1] * e2)
            u_new /= np.linalg.norm(u_new)
            rho_new = rho + factor * step[2]
            if 0 < rho_new < math.pi / 2:
                d_new, jac_new = residual_and_jacobian(u_new, rho_new)
                cost_new = float(np.sum(weights * d_new * d_new))
                if cost_new <= cost:
                    break
            factor /= 2
        else:
            break
        u, rho, d, jac, cost = u_new, rho_new, d_new, jac_new, cost_new
        if np.max(np.abs(factor * step)) < 1e-13:
            break
    normal = (jac * weights[:, None]).T @ jac
    return np.array([*u, rho]), np.linalg.pinv(normal), d


@dataclass(frozen=True)
class _Model:
    """One kind of outline: candidates through triples, residuals, the geometric fit."""

    count: int
    candidates: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
    algebraic: Callable[[np.ndarray], np.ndarray | None]
    residuals: Callable[[np.ndarray], np.ndarray]
    refine: Callable[[np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class _Fit:
    params: np.ndarray
    cov: np.ndarray
    inliers: np.ndarray
    residuals: np.ndarray


def _ransac_start(model: _Model, seed: int = 0) -> np.ndarray:
    """The candidate with the best score: points within 1 px minus three times the points
    more than 2 px outside (the whole silhouette lies inside its true outline)."""
    n = model.count
    rng = np.random.default_rng(seed)  # fixed: the same images give the same circle
    triples = rng.integers(0, n, size=(RANSAC_TRIALS, 3))
    triples = triples[
        (triples[:, 0] != triples[:, 1]) & (triples[:, 1] != triples[:, 2]) & (triples[:, 0] != triples[:, 2])
    ]
    params, valid = model.candidates(triples)
    params = params[valid]
    everything = model.algebraic(np.ones(n, dtype=bool))
    if everything is not None:
        params = np.concatenate([everything[None, :], params])
    if len(params) == 0:
        raise CaptureError("no circle fits the sphere's outline")
    scores = np.empty(len(params))
    chunk = max(1, 4_000_000 // n)  # (chunk, n) residuals at a time
    for start in range(0, len(params), chunk):
        d = model.residuals(params[start : start + chunk])
        scores[start : start + chunk] = (np.abs(d) < 1.0).sum(axis=1) - 3 * (d > 2.0).sum(axis=1)
    return params[int(np.argmax(scores))]


def _trimmed_fit(model: _Model, weights: np.ndarray, start: np.ndarray) -> _Fit:
    """Geometric fits over the points within τ = max(3.5 σ̂, 1 px) of the outline, until
    the inliers no longer change (at most 10 rounds)."""
    params = start
    d = model.residuals(params[None, :])[0]
    inliers = np.abs(d) < max(2.0, MIN_INLIER_BAND_PX)

    def enough(selected: np.ndarray) -> np.ndarray:
        if selected.sum() < MIN_BOUNDARY_POINTS:
            raise CaptureError(
                f"only {int(selected.sum())} of {model.count} points of the sphere's outline lie on one circle"
            )
        return selected

    for _ in range(10):
        params, cov, _ = model.refine(enough(inliers), weights, params)
        d = model.residuals(params[None, :])[0]
        sigma = 1.4826 * float(np.median(np.abs(d[inliers])))
        new = np.abs(d) < max(3.5 * sigma, MIN_INLIER_BAND_PX)
        if np.array_equal(new, inliers):
            return _Fit(params, cov, inliers, d)
        inliers = new
    # not settled in 10 rounds (points at the band's edge flip): the fit of the last set
    params, cov, _ = model.refine(enough(inliers), weights, params)
    return _Fit(params, cov, inliers, model.residuals(params[None, :])[0])


def _correlation_factor(residuals: np.ndarray, angles: np.ndarray) -> float:
    """Variance inflation for correlated residuals: 1 + 2 Σ_{k=1}^{L} (1 − k/(L+1)) ρ_k
    over the residuals ordered by angle (Bartlett window, L = 10), at least 1, at most 50."""
    e = residuals[np.argsort(angles)]
    e = e - e.mean()
    total = float(np.sum(e * e))
    if total <= 0 or len(e) < 3 * CORRELATION_LAGS:
        return 1.0
    lags = CORRELATION_LAGS
    factor = 1.0
    for k in range(1, lags + 1):
        rho_k = float(np.sum(e[:-k] * e[k:])) / total
        factor += 2.0 * (1.0 - k / (lags + 1)) * rho_k
    return float(np.clip(factor, 1.0, 50.0))


def _scaled_covariance(fit: _Fit, weights: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """σ̂² (Jᵀ W J)⁻¹ × the correlation factor, σ̂² = Σ w d² / (N − 3) over the inliers."""
    idx = fit.inliers
    n = int(idx.sum())
    w = weights[idx]
    d = fit.residuals[idx]
    sigma2 = float(np.sum(w * d * d)) / max(n - 3, 1)
    return fit.cov * sigma2 * _correlation_factor(np.sqrt(w) * d, angles[idx])


def _arc_deg(angles: np.ndarray) -> float:
    """The arc of the outline the points cover: 360° minus the largest angular gap."""
    a = np.sort(np.mod(angles, 2 * math.pi))
    gaps = np.diff(np.concatenate([a, a[:1] + 2 * math.pi]))
    return math.degrees(2 * math.pi - float(gaps.max()))


def _plane_model(xy: np.ndarray, weights: np.ndarray, shape: Sequence[int]) -> _Model:
    max_radius = 2.0 * float(np.hypot(shape[0], shape[1]))

    def algebraic(select: np.ndarray) -> np.ndarray | None:
        return _kasa(xy[select], weights[select])

    def refine(select: np.ndarray, w: np.ndarray, start: np.ndarray):
        return _circle_refine(xy[select], w[select], start)

    return _Model(
        len(xy),
        lambda triples: _circle_candidates(xy, triples, max_radius),
        algebraic,
        lambda params: _circle_residuals(params, xy),
        refine,
    )


def _cone_model(rays: np.ndarray, weights: np.ndarray, focal: float) -> _Model:
    start = _cone_algebraic(rays, weights)
    # a per-point image scale for scoring candidates (the trimmed fit updates it)
    state = {"scale": _cone_scale(start, rays, focal) if start is not None else focal / np.maximum(-rays[:, 2], 1e-12)}

    def algebraic(select: np.ndarray) -> np.ndarray | None:
        return _cone_algebraic(rays[select], weights[select])

    def refine(select: np.ndarray, w: np.ndarray, start: np.ndarray):
        state["scale"] = _cone_scale(start, rays, focal)
        return _cone_refine(rays[select], w[select], start, state["scale"][select])

    return _Model(
        len(rays),
        lambda triples: _cone_candidates(rays, triples),
        algebraic,
        lambda params: _cone_residuals(params, rays, state["scale"]),
        refine,
    )


def _fit_outline(
    xy: np.ndarray,
    weights: np.ndarray,
    camera: Camera,
    shape: Sequence[int],
    source: str,
    total: int,
    start: _Fit | None = None,
) -> tuple[Circle, _Fit]:
    """Fit the outline to boundary points ``xy`` (pixels) and make the Circle; ``start``: a
    previous fit to begin from (no random start)."""
    weights = weights / float(np.median(weights))  # the scale of W cancels in σ̂² (JᵀWJ)⁻¹
    plane = _plane_model(xy, weights, shape)
    if not camera.perspective:
        first = start.params if start is not None else _ransac_start(plane)
        fit = _trimmed_fit(plane, weights, first)
        cx, cy, r = fit.params
        angles = np.arctan2(xy[:, 1] - cy, xy[:, 0] - cx)
        _check_arc(angles[fit.inliers], fit, total)
        cov = _scaled_covariance(fit, weights, angles)
        sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
        circle = Circle(
            (float(cx), float(cy)),
            float(r),
            (float(sd[0]), float(sd[1])),
            float(sd[2]),
            source,
            points_used=int(fit.inliers.sum()),
            points_total=total,
        )
        return circle, fit
    rays = camera.rays(xy[:, 0], xy[:, 1], shape)
    cone = _cone_model(rays, weights, float(camera.focal_px))  # type: ignore[arg-type]
    first = start.params if start is not None else _ransac_start(cone)
    fit = _trimmed_fit(cone, weights, first)
    u, rho = fit.params[:3], float(fit.params[3])
    e1, e2 = _tangent_basis(u)
    angles = np.arctan2(rays @ e2, rays @ e1)
    _check_arc(angles[fit.inliers], fit, total)
    cov = _scaled_covariance(fit, weights, angles)
    # the pixel circle that best matches the same points (for convenience, docs/captures.md)
    inl = fit.inliers
    pixel_start = _kasa(xy[inl], weights[inl])
    if pixel_start is None:
        raise CaptureError("no circle fits the sphere's outline")
    params, pixel_cov, d = _circle_refine(xy[inl], weights[inl], pixel_start)
    pixel_fit = _Fit(params, pixel_cov, np.ones(int(inl.sum()), dtype=bool), d)
    pixel_angles = np.arctan2(xy[inl, 1] - params[1], xy[inl, 0] - params[0])
    pixel_sd = np.sqrt(np.maximum(np.diag(_scaled_covariance(pixel_fit, weights[inl], pixel_angles)), 0.0))
    circle = Circle(
        (float(params[0]), float(params[1])),
        float(params[2]),
        (float(pixel_sd[0]), float(pixel_sd[1])),
        float(pixel_sd[2]),
        source,
        direction=tuple(float(v) for v in u),  # type: ignore[arg-type]
        angular_radius=rho,
        direction_sd=float(math.sqrt(max(cov[0, 0] + cov[1, 1], 0.0))),
        angular_radius_sd=float(math.sqrt(max(cov[2, 2], 0.0))),
        points_used=int(inl.sum()),
        points_total=total,
    )
    return circle, fit


def _check_arc(angles: np.ndarray, fit: _Fit, total: int) -> None:
    arc = _arc_deg(angles)
    if arc < MIN_ARC_DEG:
        raise CaptureError(
            f"only {arc:.0f}° of the sphere's outline were found ({int(fit.inliers.sum())} of {total} boundary "
            f"points on one circle; at least {MIN_ARC_DEG:.0f}° are needed): give a mask or the circle"
        )


# --- the circle from a mask or from the images ----------------------------------------------------


def _as_mask(mask: np.ndarray) -> np.ndarray:
    """A boolean (H, W) mask: booleans as they are; numbers (grey, or the channels' maximum
    of an (H, W, C) image) true where at least half the mask's maximum, which is the 50 %
    contour of an anti-aliased mask and 'nonzero' of a binary one."""
    mask = np.asarray(mask)
    if mask.ndim == 3:
        mask = mask.max(axis=-1)
    if mask.ndim != 2:
        raise CaptureError(f"a mask must be an image (H, W), got an array of shape {mask.shape}")
    if mask.dtype == bool:
        return mask
    values = np.where(np.isfinite(mask), mask.astype(np.float64), 0.0)
    top = float(values.max()) if values.size else 0.0
    if top <= 0:
        return np.zeros(mask.shape, dtype=bool)
    return values >= 0.5 * top


def circle_from_mask(mask: np.ndarray, camera: Camera | None = None) -> Circle:
    """The sphere's circle (and cone, for a perspective camera) from a mask of its pixels.

    The mask's largest 4-connected component (specks elsewhere ignored, holes filled) gives
    the boundary points halfway between inside and outside neighbours; the outline is
    fitted robustly (module docstring), so a bump or a bite (a stand, an occluder) along it
    is left out. ``mask``: booleans, or numbers (true where at least half their maximum).
    A `CaptureError` when the mask holds nothing or too little, when too little of
    the outline is circular, and when the circle is cut by the frame."""
    camera = camera or Camera()
    inside = _as_mask(mask)
    shape = inside.shape
    if not inside.any():
        raise CaptureError(f"the mask ({shape[1]}×{shape[0]}) has nothing in it: no sphere pixel")
    component = _largest_component(inside)
    area = int(component.sum())
    if area < MIN_SPHERE_PIXELS:
        raise CaptureError(
            f"the mask's largest region has {area} pixels: too small for a sphere (at least {MIN_SPHERE_PIXELS})"
        )
    pairs = _boundary_pairs(component)
    xy = _midpoints(*pairs)
    if len(xy) < MIN_BOUNDARY_POINTS:
        raise CaptureError(f"the mask's region has only {len(xy)} boundary points inside the frame")
    with _cut_by_frame(component):
        circle, _ = _fit_outline(xy, np.ones(len(xy)), camera, shape, "mask", len(xy))
    check_in_frame(circle, shape, camera)
    return circle


@contextmanager
def _cut_by_frame(component: np.ndarray) -> Iterator[None]:
    """A failed fit of a region that touches the frame's border is the frame's doing: say so."""
    try:
        yield
    except CaptureError as exc:
        edges = (component[0, :].any(), component[-1, :].any(), component[:, 0].any(), component[:, -1].any())
        if not any(edges):
            raise
        height, width = component.shape
        raise CaptureError(
            f"the sphere is cut by the frame: its region touches the border of the {width}×{height} image "
            f"and the outline inside cannot be fitted ({exc})"
        ) from None


def _luminance(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image, dtype=np.float64)
    if image.ndim == 3:
        image = image.mean(axis=-1)
    if image.ndim != 2:
        raise CaptureError(f"an image must be (H, W) or (H, W, C), got an array of shape {image.shape}")
    return np.where(np.isfinite(image), image, 0.0)


def _border(shape: Sequence[int]) -> np.ndarray:
    """The frame's border region: a strip 5 % of the shorter side wide (at least 2 px)."""
    height, width = int(shape[0]), int(shape[1])
    band = max(2, round(0.05 * min(height, width)))
    border = np.ones((height, width), dtype=bool)
    border[band : height - band, band : width - band] = False
    return border


def circle_from_images(images: Sequence[np.ndarray], camera: Camera | None = None) -> Circle:
    """The sphere's circle (and cone) from the photographs themselves, against their background.

    1. M = the per-pixel maximum over the images of the channels' mean (a sphere lit from
       many sides is bright all over it); values that are not finite count as 0.
    2. The background: median b and robust deviation σ = 1.4826 MAD of M over the frame's
       border (a strip 5 % of the shorter side wide). Foreground: M > b + max(6 σ,
       0.05 (S − b)), S the median of M over the pixels above b + 6 σ (the sphere's typical
       brightness).
    3. The largest 4-connected foreground component, holes filled; its boundary points
       (midpoints), a robust fit; then each point moved to the edge by the area estimate
       (``_edge_points``: sub-pixel for anti-aliased edges, whatever the threshold), using
       only each point's pair along the axis nearer the outline's normal, weighted by the
       edge contrast squared (the inverse variance of the estimate), and the fit repeated.

    The shadowed side of a sphere under one light (a lit crescent) is handled: the
    terminator's points lie well inside the circle and drop out of the fit, which needs
    120° of the outline.

    A region of which more than 5 % lies over 2 px outside the fitted outline is refused as
    no sphere (the glare of a highlight, the highlights of a mirror ball in a dark room).

    What it cannot do: find a sphere no brighter than its background (a dark sphere on a
    light background, a mirror ball reflecting a dark room: give the mask or the circle);
    separate the sphere from something large and as bright that touches it (a lit stand:
    a thin one is trimmed from the outline, a large one makes the region no sphere); work when the border of
    the frame is not background (the sphere fills the frame). The outline of a sphere whose
    brightness falls to the background at its rim (one frontal light on a matte sphere)
    is found slightly inside it, by at most the width over which the rim is darker than the
    threshold."""
    camera = camera or Camera()
    if len(images) == 0:
        raise CaptureError("no images to find the sphere in")
    lum = [_luminance(image) for image in images]
    shape = lum[0].shape
    for k, image in enumerate(lum[1:], start=2):
        if image.shape != shape:
            raise CaptureError(
                f"image {k} is {image.shape[1]}×{image.shape[0]}, the first {shape[1]}×{shape[0]}: one camera, one size"
            )
    brightest = np.max(np.stack(lum), axis=0) if len(lum) > 1 else lum[0]
    border = brightest[_border(shape)]
    background = float(np.median(border))
    sigma = 1.4826 * float(np.median(np.abs(border - background)))
    above = brightest > background + BACKGROUND_SIGMAS * sigma
    if not above.any() or float(brightest.max()) <= background:
        raise CaptureError(
            f"no sphere found in the {shape[1]}×{shape[0]} images: nothing stands out from the background "
            f"(median {background:.4g}, noise {sigma:.2g} at the frame's border)"
        )
    typical = float(np.median(brightest[above]))
    threshold = background + max(BACKGROUND_SIGMAS * sigma, BRIGHTNESS_FRACTION * (typical - background))
    component = _largest_component(brightest > threshold)
    area = int(component.sum())
    if area < MIN_SPHERE_PIXELS:
        raise CaptureError(
            f"no sphere found in the {shape[1]}×{shape[0]} images: the largest region brighter than the background "
            f"(above {threshold:.4g}; median {background:.4g}, noise {sigma:.2g}) has {area} pixels, "
            f"at least {MIN_SPHERE_PIXELS} are needed"
        )
    pairs = _boundary_pairs(component)
    total = len(pairs[0])
    if total < MIN_BOUNDARY_POINTS:
        raise CaptureError(f"the sphere's region has only {total} boundary points inside the frame")
    # 1. midpoints, robust: the start
    with _cut_by_frame(component):
        _, first = _fit_outline(_midpoints(*pairs), np.ones(total), camera, shape, "image", total)
    # 2. sub-pixel edges along the axis nearer the outline's normal, weighted by contrast²
    points, strength, _ = _edge_points(brightest, component, pairs, background, threshold - background)
    centre = _pixel_centre(first, camera, shape)
    radial = points - centre
    radial /= np.maximum(np.linalg.norm(radial, axis=1, keepdims=True), 1e-12)
    along = np.abs(radial[:, 0] * pairs[3] + radial[:, 1] * pairs[2])  # |cos| between the axis and the normal
    keep = along >= math.cos(math.radians(50.0))
    weights = strength[keep] ** 2
    with _cut_by_frame(component):
        circle, fit = _fit_outline(points[keep], weights, camera, shape, "image", total, start=first)
    # the edge's position depends on how the rim's brightness is modelled: half the change
    # that holding it constant makes is added to the deviations, as a systematic part
    held, _, _ = _edge_points(brightest, component, pairs, background, threshold - background, extrapolate=False)
    circle = _with_systematic(circle, fit, held[keep], weights / float(np.median(weights)), camera, shape)
    check_in_frame(circle, shape, camera)
    _check_region_inside(component, circle, camera)
    return circle


def _check_region_inside(component: np.ndarray, circle: Circle, camera: Camera) -> None:
    """A sphere's silhouette lies inside its outline: a region of which more than
    `MAX_OUTSIDE_FRACTION` lies over 2 px outside the fitted outline is something
    else (a glare's star, a mirror ball's highlights, a lit stand), not a sphere."""
    grown = sphere_geometry(circle.grown(2.0), component.shape, camera, clip=True)
    inside = np.zeros_like(component)
    inside[grown.rows, grown.cols] = True
    area = int(component.sum())
    outside = int((component & ~inside).sum())
    if outside > MAX_OUTSIDE_FRACTION * area:
        raise CaptureError(
            f"the brightest region of the images is not a sphere: {100 * outside / area:.0f} % of its {area} pixels "
            f"lie outside the {circle.describe()} fitted to its outline (a mirror ball reflecting a dark room, glare, "
            f"a lit stand?): give a mask or the circle"
        )


def _with_systematic(
    circle: Circle, fit: _Fit, other: np.ndarray, weights: np.ndarray, camera: Camera, shape: Sequence[int]
) -> Circle:
    """``circle`` with half the change of its parameters when the same inliers are placed
    at ``other`` added in quadrature to its standard deviations."""
    inl = fit.inliers

    def add(sd: float, change: float) -> float:
        return float(math.hypot(sd, 0.5 * change))

    start = _kasa(other[inl], weights[inl])
    if start is None:
        return circle
    params, _, _ = _circle_refine(other[inl], weights[inl], start)
    cx, cy, r = params
    changed = replace(
        circle,
        center_sd=(add(circle.center_sd[0], cx - circle.center[0]), add(circle.center_sd[1], cy - circle.center[1])),
        radius_sd=add(circle.radius_sd, r - circle.radius),
    )
    if not camera.perspective:
        return changed
    rays = camera.rays(other[:, 0], other[:, 1], shape)
    scale = _cone_scale(fit.params, rays, float(camera.focal_px))  # type: ignore[arg-type]
    cone, _, _ = _cone_refine(rays[inl], weights[inl], fit.params, scale[inl])
    turn = float(_angles(cone[None, :3], np.asarray(circle.direction))[0])
    return replace(
        changed,
        direction_sd=add(circle.direction_sd, turn),
        angular_radius_sd=add(circle.angular_radius_sd, float(cone[3]) - float(circle.angular_radius)),  # type: ignore[arg-type]
    )


def _pixel_centre(fit: _Fit, camera: Camera, shape: Sequence[int]) -> np.ndarray:
    """The outline's centre in pixels (a cone's: the projection of u, near enough to pick
    each boundary point's axis)."""
    if not camera.perspective:
        return fit.params[:2]
    x, y = camera.project(fit.params[None, :3], shape)
    return np.array([float(x[0]), float(y[0])])
