"""data_synth.capture: synthetic captures with known truth (images, mask, manifest, truth).

Small frames throughout, so that the module stays fast; the ready-made examples at full
size are exercised through the command line once."""

from __future__ import annotations

import dataclasses
import json
import math
import tomllib
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

import strauss_fit as sf
from data_synth import CaptureSpec, example_capture_spec, render_capture_images, write_capture
from data_synth.capture import MANIFEST_NAME, MASK_NAME, TRUTH_NAME
from data_synth.make_capture import main
from data_synth.params import SpecError
from strauss_fit.io.images import read_image
from strauss_fit.models.material import Material
from strauss_fit.models.strauss import diffuse_reflectivity, shade

#: A small orthographic plastic capture: the "plastic" example's 12 lights on a 96 × 72 frame.
SMALL = {"frame": (96, 72), "center_px": (50.3, 37.6), "radius_px": 24.4}


def read_codes(path: Path) -> np.ndarray:
    """The integer codes of an image file, as stored (H, W, C)."""
    image = oiio.ImageInput.open(str(path))
    spec = image.spec()
    kind = "uint16" if spec.format == oiio.UINT16 else "uint8"
    codes = image.read_image(0, 0, 0, spec.nchannels, kind)
    image.close()
    return np.asarray(codes)


def pixel_centres(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    y, x = np.meshgrid(np.arange(height) + 0.5, np.arange(width) + 0.5, indexing="ij")
    return x, y


def angle_deg(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return math.degrees(math.acos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1.0, 1.0)))


@pytest.fixture(scope="module")
def plastic(tmp_path_factory):
    """The small plastic capture written once: (folder, truth)."""
    folder = tmp_path_factory.mktemp("capture") / "plastic"
    spec = example_capture_spec("plastic", noise_sd=0.001, seed=3, **SMALL)
    return folder, write_capture(spec, folder)


def test_same_seed_same_bytes_other_seed_other_noise(plastic, tmp_path):
    folder, _ = plastic
    spec = example_capture_spec("plastic", noise_sd=0.001, seed=3, **SMALL)
    again = tmp_path / "again"
    write_capture(spec, again)
    names = sorted(p.name for p in folder.iterdir())
    assert names == sorted(p.name for p in again.iterdir())
    assert {MANIFEST_NAME, TRUTH_NAME, MASK_NAME, "001.png", "012.png"} <= set(names)
    for name in names:
        assert (folder / name).read_bytes() == (again / name).read_bytes(), name
    other = tmp_path / "other"
    write_capture(dataclasses.replace(spec, seed=4), other)
    assert (other / "001.png").read_bytes() != (folder / "001.png").read_bytes()
    assert (other / MASK_NAME).read_bytes() == (folder / MASK_NAME).read_bytes()


def test_jpeg_capture_is_reproducible_and_close_to_its_codes(tmp_path):
    spec = example_capture_spec(
        "srgb8", encoding="srgb8-jpeg", frame=(64, 48), center_px=(30.2, 25.1), radius_px=17.0, noise_sd=0.0
    )
    spec = dataclasses.replace(spec, lights=spec.lights[:2], shot_slope=0.0)
    truth = write_capture(spec, tmp_path / "a")
    write_capture(spec, tmp_path / "b")
    assert truth["files"] == ["001.jpg", "002.jpg"] and truth["manifest_encoding"] == "srgb"
    for name in truth["files"]:
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
    images, _, _ = render_capture_images(spec)
    decoded = read_image(tmp_path / "a" / "001.jpg").pixels  # sRGB-decoded
    error = np.abs(np.round(sf.color.srgb_encode(decoded) * 255) - np.round(sf.color.srgb_encode(images[0]) * 255))
    # quality 95, chroma subsampled: about a code on average, more at the silhouette
    assert error.mean() < 2.0 and np.percentile(error, 99) < 10


def test_mask_is_the_analytic_disc(plastic):
    folder, truth = plastic
    x, y = pixel_centres(*SMALL["frame"])
    (cx, cy), r = SMALL["center_px"], SMALL["radius_px"]
    disc = (x - cx) ** 2 + (y - cy) ** 2 < r**2
    stored = read_codes(folder / MASK_NAME)
    assert stored.shape == (72, 96, 1) and set(np.unique(stored)) == {0, 255}
    assert np.array_equal(stored[..., 0] == 255, disc)
    assert truth["mask"] == {"file": MASK_NAME, "pixels": int(disc.sum())}
    assert truth["circle"] == {"center": list(SMALL["center_px"]), "radius": SMALL["radius_px"]}


def test_centre_pixel_is_shade_times_intensity_times_exposure(tmp_path):
    """One sample per pixel, the sphere's centre on a pixel centre: there N = V = (0, 0, 1).
    A directional light along the view axis, and a point light on it 5 radii out (4 from
    the surface: its intensity scaled by (5/4)²)."""
    material = {"color": [0.8, 0.5, 0.3], "smoothness": 0.5, "metalness": 0.4}
    spec = CaptureSpec(
        material=material,
        lights=[
            [{"direction": [0, 0, 2], "intensity": [0.6, 0.5, 0.4]}],
            [{"position": [0, 0, 5], "intensity": [0.3, 0.35, 0.4]}],
        ],
        frame=(81, 61),
        center_px=(40.5, 30.5),
        radius_px=25.0,
        exposure=[0.8, 1.3],
        supersample=1,
    )
    truth = write_capture(spec, tmp_path)
    z = np.array([0.0, 0.0, 1.0])
    with sf.float64():
        unit = np.asarray(shade(Material(**material), z, z, z), dtype=np.float64)
    expected = [unit * [0.6, 0.5, 0.4] * 0.8, unit * [0.3, 0.35, 0.4] * 1.3 * (5 / 4) ** 2]
    for name, value in zip(truth["files"], expected):
        stored = read_image(tmp_path / name, "linear").pixels[30, 40]
        assert np.all(np.abs(stored - value) <= 0.5 / 65535 + 1e-9), (name, stored, value)
        assert np.array_equal(read_codes(tmp_path / name)[30, 40], np.round(value * 65535))
    assert truth["lights"][0][0]["direction"] == [0.0, 0.0, 1.0]  # normalised
    assert truth["exposure"] == [0.8, 1.3]


def test_saturation_happens_and_is_recorded(plastic):
    folder, truth = plastic
    counts = []
    for name in truth["files"]:
        codes = read_codes(folder / name)
        assert codes.dtype == np.uint16
        counts.append(int(np.count_nonzero(np.any(codes == 65535, axis=-1))))
    assert counts == truth["saturated_pixels"]
    assert any(counts) and not all(counts)
    channels = np.array(truth["saturated_channels"])
    assert channels.shape == (12, 3) and channels[:, 0].sum() > 0
    # saturated by the light, not by the noise: exactly the images whose clean peak exceeds 1
    assert [c > 0 for c in counts] == [p > 1.0 for p in truth["peak"]]


def test_manifest_states_files_lights_camera_and_neither_circle_nor_exposure(plastic):
    folder, truth = plastic
    manifest = tomllib.loads((folder / MANIFEST_NAME).read_text())
    assert set(manifest) == {"capture", "image"}
    settings = manifest["capture"]
    assert settings == {"encoding": "linear", "black_level": 0.0, "mask": MASK_NAME, "camera": {"type": "orthographic"}}
    assert [image["file"] for image in manifest["image"]] == truth["files"]
    for image, lights in zip(manifest["image"], truth["lights"]):
        assert set(image) == {"file", "light"}
        assert image["light"] == lights
        assert (folder / image["file"]).is_file()
    assert len({tuple(image["light"][0]["intensity"]) for image in manifest["image"]}) == 12  # coloured
    # the truth file holds what the manifest does not
    stored = json.loads((folder / TRUTH_NAME).read_text())
    assert stored == truth
    assert stored["exposure"] == [1.0] * 12 and stored["material"]["smoothness"] == 0.65
    assert stored["spec"]["seed"] == 3 and stored["camera"] == {"type": "orthographic"}


def test_plastic_example_lights_are_well_conditioned():
    spec = example_capture_spec("plastic")
    assert spec.frame == (320, 240) and spec.camera == "orthographic"
    directions = np.array([lights[0]["direction"] for lights in spec.lights])
    polar = np.degrees(np.arccos(directions[:, 2]))
    assert len(directions) == 12 and polar.max() <= 45.0 and polar.min() < 15.0
    singular = np.linalg.svd(directions, compute_uv=False)
    assert singular.min() / singular.max() > 0.3
    intensities = np.array([lights[0]["intensity"] for lights in spec.lights])
    assert np.all(np.ptp(intensities, axis=1) > 0.05)  # every light coloured


def test_manifest_is_read_by_the_library(plastic, tmp_path):
    """The library's reader (strauss_fit.capture, being written alongside) reads what the
    generator writes; skipped while it is not there."""
    manifest_module = pytest.importorskip("strauss_fit.capture._manifest")
    folder, truth = plastic
    capture = manifest_module.read_capture(folder)
    assert [Path(image.path).name for image in capture.images] == truth["files"]
    assert capture.encoding == "linear" and capture.mask == folder / MASK_NAME and capture.circle is None
    for image, lights in zip(capture.images, truth["lights"]):
        assert np.allclose(image.lights[0].direction, lights[0]["direction"])
        assert np.allclose(image.lights[0].intensity, lights[0]["intensity"])
        assert image.exposure == 1.0
    spec = example_capture_spec("perspective", frame=(80, 60), center_px=(55.0, 20.0), radius_px=10.0, focal_px=70.0)
    write_capture(spec, tmp_path)
    capture = manifest_module.read_capture(tmp_path)
    assert capture.camera.kind == "perspective" and capture.camera.focal_px == 70.0
    assert capture.camera.principal_point == (40.0, 30.0)
    assert capture.images[5].lights[0].position == (4.0, 3.0, 6.0)


def test_black_level_stray_background_and_ambient_in_the_stored_values():
    """A light from the right: the left of the sphere sees only the ambient light."""
    material = {"color": [0.7, 0.5, 0.3], "smoothness": 0.4, "metalness": 0.0}
    ambient, stray, background = (0.1, 0.2, 0.3), (0.01, 0.02, 0.03), (0.04, 0.05, 0.06)
    black, exposure, sd = 0.05, 0.9, 0.001
    spec = CaptureSpec(
        material=material,
        lights=[[{"direction": [1.0, 0.0, 0.05], "intensity": 1.0}]],
        frame=(64, 48),
        center_px=(32.2, 24.1),
        radius_px=16.0,
        exposure=[exposure],
        ambient=ambient,
        stray=stray,
        background=background,
        black_level=black,
        noise_sd=sd,
        seed=5,
    )
    (image,), mask, truth = render_capture_images(spec)
    x, y = pixel_centres(64, 48)
    distance = np.hypot(x - 32.2, y - 24.1)
    far = distance > 16.0 + 2.0
    expected_background = black + np.array(stray) + exposure * np.array(background)
    assert np.all(np.abs(image[far].mean(axis=0) - expected_background) < 5 * sd / math.sqrt(far.sum()))
    assert np.all(np.abs(image[far] - expected_background) < 6 * sd)
    unlit = ((x - 32.2) / 16.0 < -0.3) & (distance < 16.0 - 1.5)
    assert unlit.sum() > 30
    with sf.float64():
        r_d = float(diffuse_reflectivity(Material(**material)))
    expected_unlit = black + np.array(stray) + exposure * np.array(ambient) * r_d * np.array(material["color"])
    assert np.all(np.abs(image[unlit].mean(axis=0) - expected_unlit) < 5 * sd / math.sqrt(unlit.sum()))
    lit = ((x - 32.2) / 16.0 > 0.3) & (distance < 16.0 - 1.5)
    assert np.all(image[lit].mean(axis=0) > expected_unlit + 0.05)
    assert truth["black_level"] == black and truth["stray"] == list(stray) and truth["ambient"] == list(ambient)
    assert truth["noise"]["sd"] == sd


def test_srgb8_stores_srgb_codes_of_the_values(tmp_path):
    spec = example_capture_spec("srgb8", frame=(64, 48), center_px=(30.2, 25.1), radius_px=17.0)
    images, _, truth = render_capture_images(spec)
    write_capture(spec, tmp_path)
    codes = read_codes(tmp_path / "004.png")
    assert codes.dtype == np.uint8
    assert np.array_equal(codes, np.round(sf.color.srgb_encode(images[3]) * 255).astype(np.uint8))
    assert truth["saturated_pixels"][3] == int(np.count_nonzero(np.any(codes == 255, axis=-1))) > 0
    manifest = tomllib.loads((tmp_path / MANIFEST_NAME).read_text())
    assert manifest["capture"]["encoding"] == "srgb" and manifest["capture"]["black_level"] == 0.02


def test_perspective_silhouette_is_an_ellipse_elongated_radially():
    spec = CaptureSpec(
        material={"color": [0.5, 0.5, 0.5], "smoothness": 0.3, "metalness": 0.0},
        lights=[[{"direction": [0, 0, 1]}]],
        frame=(160, 120),
        camera="perspective",
        focal_px=110.0,
        center_px=(128.0, 30.0),
        radius_px=20.0,
        supersample=1,
    )
    _, mask, truth = render_capture_images(spec)
    circle = truth["circle"]
    (a, b), axis = circle["ellipse"]["semi_axes"], np.array(circle["ellipse"]["major_axis"])
    assert circle["off_axis_deg"] > 25 and a > 1.1 * b
    # the cone is what the docs say: u toward the silhouette's centre, sin ρ = R/d
    assert np.allclose(
        np.linalg.norm(circle["sphere_center"]) * math.sin(math.radians(circle["angular_radius_deg"])), 1
    )
    assert circle["center"] == pytest.approx([128.0, 30.0]) and circle["radius"] == pytest.approx(20.0)
    radial = np.array([128.0 - 80.0, 30.0 - 60.0])
    assert angle_deg(axis, radial) < 1e-6
    # the mask's moments: centroid, principal axis and semi-axes of the analytic ellipse
    x, y = pixel_centres(160, 120)
    points = np.stack([x[mask], y[mask]], axis=-1)
    centroid = points.mean(axis=0)
    assert np.allclose(centroid, circle["center"], atol=0.3)
    values, vectors = np.linalg.eigh(np.cov(points.T, bias=True))
    assert min(angle_deg(vectors[:, 1], radial), angle_deg(-vectors[:, 1], radial)) < 2.0
    assert np.allclose(2 * np.sqrt(values[::-1]), [a, b], rtol=0.02)
    assert abs(mask.sum() - math.pi * a * b) < 0.01 * math.pi * a * b
    assert truth["camera"] == {"type": "perspective", "focal_px": 110.0, "principal_point": [80.0, 60.0]}


def test_perspective_centre_pixel_sees_the_sphere_head_on():
    """On the optical axis the ray through the principal point meets the sphere at N = V."""
    material = {"color": [0.3, 0.6, 0.9], "smoothness": 0.6, "metalness": 0.2}
    spec = CaptureSpec(
        material=material,
        lights=[[{"direction": [0, 0, 1], "intensity": 0.7}]],
        frame=(41, 31),
        camera="perspective",
        focal_px=80.0,
        center_px=(20.5, 15.5),
        radius_px=10.0,
        principal_point=(20.5, 15.5),
        supersample=1,
    )
    (image,), _, truth = render_capture_images(spec)
    z = np.array([0.0, 0.0, 1.0])
    with sf.float64():
        expected = np.asarray(shade(Material(**material), z, z, z), dtype=np.float64) * 0.7
    assert np.allclose(image[15, 20], expected, atol=1e-12)
    assert truth["circle"]["ellipse"]["semi_axes"] == pytest.approx([10.0, 10.0])


def test_chrome_highlight_lands_at_the_mirror_point():
    directions = [[0.3, 0.2, 0.93], [-0.5, 0.1, 0.86], [0.1, -0.6, 0.79]]
    (cx, cy), r = (63.7, 48.2), 40.0
    spec = CaptureSpec(
        material={},
        lights=[[{"direction": d, "intensity": 1.0}] for d in directions],
        frame=(128, 96),
        center_px=(cx, cy),
        radius_px=r,
        chrome=True,
        light_radius_deg=1.0,
        exposure=[2e-4] * 3,
        supersample=8,
    )
    images, _, truth = render_capture_images(spec)
    assert truth["material"] is None and truth["mirror"]["light_radius_deg"] == 1.0
    x, y = pixel_centres(128, 96)

    def reflected(px, py):
        n = np.array([(px - cx) / r, -(py - cy) / r, 0.0])
        n[2] = math.sqrt(1 - n[0] ** 2 - n[1] ** 2)
        return 2 * n[2] * n - np.array([0.0, 0.0, 1.0])

    for image, direction in zip(images, directions):
        value = image.sum(axis=-1)
        assert 0 < value.max() < 3  # unsaturated: the disc's radiance I/Ω times the exposure
        weights = value / value.sum()
        centroid = (weights * x).sum(), (weights * y).sum()
        assert angle_deg(reflected(*centroid), direction) < 1.0
        row, col = np.unravel_index(np.argmax(value), value.shape)
        assert angle_deg(reflected(col + 0.5, row + 0.5), direction) < 2.0
        # a 1° lamp's reflection covers a few pixels at most (the background is black)
        assert np.count_nonzero(value) < 12


def test_example_specs_and_their_checks():
    for kind in ("plastic", "perspective", "srgb8", "chrome"):
        spec = example_capture_spec(kind)
        assert spec.frame[0] <= 320 and spec.frame[1] <= 240
    chrome = example_capture_spec("chrome")
    assert chrome.chrome and len(chrome.lights) == 12 and len(set(chrome.exposure)) == 1
    assert example_capture_spec("perspective").camera == "perspective"
    with pytest.raises(SpecError, match="unknown example capture 'wood'"):
        example_capture_spec("wood")
    with pytest.raises(SpecError, match="unknown capture spec field 'colour'"):
        example_capture_spec("plastic", colour=[1, 0, 0])
    material = {"color": [0.5, 0.5, 0.5], "smoothness": 0.5, "metalness": 0.0}
    bad = [
        ({"lights": []}, "non-empty list"),
        ({"lights": [[{"direction": [0, 0, 1], "position": [0, 0, 3]}]]}, "exactly one of direction and position"),
        ({"lights": [[{"position": [0, 0, 0.5]}]]}, "outside the sphere"),
        ({"lights": [[{"direction": [0, 0, 0]}]]}, "zero vector"),
        ({"lights": [[{"direction": [0, 0, 1], "colour": 1}]]}, "unknown key 'colour'"),
        ({"exposure": [1.0, 2.0]}, "one value per image"),
        ({"encoding": "srgb16"}, "encoding must be one of"),
        ({"material": {**material, "transparency": 0.5}}, "opaque"),
        ({"material": {**material, "smoothness": 1.5}}, "smoothness"),
        ({"camera": "perspective", "focal_px": 10.0, "center_px": (300.0, 10.0)}, "not seen whole"),
        ({"frame": (0, 10)}, "frame"),
        ({"supersample": 0}, "supersample"),
    ]
    for change, message in bad:
        fields = {"material": material, "lights": [[{"direction": [0, 0, 1]}]], **change}
        with pytest.raises(SpecError, match=message):
            CaptureSpec(**fields)


def test_command_line_writes_an_example_and_refuses_to_overwrite(tmp_path, capsys):
    out = tmp_path / "persp"
    assert main(["perspective", str(out), "--seed", "7"]) == 0
    truth = json.loads((out / TRUTH_NAME).read_text())
    assert truth["seed"] == 7 and len(truth["files"]) == 8 and truth["camera"]["type"] == "perspective"
    assert sorted(p.name for p in out.iterdir()) == sorted([*truth["files"], MASK_NAME, MANIFEST_NAME, TRUTH_NAME])
    capsys.readouterr()
    assert main(["perspective", str(out)]) == 2
    error = capsys.readouterr().err
    assert error.startswith("capture: error:") and "exists" in error and error.count("\n") == 1
    with pytest.raises(SystemExit):
        main(["wood", str(out)])
