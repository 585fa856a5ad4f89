r"""Lights from photographs of a mirror (chrome) ball.

A distant light seen in a mirror sphere is a small bright spot, the *highlight*, where the
sphere's normal n halves the angle between the view vector v and the light: the light's
direction is the reflection of the view ray, **l = 2 (n · v) n − v** (camera frame,
toward the light). Per photograph:

1. the highlight: the brightest compact blob inside the sphere: the peak of the image
   smoothed by a Gaussian of 1 px (a hot pixel or noise does not win), then the connected
   pixels above half the peak over the local background (the median of a ring around the
   blob on the sphere), found twice (first against the sphere's median);
2. its sub-pixel centre: the centroid of the pixels of that blob, each weighted by its
   value above the background (a saturated core is fine: the centroid of a flat top is its
   centre);
3. the normal and view vector at that point (`surface_at`,
   orthographic or perspective), and l by the reflection above.

**Uncertainty.** The centroid's covariance from the pixel noise σ (1.4826 × the MAD of the
ring, at least the rounding of the stored values, step/√12): Var x̄ = σ² Σ (x_k − x̄)² / (Σ w_k)²
(and likewise y, and the covariance); the circle's from its standard deviations (centre and
radius, or the cone's direction and angular radius). Both are carried through the
reflection by central finite differences of l, projected on the plane perpendicular to
l: the reported ``direction_sd_deg`` is the root of the trace of that 2 × 2 covariance (the
rms angular error), in degrees.

**Relative intensity.** For an orthographic mirror sphere of radius r (pixels) the image
area per solid angle of reflected directions is constant: dA = (r²/4) dΩ_l. So the sum of
the highlight's values above the background, times 4/r², is the light's radiance
integrated over its solid angle (its irradiance at normal incidence) times the mirror's
reflectance: proportional to the light's intensity, per channel. With a perspective
camera each pixel's solid angle |∂l/∂x × ∂l/∂y| is computed instead. The reflectance
of chrome (Fresnel, at incidence θ/2 for a light θ from the view axis) changes by a few
per cent up to θ ≈ 90° and is taken as constant. The sum runs over the blob grown by two
pixels and is given only when none of those pixels is saturated (a stored value at or
above the saturation level, in any channel): a clipped highlight's sum says nothing.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import CaptureError
from ._sphere import (
    Camera,
    Circle,
    _cone,
    _cone_surface,
    _tangent_basis,
    check_in_frame,
    circle_from_images,
    circle_from_mask,
    cone_of_circle,
    sphere_geometry,
)

__all__ = ["LightEstimate", "estimate_light", "estimate_lights", "lights_toml"]

#: The highlight must stand this many noise deviations above the sphere's median.
MIN_HIGHLIGHT_SIGMAS = 8.0
#: Pixels the blob is grown by for the intensity sum (its faint rim).
APERTURE_GROWTH_PX = 2
#: A second bright region with this fraction of the highlight's energy gets a note.
SECOND_HIGHLIGHT_FRACTION = 0.1
#: Finite-difference steps: image positions and circle centre/radius (px), cone angles (rad).
STEP_PX = 1e-3
STEP_RAD = 1e-6


@dataclass(frozen=True)
class LightEstimate:
    """One light measured on a mirror-ball photograph.

    ``direction``: unit, toward the light, camera frame; ``direction_sd_deg``: its rms
    angular standard deviation; ``intensity``: relative RGB (see the module docstring),
    None when the highlight is saturated; ``pixel``: the highlight's sub-pixel centre (x, y)
    with ``pixel_sd``; ``notes``: what the estimate should be read with;
    ``saturated_pixels``: in the highlight; ``circle``: the mirror ball's circle used."""

    direction: tuple[float, float, float]
    direction_sd_deg: float
    intensity: tuple[float, float, float] | None
    pixel: tuple[float, float]
    pixel_sd: tuple[float, float]
    notes: tuple[str, ...] = ()
    saturated_pixels: int = 0
    circle: Circle | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "direction": list(self.direction),
            "direction_sd_deg": self.direction_sd_deg,
            "intensity": None if self.intensity is None else list(self.intensity),
            "pixel": list(self.pixel),
            "pixel_sd": list(self.pixel_sd),
            "notes": list(self.notes),
            "saturated_pixels": self.saturated_pixels,
            "circle": None if self.circle is None else self.circle.to_dict(),
        }


def _reflect(n: np.ndarray, v: np.ndarray) -> np.ndarray:
    """l = 2 (n · v) n − v, normalised (unit for unit n and v, up to rounding)."""
    l = 2.0 * np.sum(n * v, axis=-1, keepdims=True) * n - v
    return l / np.maximum(np.linalg.norm(l, axis=-1, keepdims=True), 1e-300)


def _light_at(
    x: np.ndarray, y: np.ndarray, geometry: tuple[float, ...], camera: Camera, shape: Sequence[int]
) -> np.ndarray:
    """The reflected direction at image points (x, y) for the sphere ``geometry``: (cx, cy, r)
    orthographic, (ux, uy, uz, ρ) perspective. Points outside the outline take the limb's."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if not camera.perspective:
        cx, cy, r = geometry
        nx, ny = (x - cx) / r, -(y - cy) / r
        rim = np.hypot(nx, ny)
        scale = np.where(rim > 1.0, 1.0 / np.maximum(rim, 1e-300), 1.0)  # beyond the outline: the limb
        nx, ny = nx * scale, ny * scale
        nz = np.sqrt(np.maximum(0.0, 1.0 - nx * nx - ny * ny))
        n = np.stack([nx, ny, nz], axis=-1)
        v = np.zeros_like(n)
        v[..., 2] = 1.0
        return _reflect(n, v)
    u = np.asarray(geometry[:3], dtype=np.float64)
    u /= np.linalg.norm(u)
    n, v = _cone_surface(camera.rays(x, y, shape), u, float(geometry[3]))
    return _reflect(n, v)


def _geometry(circle: Circle, camera: Camera, shape: Sequence[int]) -> tuple[tuple[float, ...], np.ndarray]:
    """The sphere's parameters for `_light_at` and their standard deviations."""
    if not camera.perspective:
        cx, cy = circle.center
        sd = np.array([circle.center_sd[0], circle.center_sd[1], circle.radius_sd])
        return (cx, cy, circle.radius), sd
    u, rho = _cone(circle, camera, shape)
    # the direction's rms angular error spread over its two tangent components
    tangent = circle.direction_sd / math.sqrt(2.0) if circle.has_cone else 0.0
    sd = np.array([tangent, tangent, circle.angular_radius_sd if circle.has_cone else 0.0])
    return (*u, rho), sd


def _direction_covariance(
    point: np.ndarray,
    point_cov: np.ndarray,
    geometry: tuple[float, ...],
    geometry_sd: np.ndarray,
    camera: Camera,
    shape: Sequence[int],
) -> tuple[np.ndarray, np.ndarray]:
    """l at ``point`` and the 2 × 2 covariance of its angular error (radians²) in a tangent
    basis at l, by central differences over the point (x, y) and the sphere's parameters."""
    l = _light_at(point[0], point[1], geometry, camera, shape)
    e1, e2 = _tangent_basis(l)
    columns = []
    for j in range(2):
        step = np.zeros(2)
        step[j] = STEP_PX
        plus = _light_at(*(point + step), geometry, camera, shape)
        minus = _light_at(*(point - step), geometry, camera, shape)
        columns.append((plus - minus) / (2 * STEP_PX))
    g = np.asarray(geometry, dtype=np.float64)
    if not camera.perspective:
        for j in range(3):
            step = np.zeros(3)
            step[j] = STEP_PX
            plus = _light_at(*point, tuple(g + step), camera, shape)
            minus = _light_at(*point, tuple(g - step), camera, shape)
            columns.append((plus - minus) / (2 * STEP_PX))
    else:
        u = g[:3]
        t1, t2 = _tangent_basis(u)
        for axis in (t1, t2):
            plus = _light_at(*point, (*(u + STEP_RAD * axis), g[3]), camera, shape)
            minus = _light_at(*point, (*(u - STEP_RAD * axis), g[3]), camera, shape)
            columns.append((plus - minus) / (2 * STEP_RAD))
        plus = _light_at(*point, (*u, g[3] + STEP_RAD), camera, shape)
        minus = _light_at(*point, (*u, g[3] - STEP_RAD), camera, shape)
        columns.append((plus - minus) / (2 * STEP_RAD))
    derivative = np.stack(columns, axis=-1)  # (3, 5): dl / d(x, y, sphere parameters)
    jac = np.stack([e1 @ derivative, e2 @ derivative])  # (2, 5): the angular components
    cov = np.zeros((5, 5))
    cov[:2, :2] = point_cov
    cov[2:, 2:] = np.diag(geometry_sd**2)
    return l, jac @ cov @ jac.T


def _solid_angles(
    x: np.ndarray, y: np.ndarray, geometry: tuple[float, ...], camera: Camera, shape: Sequence[int], radius: float
) -> np.ndarray:
    """Solid angle of reflected directions per pixel: 4/r² orthographic (dA = r²/4 dΩ_l),
    |∂l/∂x × ∂l/∂y| (central differences of a quarter pixel) perspective."""
    if not camera.perspective:
        return np.full(np.shape(x), 4.0 / radius**2)
    h = 0.25
    dx = (_light_at(x + h, y, geometry, camera, shape) - _light_at(x - h, y, geometry, camera, shape)) / (2 * h)
    dy = (_light_at(x, y + h, geometry, camera, shape) - _light_at(x, y - h, geometry, camera, shape)) / (2 * h)
    return np.linalg.norm(np.cross(dx, dy), axis=-1)


def _rgb(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image, dtype=np.float64)
    if image.ndim == 2:
        image = np.repeat(image[..., None], 3, axis=-1)
    if image.ndim != 3 or image.shape[-1] < 1:
        raise CaptureError(f"an image must be (H, W) or (H, W, C), got an array of shape {image.shape}")
    if image.shape[-1] < 3:
        image = np.repeat(image[..., :1], 3, axis=-1)
    image = image[..., :3]
    if not np.isfinite(image).all():
        raise CaptureError("the mirror-ball image holds values that are not finite numbers")
    return image


def _robust(values: np.ndarray) -> tuple[float, float]:
    """Median and 1.4826 × MAD."""
    median = float(np.median(values))
    return median, 1.4826 * float(np.median(np.abs(values - median)))


def _rounding_noise(values: np.ndarray) -> float:
    """The standard deviation of rounding to the stored values' step (step/√12, the step the
    smallest positive difference between distinct values), for the mean of three channels
    rounded independently (÷ √3); 0 where the values are not quantised visibly."""
    distinct = np.unique(values)
    if distinct.size < 2:
        return 0.0
    step = float(np.min(np.diff(distinct)))
    return step / math.sqrt(12.0) / math.sqrt(3.0)


def estimate_light(
    image: np.ndarray,
    circle: Circle,
    camera: Camera | None = None,
    mask: np.ndarray | None = None,
    *,
    saturation: float | None = None,
    clipped: np.ndarray | None = None,
) -> LightEstimate:
    """The one light of a mirror-ball photograph (module docstring).

    ``image``: (H, W, 3) or (H, W), linear (values as stored: only the highlight's position
    matters for the direction; its sum for the intensity needs linear values);
    ``circle``: the ball's circle (cone); ``mask``: (H, W) bool, where to look (besides
    inside the circle); ``saturation``: stored values at or above it (any channel) are
    saturated; ``clipped``: (H, W) bool, pixels known saturated (the reader's)."""
    camera = camera or Camera()
    pixels = _rgb(image)
    shape = pixels.shape[:2]
    geometry, geometry_sd = _geometry(circle, camera, shape)
    region = _ball_region(circle, camera, shape, mask)
    saturated = _saturated_pixels(pixels, clipped, saturation)
    # work inside the ball's bounding box (plus a margin): the rest of the frame is not looked at
    box = _bounding_box(region)
    rgb, inside, sat = pixels[box], region[box], saturated[box]
    lum = rgb.mean(axis=-1)
    spot = _highlight(lum, inside)
    aperture, total, point, point_cov = _centroid(spot, lum, inside, rgb, box)
    direction, angular_cov = _direction_covariance(point, point_cov, geometry, geometry_sd, camera, shape)
    direction_sd = math.degrees(math.sqrt(max(float(np.trace(angular_cov)), 0.0)))
    notes: list[str] = []
    saturated_count = int(sat[aperture].sum())
    intensity: tuple[float, float, float] | None
    if saturated_count:
        intensity = None
        notes.append(f"{saturated_count} saturated pixels in the highlight: its intensity is unknown")
    else:
        intensity = _intensity(spot, rgb, inside, aperture, box, geometry, camera, shape, circle.radius)
    notes += _highlight_notes(spot, lum, total, circle, camera, shape, box)
    return LightEstimate(
        direction=tuple(float(v) for v in direction),  # type: ignore[arg-type]
        direction_sd_deg=direction_sd,
        intensity=intensity,
        pixel=(float(point[0]), float(point[1])),
        pixel_sd=(math.sqrt(max(point_cov[0, 0], 0.0)), math.sqrt(max(point_cov[1, 1], 0.0))),
        notes=tuple(notes),
        saturated_pixels=saturated_count,
        circle=circle,
    )


def _ball_region(circle: Circle, camera: Camera, shape: tuple[int, int], mask: np.ndarray | None) -> np.ndarray:
    """Where to look for the highlight (H, W): the ball's pixels, within ``mask`` if given;
    a one-line error when that is under ten pixels."""
    height, width = shape
    sphere = sphere_geometry(circle, shape, camera, clip=True)
    region = np.zeros(shape, dtype=bool)
    region[sphere.rows, sphere.cols] = True
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != shape:
            raise CaptureError(f"the mask is {mask.shape[1]}×{mask.shape[0]}, the image {width}×{height}")
        region &= mask
    if region.sum() < 10:
        raise CaptureError(f"the mirror ball ({circle.describe()}) covers only {int(region.sum())} pixels")
    return region


def _saturated_pixels(pixels: np.ndarray, clipped: np.ndarray | None, saturation: float | None) -> np.ndarray:
    """The saturated pixels (H, W): those the reader found clipped and those with a value at
    or above ``saturation`` in any channel."""
    saturated = np.zeros(pixels.shape[:2], dtype=bool)
    if clipped is not None:
        saturated |= np.asarray(clipped, dtype=bool)
    if saturation is not None:
        saturated |= np.any(pixels >= saturation, axis=-1)
    return saturated


def _bounding_box(region: np.ndarray) -> tuple[slice, slice]:
    """The rows and columns of ``region``'s bounding box, with a margin of three pixels
    (within the frame)."""
    height, width = region.shape
    rows_any, cols_any = np.nonzero(region)
    i0, i1 = max(rows_any.min() - 3, 0), min(rows_any.max() + 4, height)
    k0, k1 = max(cols_any.min() - 3, 0), min(cols_any.max() + 4, width)
    return slice(i0, i1), slice(k0, k1)


@dataclass
class _Highlight:
    """The highlight found in the ball's bounding box (module docstring, step 1)."""

    #: the brightest raw pixel next to the smoothed peak (row, column in the box)
    seed: tuple[int, int]
    #: its luminance
    peak: float
    #: the connected regions above the half level (`scipy.ndimage.label`)
    labels: np.ndarray
    #: the highlight: the region of the seed
    blob: np.ndarray
    #: the ring around it the background is measured in
    ring: np.ndarray
    #: the background's median luminance and noise (1.4826 × MAD)
    background: float
    noise: float


def _highlight(lum: np.ndarray, inside: np.ndarray) -> _Highlight:
    """The highlight on the ball (``inside``) of the luminance ``lum``: the connected
    pixels above half its peak over the background, found twice (against the ball's
    median, then against the ring around the blob); a one-line error when nothing stands
    out."""
    from scipy import ndimage

    background, noise = _robust(lum[inside])
    seed = _seed(lum, inside)
    peak = float(lum[seed])
    if not peak - background > max(MIN_HIGHLIGHT_SIGMAS * noise, 0.0):
        raise CaptureError(
            f"no highlight on the mirror ball: its brightest point ({peak:.4g}) does not stand out from the "
            f"ball's median ({background:.4g}, noise {noise:.2g})"
        )
    structure = np.ones((3, 3), dtype=bool)
    ring = np.zeros_like(inside)
    for _ in range(2):  # against the ball's median, then against the ring around the blob
        level = background + 0.5 * (peak - background)
        labels, _count = ndimage.label(inside & (lum > level), structure=structure)
        blob = labels == labels[seed]
        size = math.sqrt(blob.sum() / math.pi)
        distance = ndimage.distance_transform_edt(~blob)
        ring = inside & (distance > 2.0) & (distance <= 2.0 + max(6.0, 2.0 * size))
        if ring.sum() < 10:
            break
        background, noise = _robust(lum[ring])
        if not peak > background:
            raise CaptureError(
                f"no highlight on the mirror ball: its brightest point ({peak:.4g}) is no brighter "
                f"than its surroundings ({background:.4g})"
            )
    level = background + 0.5 * (peak - background)
    labels, _count = ndimage.label(inside & (lum > level), structure=structure)
    blob = labels == labels[seed]
    return _Highlight(seed, peak, labels, blob, ring, background, noise)


def _seed(lum: np.ndarray, inside: np.ndarray) -> tuple[int, int]:
    """The highlight's seed: the peak of the ball's luminance smoothed by a Gaussian of
    1 px (a hot pixel or noise does not win), moved to the brightest raw pixel next to it
    (which lies above any half level)."""
    from scipy import ndimage

    weight = ndimage.gaussian_filter(inside.astype(np.float64), 1.0)
    smooth = ndimage.gaussian_filter(np.where(inside, lum, 0.0), 1.0) / np.maximum(weight, 1e-12)
    smooth = np.where(inside, smooth, -np.inf)
    pi, pk = np.unravel_index(int(np.argmax(smooth)), smooth.shape)
    window = (slice(max(pi - 1, 0), pi + 2), slice(max(pk - 1, 0), pk + 2))
    local = np.where(inside[window], lum[window], -np.inf)
    wi, wk = np.unravel_index(int(np.argmax(local)), local.shape)
    return (window[0].start + wi, window[1].start + wk)


def _centroid(
    spot: _Highlight, lum: np.ndarray, inside: np.ndarray, rgb: np.ndarray, box: tuple[slice, slice]
) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """The highlight's sub-pixel centre (module docstring, step 2): the aperture summed
    over, the total weight, the centre (x, y) in the frame and its 2 × 2 covariance from
    the pixel noise.

    The centroid runs over the blob grown by two pixels: the pixels the spot covers only
    partly (below the half level) count with their share, so a spot of a few pixels is not
    pulled toward whichever side the sampling grid happens to favour."""
    from scipy import ndimage

    structure = np.ones((3, 3), dtype=bool)
    aperture = ndimage.binary_dilation(spot.blob, structure=structure, iterations=APERTURE_GROWTH_PX) & inside
    rows, cols = np.nonzero(aperture)
    weights = lum[rows, cols] - spot.background
    total = float(weights.sum())  # > 0: the blob's pixels lie above the half level, the rim's near 0
    if not total > 0:
        raise CaptureError("no highlight on the mirror ball: nothing stands above its surroundings")
    x = cols + box[1].start + 0.5
    y = rows + box[0].start + 0.5
    cx_bar = float(np.sum(weights * x) / total)
    cy_bar = float(np.sum(weights * y) / total)
    around = aperture | spot.ring
    sigma = max(spot.noise, _rounding_noise(rgb[around].ravel()))
    dx, dy = x - cx_bar, y - cy_bar
    point_cov = sigma**2 / total**2 * np.array([[np.sum(dx * dx), np.sum(dx * dy)], [np.sum(dx * dy), np.sum(dy * dy)]])
    return aperture, total, np.array([cx_bar, cy_bar]), point_cov


def _intensity(
    spot: _Highlight,
    rgb: np.ndarray,
    inside: np.ndarray,
    aperture: np.ndarray,
    box: tuple[slice, slice],
    geometry: tuple[float, ...],
    camera: Camera,
    shape: tuple[int, int],
    radius: float,
) -> tuple[float, float, float]:
    """The light's relative RGB intensity (module docstring): the aperture's values above
    the background, each times its pixel's solid angle of reflected directions."""
    ring = spot.ring
    channel_background = np.median(rgb[ring], axis=0) if ring.sum() >= 10 else np.median(rgb[inside], axis=0)
    ar, ac = np.nonzero(aperture)
    solid = _solid_angles(ac + box[1].start + 0.5, ar + box[0].start + 0.5, geometry, camera, shape, radius)
    sums = ((rgb[ar, ac] - channel_background) * solid[:, None]).sum(axis=0)
    return tuple(float(max(v, 0.0)) for v in sums)  # type: ignore[return-value]


def _highlight_notes(
    spot: _Highlight,
    lum: np.ndarray,
    total: float,
    circle: Circle,
    camera: Camera,
    shape: tuple[int, int],
    box: tuple[slice, slice],
) -> list[str]:
    """What the estimate should be read with: a highlight at the ball's edge (a light near
    grazing, seen foreshortened and cut), and another bright region that was ignored."""
    notes = []
    edge = np.zeros(shape, dtype=bool)
    try:
        inner = sphere_geometry(circle, shape, camera, margin=1.5, clip=True)
        edge[inner.rows, inner.cols] = True
    except CaptureError:
        pass
    if np.any(spot.blob & ~edge[box]):
        notes.append("the highlight reaches the ball's edge: the light is near grazing and its direction less certain")
    labels = spot.labels
    energy = np.bincount(labels.ravel(), weights=np.maximum(lum - spot.background, 0.0).ravel())
    energy[0] = 0.0
    energy[labels[spot.seed]] = 0.0
    if energy.size and energy.max() > SECOND_HIGHLIGHT_FRACTION * total:
        notes.append(
            f"another bright region ({100 * energy.max() / total:.0f} % of the highlight's energy) was ignored: "
            "a second light or a reflection"
        )
    return notes


def _read_mask(path: str | Path, shape: tuple[int, int] | None) -> np.ndarray:
    """A mask file as booleans: at least half its maximum (the 50 % contour of an
    anti-aliased mask; 'nonzero' of a binary one)."""
    from ..io.images import read_image

    pixels = read_image(path, encoding="linear").pixels.max(axis=-1)
    if shape is not None and pixels.shape != shape:
        raise CaptureError(f"the mask {path} is {pixels.shape[1]}×{pixels.shape[0]}, the images {shape[1]}×{shape[0]}")
    top = float(pixels.max()) if pixels.size else 0.0
    if not top > 0:
        raise CaptureError(f"the mask {path} has nothing in it: no nonzero pixel")
    return pixels >= 0.5 * top


def estimate_lights(
    paths: Sequence[str | Path],
    mask_path: str | Path | None = None,
    circle: Circle | None = None,
    camera: Camera | None = None,
    saturation: float | None = None,
    *,
    encoding: str = "linear",
    progress: Callable[[str], Any] | None = None,
) -> list[LightEstimate]:
    """One light per mirror-ball photograph in ``paths``.

    The images are read with ``encoding`` (default ``"linear"``: values as stored; the
    highlight's position is what matters, its intensity needs linear values). The ball's
    circle: ``circle`` if given (for a perspective camera its cone is derived when it has
    none), else from the mask at ``mask_path``, else from the images
    (`circle_from_images`, which needs a ball brighter
    than the background: a ball reflecting a dark room needs the mask or the circle).
    ``saturation``: stored values at or above it are saturated (default: the largest code
    of an integer file, none for a float file). Intensities are scaled so that their
    largest channel is 1 (those known). A `CaptureError` names the file it concerns."""
    from ..color import srgb_decode
    from ..io.images import read_image

    camera = camera or Camera()
    say = progress or (lambda message: None)
    if len(paths) == 0:
        raise CaptureError("no mirror-ball images given")
    if encoding not in ("linear", "srgb"):
        raise CaptureError(f"unknown encoding {encoding!r}; expected linear or srgb")
    if saturation is not None and not (math.isfinite(saturation) and 0 < saturation <= 1):
        raise CaptureError(f"the saturation level must lie in (0, 1], got {saturation}")
    images = []
    shape: tuple[int, int] | None = None
    for path in paths:
        loaded = read_image(path, encoding=encoding)  # type: ignore[arg-type]
        if shape is None:
            shape = loaded.pixels.shape[:2]
        elif loaded.pixels.shape[:2] != shape:
            raise CaptureError(
                f"{path} is {loaded.pixels.shape[1]}×{loaded.pixels.shape[0]}, the first image "
                f"{shape[1]}×{shape[0]}: the mirror-ball images come from one camera"
            )
        if not np.isfinite(loaded.pixels).all():
            raise CaptureError(f"{path} holds values that are not finite numbers")
        clipped = None
        if saturation is not None:
            # a stored value at or above the level; sRGB decoding is monotone
            level = float(srgb_decode(np.array([saturation]))[0]) if loaded.encoding == "srgb" else saturation
            clipped = np.any(loaded.pixels >= level, axis=-1)
        elif np.any(loaded.clipped):
            clipped = loaded.clipped
        images.append((path, loaded.pixels, clipped))
    say(f"read {len(images)} images ({shape[1]}×{shape[0]})")  # type: ignore[index]
    assert shape is not None
    mask = None
    if mask_path is not None:
        mask = _read_mask(mask_path, shape)
    if circle is not None:
        if camera.perspective and not circle.has_cone:
            circle = cone_of_circle(circle, camera, shape)
        check_in_frame(circle, shape, camera)
    elif mask is not None:
        try:
            circle = circle_from_mask(mask, camera)
        except CaptureError as exc:
            raise CaptureError(f"{mask_path}: {exc}") from None
    else:
        circle = circle_from_images([pixels for _, pixels, _ in images], camera)
    say(f"mirror ball: {circle.describe()} (from the {circle.source if circle.source != 'image' else 'images'})")
    estimates = []
    for path, pixels, clipped in images:
        try:
            estimate = estimate_light(pixels, circle, camera, mask, clipped=clipped)
        except CaptureError as exc:
            raise CaptureError(f"{path}: {exc}") from None
        estimates.append(estimate)
        say(f"{path}: light {_format_direction(estimate.direction)} ± {estimate.direction_sd_deg:.2f}°")
    known = [max(e.intensity) for e in estimates if e.intensity is not None]
    top = max(known) if known else 0.0
    if top > 0:
        estimates = [
            e if e.intensity is None else replace(e, intensity=tuple(v / top for v in e.intensity))  # type: ignore[arg-type]
            for e in estimates
        ]
    return estimates


def _format_direction(direction: Sequence[float]) -> str:
    return "(" + ", ".join(f"{v:+.4f}" for v in direction) + ")"


# --- the lights file ----------------------------------------------------------------------------

_TOML_ESCAPES = {'"': '\\"', "\\": "\\\\", "\b": "\\b", "\t": "\\t", "\n": "\\n", "\f": "\\f", "\r": "\\r"}


def toml_string(text: str) -> str:
    """``text`` as a TOML basic string: quotes, backslashes and control characters escaped
    (\\uXXXX where TOML has no short escape). A lone surrogate (a file name that is not
    valid UTF-8) cannot be written and is a `CaptureError`."""
    out = ['"']
    for char in text:
        code = ord(char)
        if 0xD800 <= code <= 0xDFFF:
            raise CaptureError(
                f"the name {text.encode('utf-8', 'backslashreplace').decode()!r} is not valid UTF-8: "
                "TOML cannot hold it"
            )
        if char in _TOML_ESCAPES:
            out.append(_TOML_ESCAPES[char])
        elif code < 0x20 or code == 0x7F:
            out.append(f"\\u{code:04X}")
        else:
            out.append(char)
    out.append('"')
    return "".join(out)


def _toml_float(value: float) -> str:
    """A finite float as TOML writes it (Python's shortest repr: ``0.1``, ``1e-07``)."""
    value = float(value)
    if not math.isfinite(value):
        raise CaptureError(f"cannot write {value} in a lights file")
    return repr(value)


def lights_toml(
    estimates: Sequence[LightEstimate], files: Sequence[str], circle: Circle, camera: Camera | None = None
) -> str:
    """The lights file of docs/captures.md: per image an ``[[image]]`` table with ``file``
    and one ``[[image.light]]`` with ``direction``, ``direction_sd_deg`` and, when known,
    ``intensity``. The mirror ball's circle and camera are recorded in comment lines only
    (the file describes lights; the ball is not the sample)."""
    camera = camera or Camera()
    if len(estimates) != len(files):
        raise CaptureError(f"{len(estimates)} light estimates for {len(files)} files")
    camera_text = f"{camera.kind} camera"
    if camera.perspective:
        camera_text += f" (focal length {camera.focal_px:g} px"
        if camera.principal_point is not None:
            camera_text += f", principal point ({camera.principal_point[0]:g}, {camera.principal_point[1]:g})"
        camera_text += ")"
    source = {"mask": "from the mask", "image": "from the images", "given": "given"}[circle.source]
    lines = [
        "# Lights measured on a mirror ball by strauss-fit lights (docs/captures.md).",
        f"# Mirror ball: {camera_text}; {circle.describe()}, {source}.",
        "# direction: toward the light, camera frame (+x right, +y up, +z toward the camera);",
        "# direction_sd_deg: its angular standard deviation; intensity: relative, the largest channel",
        "# of the brightest light = 1 (absent where the highlight is saturated).",
    ]
    for estimate, file in zip(estimates, files):
        lines += ["", "[[image]]", f"file = {toml_string(str(file))}", "[[image.light]]"]
        lines.append("direction = [" + ", ".join(_toml_float(round(v, 7)) for v in estimate.direction) + "]")
        lines.append(f"direction_sd_deg = {_toml_float(float(f'{estimate.direction_sd_deg:.3g}'))}")
        if estimate.intensity is not None:
            lines.append("intensity = [" + ", ".join(_toml_float(float(f"{v:.5g}")) for v in estimate.intensity) + "]")
        for note in estimate.notes:
            lines.append("# note: " + note.replace("\n", " ").replace("\r", " "))
    return "\n".join(lines) + "\n"
