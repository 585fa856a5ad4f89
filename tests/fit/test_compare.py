"""``strauss-fit compare`` (issue 26): several reflectance models on the same target or capture,
their information criteria, and whether Strauss is distinguishable from the best."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from data_synth.capture import example_capture_spec, write_capture
from strauss_fit import Material
from strauss_fit.fitting import compare as compare_module
from strauss_fit.fitting.capture import MODELS
from strauss_fit.fitting.compare import compare_models, format_comparison_table, information_criteria
from strauss_fit.fitting.scene_samples import samples_from_scene
from strauss_fit.io.targets import Target
from strauss_fit.models.phong import PhongMaterial
from strauss_fit.rendering.phong import render_phong
from strauss_fit.rendering.strauss import render
from strauss_fit.scene.loading import load_scene
from strauss_fit_cli.main import main

SCENES = Path(__file__).resolve().parents[2] / "data_synth" / "scenes"
SIGMA = 0.005


def _noisy_samples(image, scene, seed: int):
    pixels = np.asarray(image, dtype=np.float64)
    pixels = pixels + np.random.default_rng(seed).normal(0.0, SIGMA, pixels.shape)
    target = Target(pixels, np.ones(pixels.shape[:2], dtype=bool), "target.exr", "linear", 0, 0)
    return samples_from_scene(scene, target)


@pytest.fixture(scope="module")
def phong_comparison():
    """Every model on a Phong render (64 × 64, two lights) with Gaussian noise of known σ."""
    scene = load_scene(SCENES / "two_lights.toml")
    material = PhongMaterial(ka=0.6, kd=0.6, ks=0.25, exponent=40.0, diffuse_color=(0.9, 0.5, 0.3))
    image, _ = render_phong(scene, material)
    return compare_models(_noisy_samples(image, scene, 1), exposure="fixed", noise=SIGMA)


def test_phong_target_phong_wins_and_strauss_is_distinguishable(phong_comparison):
    result = phong_comparison
    json.dumps(result, allow_nan=False)
    assert result["order"] == list(MODELS) and not result["failed"]
    assert result["criteria"]["likelihood"] == "gaussian, σ known"
    models = result["models"]
    assert min(models, key=lambda m: models[m]["bic"]) == "phong"
    assert models["strauss"]["delta_bic"] > 10
    verdict = result["verdict"]
    assert verdict["best"] == "phong" and verdict["best_by"] == "BIC"
    assert verdict["outcome"] == "distinguishable" and verdict["distinguishable"] is True
    assert verdict["delta_bic"] == pytest.approx(models["strauss"]["bic"] - models["phong"]["bic"])
    assert "Strauss is distinguishable from the best model, phong" in verdict["statement"]
    assert verdict["prediction_delta_e2000_mean"] > 0
    assert any("overconfident" in caveat for caveat in verdict["caveats"])
    # the true model's χ²/dof is 1 within its spread, √(2/dof)
    phong = models["phong"]
    assert abs(phong["chi2_per_dof"] - 1) < 3 * math.sqrt(2 / phong["dof"])
    assert models["strauss"]["chi2_per_dof"] > 2
    table = format_comparison_table(result)
    assert "verdict: Strauss is distinguishable" in table and "blinn-phong" in table


def test_criteria_by_hand(phong_comparison):
    phong = phong_comparison["models"]["phong"]
    n, k, rss = phong["n"], phong["k"], phong["rss"]
    assert (n, k) == (phong_comparison["values_used"], 5)
    chi2 = rss / SIGMA**2  # one σ for every value
    assert phong["chi2"] == pytest.approx(chi2, rel=1e-12)
    assert phong["aic"] == pytest.approx(chi2 + 2 * k, rel=1e-12)
    assert phong["bic"] == pytest.approx(chi2 + k * math.log(n), rel=1e-12)
    # σ profiled out, by hand: n ln(RSS/n) + 2k, + k ln n
    profiled = information_criteria(2.5, 1000, 4)
    assert profiled["aic"] == pytest.approx(1000 * math.log(0.0025) + 8)
    assert profiled["bic"] == pytest.approx(1000 * math.log(0.0025) + 4 * math.log(1000))
    assert profiled["likelihood"] == "gaussian, σ profiled out"


def test_strauss_target_strauss_wins_and_a_failing_model_is_recorded(monkeypatch):
    scene = load_scene(SCENES / "two_lights.toml")
    image, _ = render(scene, Material(color=(0.7, 0.4, 0.25), smoothness=0.75, metalness=0.3))
    samples = _noisy_samples(image, scene, 2)
    real_fit = compare_module.fit_capture_samples

    def failing_lambert(samples, options):
        if options.model == "lambert":
            raise RuntimeError("lambert broke\non two lines")
        return real_fit(samples, options)

    monkeypatch.setattr(compare_module, "fit_capture_samples", failing_lambert)
    result = compare_models(samples, ["strauss", "lambert", "phong"], exposure="fixed", noise=(SIGMA,) * 3)
    json.dumps(result, allow_nan=False)
    assert result["failed"] == ["lambert"]
    assert result["models"]["lambert"]["status"] == "failed"
    assert result["models"]["lambert"]["error"] == "RuntimeError: lambert broke on two lines"
    strauss = result["models"]["strauss"]
    assert strauss["delta_bic"] < 10  # the best, or within 10 of it
    assert abs(strauss["chi2_per_dof"] - 1) < 3 * math.sqrt(2 / strauss["dof"])
    assert result["verdict"]["outcome"] in ("strauss-best", "indistinguishable")
    assert "lambert failed" in format_comparison_table(result)


@pytest.fixture(scope="module")
def capture_folder(tmp_path_factory):
    folder = tmp_path_factory.mktemp("capture")
    spec = example_capture_spec(
        "plastic", noise_sd=0.003, supersample=1, seed=5, frame=(120, 96), center_px=(60.3, 47.8), radius_px=30.0
    )
    write_capture(spec, folder)
    return folder


def test_cli_capture_with_holdout_writes_json_and_png(capture_folder, tmp_path, capsys):
    out = tmp_path / "compare.json"
    code = main(["compare", "--capture", str(capture_folder), "--holdout", "3", "-o", str(out), "--quiet"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    result = json.loads(out.read_text())
    assert result["images_fitted"] == 8 and len(result["held_out"]) == 4
    assert result["settings"]["holdout"] == "3" and result["exposure"] == "global"
    for name in MODELS:
        held = result["models"][name]["held_out"]
        assert held["relative_rms"] > 0 and held["delta_e2000_mean"] >= 0, name
    assert result["verdict"]["best_by"] == "held-out relative RMS"
    assert result["criteria"]["likelihood"] == "gaussian, σ profiled out"
    assert (
        result["models"]["lambert"]["held_out"]["relative_rms"]
        > 3 * result["models"]["strauss"]["held_out"]["relative_rms"]
    )
    png = tmp_path / "compare.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert result["figure"] == {"file": "compare.png", "image": 1}
    assert "verdict:" in captured.out and "held-out rel. RMS" in captured.out
    # an existing output is refused without --force: one line, exit 2
    again = main(["compare", "--capture", str(capture_folder), "--models", "lambert", "-o", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert again == 2 and len(err.strip().splitlines()) == 1 and "exists" in err


def test_unknown_model_is_one_line_listing_the_known(capture_folder, tmp_path, capsys):
    out = tmp_path / "c.json"
    code = main(["compare", "--capture", str(capture_folder), "--models", "strauss,torrance", "-o", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "unknown model 'torrance'" in err and all(name in err for name in MODELS)
    assert not out.exists() and not out.with_suffix(".png").exists()


def test_target_needs_its_scene_and_no_holdout(tmp_path, capsys):
    out = str(tmp_path / "c.json")
    assert main(["compare", "t.exr", "-o", out]) == 2
    assert "--scene" in capsys.readouterr().err
    scene = str(SCENES / "two_lights.toml")
    assert main(["compare", "t.exr", "--scene", scene, "--holdout", "2", "-o", out]) == 2
    assert "--holdout needs a capture" in capsys.readouterr().err


def test_cli_target_reads_the_sidecars_noise(tmp_path, capsys):
    import OpenImageIO as oiio

    scene = SCENES / "two_lights.toml"
    material = PhongMaterial(ka=0.6, kd=0.6, ks=0.25, exponent=40.0, diffuse_color=(0.9, 0.5, 0.3))
    image, _ = render_phong(load_scene(scene), material)
    pixels = np.asarray(image) + np.random.default_rng(3).normal(0.0, SIGMA, np.shape(image))
    target = tmp_path / "phong.exr"
    out = oiio.ImageOutput.create(str(target))
    out.open(str(target), oiio.ImageSpec(pixels.shape[1], pixels.shape[0], 3, "float"))
    out.write_image(np.asarray(pixels, dtype=np.float32))
    out.close()
    sidecar = {"format": "strauss-fit synth sample", "noise": {"per_channel": [SIGMA] * 3}}
    (tmp_path / "phong.json").write_text(json.dumps(sidecar))
    # -o must not replace the sidecar, which has the same name
    assert main(["compare", str(target), "--scene", str(scene), "-o", str(tmp_path / "phong.json")]) == 2
    assert "sidecar" in capsys.readouterr().err
    result_path = tmp_path / "c.json"
    argv = ["compare", str(target), "--scene", str(scene), "--models", "strauss,phong", "-o", str(result_path)]
    assert main([*argv, "--quiet"]) == 0
    result = json.loads(result_path.read_text())
    assert result["noise"]["known"] and result["noise"]["source"].startswith("sensor")
    assert result["verdict"]["outcome"] == "distinguishable"
    assert abs(result["models"]["phong"]["chi2_per_dof"] - 1) < 3 * math.sqrt(2 / result["models"]["phong"]["dof"])
    assert result["inputs"]["target"] == str(target)
