"""Rendering any registered reflectance model (``render --model``) and fitting it back."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from strauss_fit.fitting.capture import CaptureFitOptions, fit_capture_samples
from strauss_fit.fitting.scene_samples import samples_from_scene
from strauss_fit.io.targets import Target
from strauss_fit.models.phong import PhongMaterial
from strauss_fit.rendering.coverage import fully_covered
from strauss_fit.rendering.phong import render_phong
from strauss_fit.rendering.reflectance import render_model
from strauss_fit.rendering.strauss import render
from strauss_fit.scene.loading import load_scene

SCENES = Path(__file__).resolve().parents[2] / "data_synth" / "scenes"


def test_strauss_and_phong_match_their_own_renderers():
    scene = load_scene(SCENES / "basic.toml")  # opaque: the local model is the whole image
    strauss, _ = render(scene)
    local, mask = render_model(scene, "strauss", {"color": [0.8, 0.3, 0.2], "smoothness": 0.5, "metalness": 0.0})
    covered = np.asarray(fully_covered(scene.camera))
    assert np.abs(np.asarray(strauss) - np.asarray(local))[covered].max() < 1e-12
    scene = load_scene(SCENES / "two_lights.toml")
    phong, _ = render_phong(scene, PhongMaterial(ka=0.6, kd=0.6, ks=0.25, exponent=40.0, diffuse_color=(0.9, 0.5, 0.3)))
    ours, _ = render_model(scene, "phong", {"diffuse": [0.54, 0.3, 0.18], "specular": 0.25, "exponent": 40.0})
    assert np.abs(np.asarray(phong) - np.asarray(ours)).max() < 1e-12


def test_cook_torrance_renders_and_fits_back():
    scene = load_scene(SCENES / "two_lights.toml")
    truth = {"kd": [0.3, 0.2, 0.1], "f0": [0.9, 0.6, 0.3], "roughness": 0.25}
    image, _ = render_model(scene, "cook-torrance", truth)
    pixels = np.asarray(image, dtype=np.float64)
    target = Target(pixels, np.ones(pixels.shape[:2], dtype=bool), "ct.exr", "linear", 0, 0)
    fit = fit_capture_samples(
        samples_from_scene(scene, target), CaptureFitOptions(model="cook-torrance", exposure="fixed")
    )
    values = fit.values()
    assert np.allclose(values["kd"], truth["kd"], atol=1e-4)
    assert np.allclose(values["f0"], truth["f0"], atol=1e-4)
    assert values["roughness"] == pytest.approx(0.25, abs=1e-4)


def test_cli_render_model(tmp_path):
    values = tmp_path / "v.json"
    values.write_text(json.dumps({"model": "lambert", "values": {"albedo": [0.5, 0.4, 0.3]}}))
    cli = [sys.executable, "-m", "strauss_fit_cli.main", "render", str(SCENES / "basic.toml")]
    ok = subprocess.run(cli + ["--model", "lambert", "--values", str(values), "-o", str(tmp_path / "l.exr")],
                        capture_output=True, text=True, timeout=300)  # fmt: skip
    assert ok.returncode == 0 and "model lambert" in ok.stdout, ok.stderr
    wrong = subprocess.run(cli + ["--model", "phong", "--values", str(values), "-o", str(tmp_path / "p.exr")],
                           capture_output=True, text=True, timeout=300)  # fmt: skip
    assert wrong.returncode == 2 and "is a lambert fit" in wrong.stderr and len(wrong.stderr.splitlines()) == 1
    unknown = subprocess.run(cli + ["--model", "ward", "-o", str(tmp_path / "w.exr")],
                             capture_output=True, text=True, timeout=300)  # fmt: skip
    assert unknown.returncode == 2 and "cook-torrance" in unknown.stderr
    assert not (tmp_path / "p.exr").exists() and not (tmp_path / "w.exr").exists()
