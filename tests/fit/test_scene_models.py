"""Any reflectance model on one target and its scene (``fit TARGET --scene S --model NAME``):
the scene's pixels as a capture of one image (:mod:`strauss_fit.fitting.scene_samples`)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from strauss_fit.fitting.capture import CaptureFitOptions
from strauss_fit.fitting.capture_result import fit_capture, reload_capture_fit
from strauss_fit.fitting.scene_samples import samples_from_scene
from strauss_fit.io.targets import Target
from strauss_fit.models.phong import PhongMaterial
from strauss_fit.rendering.phong import render_phong
from strauss_fit.rendering.strauss import render
from strauss_fit.scene.loading import load_scene

SCENES = Path(__file__).resolve().parents[2] / "data_synth" / "scenes"


def _target(image, path="target.exr") -> Target:
    pixels = np.asarray(image, dtype=np.float64)
    return Target(pixels, np.ones(pixels.shape[:2], dtype=bool), path, "linear", 0, 0)


def test_strauss_through_the_scene_recovers_the_scene_material():
    scene = load_scene(SCENES / "basic.toml")  # C (0.8, 0.3, 0.2), s 0.5, m 0; one light and ambient 0.1
    image, _ = render(scene)
    samples = samples_from_scene(scene, _target(image))
    assert samples.ambient_light is not None and np.allclose(samples.ambient_light, 0.1)
    result = fit_capture(samples, CaptureFitOptions(exposure="fixed"))
    assert np.allclose(result["color"], [0.8, 0.3, 0.2], atol=1e-6)
    assert abs(result["smoothness"] - 0.5) < 1e-6 and result["metalness"] < 1e-6


def test_phong_through_the_scene_recovers_a_phong_render():
    scene = load_scene(SCENES / "two_lights.toml")
    # ka = kd: the fitted Phong reflects ambient light as its diffuse albedo
    material = PhongMaterial(ka=0.6, kd=0.6, ks=0.25, exponent=40.0, diffuse_color=(0.9, 0.5, 0.3))
    image, _ = render_phong(scene, material)
    samples = samples_from_scene(scene, _target(image))
    result = fit_capture(samples, CaptureFitOptions(model="phong", exposure="fixed"))
    assert np.allclose(result["diffuse"], 0.6 * np.array([0.9, 0.5, 0.3]), rtol=1e-5)
    assert result["specular"] == pytest.approx(0.25, rel=1e-4)
    assert result["exponent"] == pytest.approx(40.0, rel=1e-4)
    # one image: the sandwich sums over tiles of it, not over the one image
    assert result["uncertainty_method"]["name"] == "tile-cluster sandwich"


def test_cli_model_on_one_target_and_back(tmp_path):
    scene = SCENES / "basic.toml"
    image, _ = render(load_scene(scene))
    import OpenImageIO as oiio

    target = tmp_path / "t.exr"
    out = oiio.ImageOutput.create(str(target))
    out.open(str(target), oiio.ImageSpec(image.shape[1], image.shape[0], 3, "float"))
    out.write_image(np.asarray(image, dtype=np.float32))
    out.close()
    run = subprocess.run(
        [sys.executable, "-m", "strauss_fit_cli.main", "fit", str(target), "--scene", str(scene),
         "--model", "lambert", "-o", str(tmp_path / "l.json"), "--quiet"],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    result = json.loads((tmp_path / "l.json").read_text())
    assert result["model"] == "lambert" and result["residual"]["verdict"] == "mismatch"
    # the result reads back from its recorded target and scene (what sample and report do)
    samples, fit = reload_capture_fit(result, base=tmp_path)
    assert fit.model == "lambert" and samples.count == 1
    report = subprocess.run(
        [sys.executable, "-m", "strauss_fit_cli.main", "report", "--fit", str(tmp_path / "l.json"),
         "-o", str(tmp_path / "r.html")],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert report.returncode == 0, report.stderr
    assert "lambert" in (tmp_path / "r.md").read_text()
    two = subprocess.run(
        [sys.executable, "-m", "strauss_fit_cli.main", "fit", str(target), str(target), "--scene", str(scene),
         "--model", "phong", "-o", str(tmp_path / "p/"), "--quiet"],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    # the same target twice into one folder: refused before any work (each would overwrite the other)
    assert two.returncode == 2 and len(two.stderr.strip().splitlines()) == 1 and "given twice" in two.stderr


def test_one_image_is_not_called_a_capture_in_the_verdict():
    from strauss_fit.reporting.capture_report import _verdict_text

    one = _verdict_text("mismatch", "lambert", {}, 1)
    many = _verdict_text("mismatch", "lambert", {}, 96)
    assert "this image" in one and "capture" not in one and "photographs" not in one
    assert "this capture" in many and "photographs" in many
