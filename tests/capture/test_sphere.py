"""The sphere found in the frame (strauss_fit.capture._sphere): circles and cones from masks
and from images, their standard deviations, the normals of the sphere's pixels, and the
one-line errors. Every image is made here, analytically: supersampled anti-aliased discs,
Lambertian spheres (orthographic and perspective, ray-cast independently of the library)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from strauss_fit.capture._sphere import (
    Camera,
    CaptureError,
    Circle,
    check_in_frame,
    circle_from_images,
    circle_from_mask,
    sphere_geometry,
    surface_at,
)
from strauss_fit.errors import StraussFitError

# --- synthetic images ---------------------------------------------------------------------------


def _subsamples(height: int, width: int, ss: int) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel sample positions (height·ss, width·ss): x = k + (a + ½)/ss, y = i + (b + ½)/ss."""
    offsets = (np.arange(ss) + 0.5) / ss
    y = (np.arange(height)[:, None] + offsets[None, :]).ravel()
    x = (np.arange(width)[:, None] + offsets[None, :]).ravel()
    return np.meshgrid(x, y)


def _box(values: np.ndarray, height: int, width: int, ss: int) -> np.ndarray:
    """Average ss × ss sub-samples into pixels (a box filter)."""
    return values.reshape(height, ss, width, ss, *values.shape[2:]).mean(axis=(1, 3))


def disc_coverage(height: int, width: int, cx: float, cy: float, r: float, ss: int = 8) -> np.ndarray:
    x, y = _subsamples(height, width, ss)
    return _box(((x - cx) ** 2 + (y - cy) ** 2 < r * r).astype(float), height, width, ss)


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def lambert_images(
    shape, cx, cy, r, lights, *, albedo=0.8, background=0.02, noise=0.0, seed=0, ss=4
) -> list[np.ndarray]:
    """Orthographic Lambertian sphere renders, box-filtered from ss × ss samples, with noise."""
    height, width = shape
    x, y = _subsamples(height, width, ss)
    nx, ny = (x - cx) / r, -(y - cy) / r
    inside = nx * nx + ny * ny < 1
    nz = np.sqrt(np.maximum(0.0, 1 - nx * nx - ny * ny))
    rng = np.random.default_rng(seed)
    images = []
    for light in lights:
        l = _unit(light)
        shade = np.where(inside, albedo * np.maximum(0.0, nx * l[0] + ny * l[1] + nz * l[2]), background)
        image = _box(shade, height, width, ss) + noise * rng.standard_normal((height, width))
        images.append(np.repeat(image[..., None], 3, axis=-1))
    return images


def perspective_rays(height, width, focal, ss, principal=None) -> np.ndarray:
    px, py = principal if principal is not None else (width / 2, height / 2)
    x, y = _subsamples(height, width, ss)
    w = np.stack([(x - px) / focal, -(y - py) / focal, -np.ones_like(x)], axis=-1)
    return w / np.linalg.norm(w, axis=-1, keepdims=True)


def ray_sphere(w: np.ndarray, centre: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Hit mask and unit normals of rays from the origin along w: |t w − C|² = R², the
    smaller root of t² − 2 t (w·C) + |C|² − R² = 0 by the quadratic formula."""
    b = -2.0 * (w @ centre)
    c = centre @ centre - radius * radius
    disc = b * b - 4 * c
    t = (-b - np.sqrt(np.maximum(disc, 0.0))) / 2
    return disc > 0, (t[..., None] * w - centre) / radius


def perspective_coverage(shape, focal, centre, radius, ss=8) -> np.ndarray:
    hit, _ = ray_sphere(perspective_rays(*shape, focal, ss), np.asarray(centre, float), radius)
    return _box(hit.astype(float), *shape, ss)


def perspective_lambert(shape, focal, centre, radius, lights, *, noise=0.0, seed=0, ss=4) -> list[np.ndarray]:
    hit, n = ray_sphere(perspective_rays(*shape, focal, ss), np.asarray(centre, float), radius)
    rng = np.random.default_rng(seed)
    images = []
    for light in lights:
        shade = np.where(hit, 0.8 * np.maximum(0.0, n @ _unit(light)), 0.02)
        image = _box(shade, *shape, ss) + noise * rng.standard_normal(shape)
        images.append(np.repeat(image[..., None], 3, axis=-1))
    return images


AROUND = [(0.5, 0.3, 0.8), (-0.5, 0.4, 0.8), (0.0, -0.6, 0.8), (0.1, 0.1, 1.0)]


def _angle_deg(a, b) -> float:
    a, b = _unit(a), _unit(b)
    return math.degrees(math.atan2(np.linalg.norm(np.cross(a, b)), a @ b))


# --- the circle -------------------------------------------------------------------------------


def test_circle_from_mask_off_centre_in_a_larger_frame() -> None:
    cx, cy, r = 171.37, 88.62, 54.3
    mask = disc_coverage(180, 260, cx, cy, r) >= 0.5
    # specks elsewhere and a hole inside change nothing
    mask[5:8, 5:8] = True
    mask[150, 20] = True
    mask[85:90, 170:175] = False
    circle = circle_from_mask(mask)
    assert abs(circle.center[0] - cx) < 0.3 and abs(circle.center[1] - cy) < 0.3
    assert abs(circle.radius - r) < 0.3
    assert circle.source == "mask" and not circle.has_cone
    assert 0 < circle.center_sd[0] < 0.1 and 0 < circle.radius_sd < 0.1


def test_circle_from_mask_takes_numbers_and_ignores_a_bite() -> None:
    """A grey (anti-aliased) mask is cut at half its maximum; a stand that hides part of the
    sphere (a bite out of the outline) is left out of the fit."""
    cx, cy, r = 120.4, 101.7, 70.2
    coverage = disc_coverage(220, 240, cx, cy, r)
    bitten = coverage.copy()
    bitten[160:, 100:140] = 0.0  # the stand's notch at the bottom
    circle = circle_from_mask(np.round(255 * bitten))
    assert abs(circle.center[0] - cx) < 0.3 and abs(circle.center[1] - cy) < 0.3 and abs(circle.radius - r) < 0.3
    assert circle.points_used < circle.points_total


@pytest.mark.parametrize("noise", [0.0, 0.02])
def test_circle_from_images_lit_from_around(noise: float) -> None:
    cx, cy, r = 143.3, 97.8, 61.7
    images = lambert_images((200, 300), cx, cy, r, AROUND, noise=noise, seed=3)
    circle = circle_from_images(images)
    assert abs(circle.center[0] - cx) < 0.3 and abs(circle.center[1] - cy) < 0.3
    assert abs(circle.radius - r) < 0.3
    assert circle.source == "image"


@pytest.mark.parametrize("light", [(0.87, 0.0, 0.5), (-0.6, 0.6, 0.5), (0.2, -0.7, 0.7)])
def test_circle_from_images_of_a_lit_crescent(light) -> None:
    """One light from the side: only a crescent is lit; the terminator's points drop out."""
    cx, cy, r = 131.6, 104.2, 58.9
    images = lambert_images((210, 280), cx, cy, r, [light], noise=0.01, seed=5)
    circle = circle_from_images(images)
    assert abs(circle.center[0] - cx) < 0.3 and abs(circle.center[1] - cy) < 0.3
    assert abs(circle.radius - r) < 0.3
    assert circle.points_used < 0.8 * circle.points_total  # the terminator was left out


def test_reported_centre_deviation_is_honest() -> None:
    """Over 20 noise draws (and sub-pixel positions), the centre's error lies within 3 sd
    in at least 90 % of them."""
    rng = np.random.default_rng(11)
    within = 0
    draws = 20
    for seed in range(draws):
        cx, cy, r = 60 + rng.uniform(0, 1), 50 + rng.uniform(0, 1), 30 + rng.uniform(0, 1)
        images = lambert_images((100, 128), cx, cy, r, AROUND[:3], noise=0.03, seed=seed)
        circle = circle_from_images(images)
        ok = (
            abs(circle.center[0] - cx) <= 3 * circle.center_sd[0]
            and abs(circle.center[1] - cy) <= 3 * circle.center_sd[1]
        )
        within += ok
    assert within >= 0.9 * draws


def test_perspective_cone_from_mask_and_from_images() -> None:
    shape, focal = (240, 320), 400.0
    tilt = math.radians(15)
    u = np.array([math.sin(tilt) * 0.8, math.sin(tilt) * 0.6, -math.cos(tilt)])
    centre = 10.0 * u
    camera = Camera("perspective", focal)
    rho = math.asin(1.0 / 10.0)
    mask = perspective_coverage(shape, focal, centre, 1.0) >= 0.5
    circle = circle_from_mask(mask, camera)
    assert circle.has_cone
    assert _angle_deg(circle.direction, u) < 0.02
    assert abs(circle.angular_radius - rho) < math.radians(0.02)
    assert 0 < circle.direction_sd < math.radians(0.02)
    images = perspective_lambert(shape, focal, centre, 1.0, AROUND, noise=0.01, seed=2)
    found = circle_from_images(images, camera)
    assert _angle_deg(found.direction, u) < 0.05
    assert abs(found.angular_radius - rho) < math.radians(0.05)


# --- errors -----------------------------------------------------------------------------------


def _one_line(exc: pytest.ExceptionInfo) -> str:
    message = str(exc.value)
    assert "\n" not in message and message
    assert isinstance(exc.value, StraussFitError)
    return message


def test_no_sphere_in_an_empty_or_noisy_image() -> None:
    with pytest.raises(CaptureError) as exc:
        circle_from_images([np.zeros((60, 80, 3))])
    assert "no sphere found" in _one_line(exc)
    rng = np.random.default_rng(0)
    with pytest.raises(CaptureError) as exc:
        circle_from_images([0.1 + 0.01 * rng.standard_normal((60, 80, 3)) for _ in range(3)])
    assert "no sphere found" in _one_line(exc)
    with pytest.raises(CaptureError) as exc:
        circle_from_images([])
    _one_line(exc)


def test_a_mask_with_nothing_in_it() -> None:
    with pytest.raises(CaptureError) as exc:
        circle_from_mask(np.zeros((50, 70), dtype=bool))
    assert "nothing in it" in _one_line(exc) and "70×50" in str(exc.value)
    with pytest.raises(CaptureError) as exc:
        circle_from_mask(np.pad(np.ones((3, 3), dtype=bool), 20))
    assert "too small" in _one_line(exc)


@pytest.mark.parametrize(
    "cx, cy, r",
    [(20.0, 60.0, 35.0), (150.0, 100.0, 40.0), (85.0, 60.0, 64.0)],  # cut left; cut bottom-right; cut at top and bottom
)
def test_a_sphere_cut_by_the_frame(cx: float, cy: float, r: float) -> None:
    shape = (120, 170)
    with pytest.raises(CaptureError) as exc:
        circle_from_mask(disc_coverage(*shape, cx, cy, r) >= 0.5)
    message = _one_line(exc)
    assert "cut by the frame" in message and "170×120" in message
    with pytest.raises(CaptureError) as exc:
        circle_from_images(lambert_images(shape, cx, cy, r, AROUND))
    assert "cut by the frame" in _one_line(exc)


def test_a_perspective_sphere_cut_by_the_frame() -> None:
    shape, focal = (200, 260), 300.0
    u = _unit((0.15, 0.1, -1.0))
    camera = Camera("perspective", focal)
    inside = Circle((0.0, 0.0), 1.0, direction=tuple(u), angular_radius=math.radians(8))
    check_in_frame(inside, shape, camera)
    cut = Circle((0.0, 0.0), 1.0, direction=tuple(u), angular_radius=math.radians(16))
    with pytest.raises(CaptureError) as exc:
        check_in_frame(cut, shape, camera)
    assert "ellipse" in _one_line(exc) and "260×200" in str(exc.value)
    with pytest.raises(CaptureError) as exc:
        sphere_geometry(cut, shape, camera)
    assert "cut by the frame" in _one_line(exc)
    assert sphere_geometry(cut, shape, camera, clip=True).count > 0


def test_camera_and_circle_are_validated() -> None:
    for kwargs in (
        dict(kind="fisheye"),
        dict(kind="perspective"),
        dict(kind="perspective", focal_px=0.0),
        dict(kind="perspective", focal_px=float("nan")),
        dict(kind="perspective", focal_px=100.0, principal_point=(1.0,)),
    ):
        with pytest.raises(CaptureError) as exc:
            Camera(**kwargs)
        _one_line(exc)
    for kwargs in (
        dict(center=(1.0, 2.0), radius=0.0),
        dict(center=(1.0, float("inf")), radius=3.0),
        dict(center=(1.0, 2.0), radius=3.0, source="guess"),
        dict(center=(1.0, 2.0), radius=3.0, direction=(0.0, 0.0, -1.0)),
        dict(center=(1.0, 2.0), radius=3.0, direction=(0.0, 0.0, 0.0), angular_radius=0.1),
        dict(center=(1.0, 2.0), radius=3.0, direction=(0.0, 0.0, -1.0), angular_radius=2.0),
    ):
        with pytest.raises(CaptureError) as exc:
            Circle(**kwargs)
        _one_line(exc)


def test_circle_round_trips_through_json() -> None:
    circle = Circle(
        (10.5, 20.25),
        7.0,
        (0.01, 0.02),
        0.03,
        "image",
        direction=(0.1, 0.2, -0.97),
        angular_radius=0.1,
        direction_sd=1e-4,
        angular_radius_sd=2e-4,
        points_used=40,
        points_total=50,
    )
    data = json.loads(json.dumps(circle.to_dict()))
    back = Circle.from_dict(data)
    assert back.center == circle.center and back.radius == circle.radius and back.source == "image"
    assert np.allclose(back.direction, circle.direction) and math.isclose(back.angular_radius, 0.1)
    assert math.isclose(back.direction_sd, 1e-4) and back.points_used == 40
    assert Circle.from_dict({"center": [1, 2], "radius": 3}).source == "given"
    with pytest.raises(CaptureError):
        Circle.from_dict({"center": [1, 2]})
    with pytest.raises(CaptureError):
        Circle.from_dict({"center": [1, 2], "radius": 3, "colour": 1})
    camera = Camera("perspective", 500.0, (10.0, 20.0))
    assert Camera.from_dict(json.loads(json.dumps(camera.to_dict()))) == camera


# --- the sphere's pixels --------------------------------------------------------------------


def test_orthographic_geometry_matches_the_formula() -> None:
    shape = (90, 130)
    cx, cy, r = 70.3, 41.8, 30.6
    circle = Circle((cx, cy), r)
    geometry = sphere_geometry(circle, shape)
    rows, cols = np.mgrid[0 : shape[0], 0 : shape[1]]
    inside = np.hypot(cols + 0.5 - cx, rows + 0.5 - cy) < r
    assert geometry.count == inside.sum()
    assert inside[geometry.rows, geometry.cols].all()
    x, y = geometry.cols + 0.5, geometry.rows + 0.5
    nx, ny = (x - cx) / r, -(y - cy) / r
    expected = np.stack([nx, ny, np.sqrt(1 - nx**2 - ny**2)], axis=-1)
    assert geometry.normals.dtype == np.float64
    assert np.abs(geometry.normals - expected).max() < 1e-12
    assert np.all(geometry.views == np.array([0.0, 0.0, 1.0]))
    inner = sphere_geometry(circle, shape, margin=2.0)
    assert np.all(np.hypot(inner.cols + 0.5 - cx, inner.rows + 0.5 - cy) < r - 2.0)
    assert inner.count == (np.hypot(cols + 0.5 - cx, rows + 0.5 - cy) < r - 2.0).sum()


def test_perspective_geometry_matches_an_independent_ray_cast() -> None:
    shape, focal = (160, 220), 260.0
    principal = (100.0, 90.0)
    camera = Camera("perspective", focal, principal)
    u = _unit((-0.15, 0.1, -1.0))
    rho = math.radians(8.0)
    distance = 3.0 / math.sin(rho)  # any scale: a sphere of radius 3
    circle = Circle((0.0, 0.0), 1.0, direction=tuple(u), angular_radius=rho)
    geometry = sphere_geometry(circle, shape, camera)
    w = perspective_rays(*shape, focal, 1, principal).reshape(*shape, 3)
    hit, normals = ray_sphere(w, distance * u, 3.0)
    # every pixel whose centre ray meets the sphere, except rays within rounding of the rim
    assert hit[geometry.rows, geometry.cols].all()
    assert abs(int(hit.sum()) - geometry.count) <= 2
    assert np.abs(geometry.normals - normals[geometry.rows, geometry.cols]).max() < 1e-9
    assert np.abs(geometry.views + w[geometry.rows, geometry.cols]).max() < 1e-12
    # the margin keeps pixels whose neighbourhood lies inside
    inner = sphere_geometry(circle, shape, camera, margin=3.0)
    assert 0 < inner.count < geometry.count
    offsets = [(3 * math.cos(a), 3 * math.sin(a)) for a in np.linspace(0, 2 * math.pi, 7)]
    for dx, dy in offsets:
        rays = camera.rays(inner.cols + 0.5 + dx, inner.rows + 0.5 + dy, shape)
        assert np.all(rays @ u > math.cos(rho) - 1e-9)


def test_surface_at_sub_pixel_points() -> None:
    circle = Circle((50.0, 40.0), 20.0)
    n, v = surface_at(np.array([50.0, 70.0]), np.array([30.0, 40.0]), circle, Camera(), (80, 100))
    assert np.allclose(n[0], [0.0, 0.5, math.sqrt(0.75)])
    assert np.allclose(n[1], [1.0, 0.0, 0.0])  # beyond the outline: the limb
    assert np.allclose(v, [0.0, 0.0, 1.0])


def test_given_circle_for_a_perspective_camera_gets_a_cone() -> None:
    shape, focal = (200, 300), 350.0
    camera = Camera("perspective", focal)
    u = _unit((0.2, -0.1, -1.0))
    truth = Circle((0.0, 0.0), 1.0, direction=tuple(u), angular_radius=math.radians(10))
    mask = np.zeros(shape, dtype=bool)
    g = sphere_geometry(truth, shape, camera)
    mask[g.rows, g.cols] = True
    found = circle_from_mask(mask, camera)
    given = Circle.given(found.center, found.radius, camera, shape)
    assert given.source == "given" and given.has_cone
    # a circle only approximates the ellipse: the cone is close, not exact
    assert _angle_deg(given.direction, u) < 0.5
    assert abs(math.degrees(given.angular_radius) - 10) < 0.3
    grown = given.grown(5.0)
    assert grown.radius == given.radius + 5.0 and grown.angular_radius > given.angular_radius


def test_a_star_of_glare_is_no_sphere() -> None:
    """A bright blob with spikes (a saturated highlight's glare, what the maximum over
    mirror-ball photographs in a dark room looks like) is refused, not fitted."""
    shape = (160, 200)
    rows, cols = np.mgrid[0 : shape[0], 0 : shape[1]]
    dx, dy = cols + 0.5 - 100.3, rows + 0.5 - 80.6
    image = (np.hypot(dx, dy) < 20).astype(float)
    for angle in np.linspace(0, math.pi, 4, endpoint=False):
        along = dx * math.cos(angle) + dy * math.sin(angle)
        across = -dx * math.sin(angle) + dy * math.cos(angle)
        image[(np.abs(across) < 2.5) & (np.abs(along) < 60)] = 1.0
    with pytest.raises(CaptureError) as exc:
        circle_from_images([image])
    assert "not a sphere" in _one_line(exc)
