"""Lights from a mirror ball (strauss_fit.capture._mirror) and ``strauss-fit lights``.

The chrome balls are ray-cast here: per sub-sample (4 × 4 per pixel) the view ray is
reflected at the sphere, and a light of intensity I and angular radius δ adds I where the
reflected ray lies within δ of its direction; a dim environment, a dark background and
noise complete the photograph."""

from __future__ import annotations

import argparse
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from strauss_fit.capture._mirror import estimate_light, estimate_lights, lights_toml, toml_string
from strauss_fit.capture._sphere import Camera, CaptureError, Circle, circle_from_images, circle_from_mask
from strauss_fit.errors import StraussFitError
from strauss_fit.io.images import write_image

SHAPE = (200, 260)
CENTRE, RADIUS = (131.3, 97.6), 80.4


def _subsamples(height: int, width: int, ss: int) -> tuple[np.ndarray, np.ndarray]:
    offsets = (np.arange(ss) + 0.5) / ss
    y = (np.arange(height)[:, None] + offsets[None, :]).ravel()
    x = (np.arange(width)[:, None] + offsets[None, :]).ravel()
    return np.meshgrid(x, y)


def _box(values: np.ndarray, height: int, width: int, ss: int) -> np.ndarray:
    return values.reshape(height, ss, width, ss, *values.shape[2:]).mean(axis=(1, 3))


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def toward(polar_deg: float, azimuth_deg: float) -> np.ndarray:
    """The unit direction polar_deg from the view axis +z, at azimuth_deg from +x."""
    t, p = math.radians(polar_deg), math.radians(azimuth_deg)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


def _shade(hit, normals, views, lights, radius_deg, environment, background, noise, seed, shape, ss):
    reflected = 2.0 * np.sum(normals * views, axis=-1, keepdims=True) * normals - views
    image = np.where(hit[..., None], environment, background) * np.ones(3)
    cos_delta = math.cos(math.radians(radius_deg))
    for direction, rgb in lights:
        image = image + (hit & (reflected @ _unit(direction) > cos_delta))[..., None] * np.asarray(rgb, float)
    image = _box(image, *shape, ss)
    return image + noise * np.random.default_rng(seed).standard_normal(image.shape)


def chrome(lights, *, radius_deg=3.0, environment=0.05, background=0.01, noise=0.005, seed=0, ss=4):
    """An orthographic chrome ball at CENTRE, RADIUS in a SHAPE frame."""
    height, width = SHAPE
    x, y = _subsamples(height, width, ss)
    nx, ny = (x - CENTRE[0]) / RADIUS, -(y - CENTRE[1]) / RADIUS
    hit = nx * nx + ny * ny < 1
    normals = np.stack([nx, ny, np.sqrt(np.maximum(0.0, 1 - nx * nx - ny * ny))], axis=-1)
    views = np.broadcast_to(np.array([0.0, 0.0, 1.0]), normals.shape)
    return _shade(hit, normals, views, lights, radius_deg, environment, background, noise, seed, SHAPE, ss)


def chrome_perspective(shape, focal, centre, lights, *, radius_deg=3.0, noise=0.005, seed=0, ss=4):
    """A perspective chrome ball of radius 1 at ``centre``: rays from the origin through the
    sub-samples meet it by the quadratic formula."""
    height, width = shape
    x, y = _subsamples(height, width, ss)
    w = np.stack([(x - width / 2) / focal, -(y - height / 2) / focal, -np.ones_like(x)], axis=-1)
    w /= np.linalg.norm(w, axis=-1, keepdims=True)
    c = np.asarray(centre, float)
    b = -2.0 * (w @ c)
    disc = b * b - 4 * (c @ c - 1.0)
    t = (-b - np.sqrt(np.maximum(disc, 0.0))) / 2
    normals = t[..., None] * w - c
    return _shade(disc > 0, normals, -w, lights, radius_deg, 0.05, 0.01, noise, seed, shape, ss), disc > 0


def _disc_mask() -> np.ndarray:
    height, width = SHAPE
    x, y = _subsamples(height, width, 8)
    return _box(((x - CENTRE[0]) ** 2 + (y - CENTRE[1]) ** 2 < RADIUS**2).astype(float), height, width, 8) >= 0.5


def _angle_deg(a, b) -> float:
    a, b = _unit(a), _unit(b)
    return math.degrees(math.atan2(np.linalg.norm(np.cross(a, b)), a @ b))


HEMISPHERE = [(0, 0), (10, 30), (25, 100), (40, 200), (50, 320), (60, 45), (60, 135), (60, 250)]


@pytest.fixture(scope="module")
def ball() -> Circle:
    return circle_from_mask(_disc_mask())


@pytest.mark.parametrize("polar, azimuth", HEMISPHERE)
def test_directions_within_half_a_degree(ball: Circle, polar: float, azimuth: float) -> None:
    light = toward(polar, azimuth)
    image = chrome([(light, (0.9, 0.7, 0.5))], seed=polar)
    estimate = estimate_light(image, ball)
    assert _angle_deg(estimate.direction, light) < 0.5
    assert 0 < estimate.direction_sd_deg < 0.5
    assert math.isclose(np.linalg.norm(estimate.direction), 1.0, rel_tol=1e-12)
    # the highlight lies where the normal halves the angle between the view and the light
    half = _unit(light + np.array([0.0, 0.0, 1.0]))
    expected = (CENTRE[0] + RADIUS * half[0], CENTRE[1] - RADIUS * half[1])
    assert np.hypot(estimate.pixel[0] - expected[0], estimate.pixel[1] - expected[1]) < 0.5
    assert estimate.notes == ()


@pytest.mark.parametrize("polar, azimuth", [(0, 0), (30, 60), (45, 170), (60, 290)])
def test_directions_with_a_perspective_camera(polar: float, azimuth: float) -> None:
    shape, focal = (240, 320), 450.0
    tilt = math.radians(12)
    u = np.array([math.sin(tilt) * 0.8, -math.sin(tilt) * 0.6, -math.cos(tilt)])
    camera = Camera("perspective", focal)
    light = toward(polar, azimuth)
    image, hit = chrome_perspective(shape, focal, 8.0 * u, [(light, (1.0, 1.0, 1.0))], seed=polar)
    circle = circle_from_mask(hit.reshape(shape[0], 4, shape[1], 4).mean(axis=(1, 3)) >= 0.5, camera)
    estimate = estimate_light(image, circle, camera)
    assert _angle_deg(estimate.direction, light) < 0.5
    assert estimate.intensity is not None


def test_the_ball_found_in_the_images(ball: Circle) -> None:
    """A ball reflecting a dim room stands out from a darker background: no mask needed."""
    images = [chrome([(toward(p, a), (1.0, 1.0, 1.0))], seed=k) for k, (p, a) in enumerate(HEMISPHERE[:4])]
    found = circle_from_images(images)
    assert abs(found.center[0] - CENTRE[0]) < 0.3 and abs(found.center[1] - CENTRE[1]) < 0.3
    assert abs(found.radius - RADIUS) < 0.3
    for image, (p, a) in zip(images, HEMISPHERE[:4]):
        assert _angle_deg(estimate_light(image, found).direction, toward(p, a)) < 0.5


def test_relative_intensities(ball: Circle) -> None:
    """The highlight's sum × 4/r² is the light's intensity × solid angle (orthographic)."""
    rgb = [(1.0, 0.8, 0.6), (0.3, 0.5, 0.45), (0.7, 0.7, 0.2)]
    radius_deg = 3.0
    solid_angle = 2 * math.pi * (1 - math.cos(math.radians(radius_deg)))
    estimates = [
        estimate_light(chrome([(toward(p, a), c)], radius_deg=radius_deg, seed=k), ball)
        for k, ((p, a), c) in enumerate(zip([(5, 0), (35, 80), (55, 200)], rgb))
    ]
    for estimate, c in zip(estimates, rgb):
        assert estimate.intensity is not None
        assert np.allclose(np.asarray(estimate.intensity) / solid_angle, c, rtol=0.03, atol=0.01)


def test_saturated_highlight_has_no_intensity(ball: Circle) -> None:
    image = np.clip(chrome([(toward(20, 40), (3.0, 3.0, 3.0))]), 0.0, 1.0)
    estimate = estimate_light(image, ball, saturation=1.0)
    assert estimate.intensity is None and estimate.saturated_pixels > 0
    assert any("saturated" in note for note in estimate.notes)
    assert _angle_deg(estimate.direction, toward(20, 40)) < 0.5  # a clipped core is still centred


def test_no_highlight_is_one_line(ball: Circle) -> None:
    with pytest.raises(CaptureError) as exc:
        estimate_light(np.full(SHAPE + (3,), 0.05), ball)
    assert "no highlight" in str(exc.value) and "\n" not in str(exc.value)
    with pytest.raises(CaptureError) as exc:
        estimate_light(chrome([]), ball)
    assert "no highlight" in str(exc.value)


def _write_set(folder: Path, lights, *, clip: bool = False) -> list[Path]:
    paths = []
    for k, (direction, rgb) in enumerate(lights):
        image = chrome([(direction, rgb)], seed=10 + k)
        path = folder / f"chrome {k}.exr"
        write_image(path, np.clip(image, 0, 1) if clip else image.astype(np.float32))
        paths.append(path)
    return paths


def _write_mask(folder: Path) -> Path:
    path = folder / "mask.png"
    write_image(path, np.repeat(_disc_mask()[..., None], 3, axis=-1).astype(float), encoding="linear")
    return path


LIGHT_SET = [(toward(10, 20), (1.0, 0.9, 0.8)), (toward(40, 150), (0.5, 0.5, 0.5)), (toward(55, 260), (0.2, 0.3, 0.4))]


def test_estimate_lights_from_files(tmp_path: Path) -> None:
    paths = _write_set(tmp_path, LIGHT_SET)
    mask = _write_mask(tmp_path)
    estimates = estimate_lights(paths, mask_path=mask)
    assert len(estimates) == 3
    assert max(max(e.intensity) for e in estimates) == pytest.approx(1.0)
    for estimate, (direction, rgb) in zip(estimates, LIGHT_SET):
        assert _angle_deg(estimate.direction, direction) < 0.5
        assert np.allclose(estimate.intensity, np.asarray(rgb) / 1.0, rtol=0.03, atol=0.01)
        assert estimate.circle is not None and estimate.circle.source == "mask"
    # a given circle, and the images alone, give the same lights
    given = estimate_lights(paths, circle=Circle(CENTRE, RADIUS))
    found = estimate_lights(paths)
    for a, b, c in zip(estimates, given, found):
        assert _angle_deg(a.direction, b.direction) < 0.1 and _angle_deg(a.direction, c.direction) < 0.1


def test_estimate_lights_errors_name_the_file(tmp_path: Path) -> None:
    paths = _write_set(tmp_path, LIGHT_SET[:1])
    dark = tmp_path / "dark.exr"
    write_image(dark, np.full(SHAPE + (3,), 0.05, dtype=np.float32))
    with pytest.raises(CaptureError) as exc:
        estimate_lights([*paths, dark], circle=Circle(CENTRE, RADIUS))
    assert "dark.exr" in str(exc.value) and "no highlight" in str(exc.value)
    empty = tmp_path / "empty.png"
    write_image(empty, np.zeros(SHAPE + (3,)), encoding="linear")
    with pytest.raises(CaptureError) as exc:
        estimate_lights(paths, mask_path=empty)
    assert "nothing in it" in str(exc.value)
    small = tmp_path / "small.exr"
    write_image(small, np.zeros((20, 30, 3), dtype=np.float32))
    with pytest.raises(CaptureError) as exc:
        estimate_lights([*paths, small], circle=Circle(CENTRE, RADIUS))
    assert "30×20" in str(exc.value)
    with pytest.raises(CaptureError) as exc:
        estimate_lights(paths, circle=Circle((20.0, 30.0), 50.0))
    assert "cut by the frame" in str(exc.value)


def test_saturated_files_have_no_intensity(tmp_path: Path) -> None:
    paths = []
    for k, strength in enumerate((0.5, 30.0)):
        path = tmp_path / f"{k}.png"
        image = chrome([(toward(30, 90 * k), (strength,) * 3)], seed=k)
        write_image(path, np.clip(image, 0, 1), encoding="linear")
        paths.append(path)
    estimates = estimate_lights(paths, circle=Circle(CENTRE, RADIUS))
    assert estimates[0].intensity is not None and max(estimates[0].intensity) == pytest.approx(1.0)
    assert estimates[1].intensity is None


def test_lights_file_round_trips_and_escapes_names(ball: Circle) -> None:
    estimates = [estimate_light(chrome([(d, c)]), ball) for d, c in LIGHT_SET[:2]]
    estimates[1] = estimates[1].__class__(**{**estimates[1].__dict__, "intensity": None})
    names = ['odd "name"\\with\nnewline.exr', "tab\tand\x01control\x7f.exr"]
    text = lights_toml(estimates, names, ball, Camera())
    data = tomllib.loads(text)
    assert set(data) == {"image"}  # lights only: the ball is in comments
    assert "circle centre (131." in text
    assert [image["file"] for image in data["image"]] == names
    first, second = (image["light"] for image in data["image"])
    assert len(first) == len(second) == 1
    assert np.allclose(first[0]["direction"], estimates[0].direction, atol=1e-6)
    assert first[0]["direction_sd_deg"] == pytest.approx(estimates[0].direction_sd_deg, rel=1e-2)
    assert "intensity" in first[0] and "intensity" not in second[0]
    assert toml_string("a\u2028b") == '"a\u2028b"'
    with pytest.raises(CaptureError):
        toml_string("bad\udcffname")
    with pytest.raises(CaptureError):
        lights_toml(estimates, names[:1], ball)


def test_with_the_capture_generator(tmp_path: Path) -> None:
    """Cross-check on data_synth.capture's chrome renders (its own ray caster), when present."""
    capture = pytest.importorskip("data_synth.capture")
    spec = capture.example_capture_spec("chrome", lights=capture._plastic_lights()[:4])
    capture.write_capture(spec, tmp_path / "ball")
    manifest = tomllib.loads((tmp_path / "ball" / "capture.toml").read_text())
    files = [tmp_path / "ball" / image["file"] for image in manifest["image"]]
    estimates = estimate_lights(files, mask_path=tmp_path / "ball" / manifest["capture"]["mask"])
    truth = np.array([image["light"][0]["intensity"] for image in manifest["image"]], dtype=float)
    truth /= truth.max()
    for estimate, image, expected in zip(estimates, manifest["image"], truth):
        assert _angle_deg(estimate.direction, image["light"][0]["direction"]) < 0.5
        assert np.allclose(estimate.intensity, expected, rtol=0.03)


# --- the command ------------------------------------------------------------------------------


def _run(argv: list[str]) -> int:
    from strauss_fit_cli import lights_cmd

    parser = argparse.ArgumentParser(prog="strauss-fit")
    lights_cmd.add_parser(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["lights", *argv])
    return args.run(args)


def test_lights_command(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    paths = _write_set(tmp_path, LIGHT_SET)
    mask = _write_mask(tmp_path)
    out = tmp_path / "lights.toml"
    assert _run([*map(str, paths), "--mask", str(mask), "-o", str(out)]) == 0
    printed = capsys.readouterr()
    assert "direction (x, y, z)" in printed.out and "chrome 0.exr" in printed.out and "wrote" in printed.out
    assert "mirror ball: circle centre" in printed.err
    data = tomllib.loads(out.read_text())
    assert [image["file"] for image in data["image"]] == ["chrome 0.exr", "chrome 1.exr", "chrome 2.exr"]
    for image, (direction, _) in zip(data["image"], LIGHT_SET):
        assert _angle_deg(image["light"][0]["direction"], direction) < 0.5
    # an existing output needs --force; --quiet prints no progress
    with pytest.raises(StraussFitError, match="exists"):
        _run([str(paths[0]), "-o", str(out), "--circle", str(CENTRE[0]), str(CENTRE[1]), str(RADIUS)])
    assert _run([str(paths[0]), "-o", str(out), "--circle", *map(str, (*CENTRE, RADIUS)), "--force", "--quiet"]) == 0
    assert capsys.readouterr().err == ""
    assert len(tomllib.loads(out.read_text())["image"]) == 1


def test_lights_command_refuses_bad_requests(tmp_path: Path) -> None:
    paths = _write_set(tmp_path, LIGHT_SET[:1])
    out = tmp_path / "lights.toml"
    cases = [
        ([str(paths[0]), "-o", str(paths[0]), "--force"], "is the input"),
        ([str(paths[0]), "-o", str(out), "--camera", "perspective"], "--focal-px"),
        ([str(paths[0]), "-o", str(out), "--focal-px", "500"], "perspective only"),
        ([str(paths[0]), "-o", str(out), "--circle", "10", "10", "-3"], "radius must be > 0"),
        ([str(paths[0]), "-o", str(out), "--saturation", "2"], "(0, 1]"),
        ([str(tmp_path / "missing.exr"), "-o", str(out)], "not found"),
    ]
    for argv, message in cases:
        with pytest.raises(StraussFitError) as exc:
            _run(argv)
        assert message in str(exc.value) and "\n" not in str(exc.value)
    assert not out.exists()
