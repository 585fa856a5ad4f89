"""The study's real-photograph part (part 6, strauss_fit.study.real.capture_models) on a small
synthetic capture (the command runs it on a real one, e.g. DiLiGenT's ballPNG): held-out
error, stability over two halves, the report's section and a verdict that follows the numbers."""

import copy

import pytest

from strauss_fit.reporting.document import Document
from strauss_fit.study.real import capture_models
from strauss_fit.study.real_report import add_sections, real_conclusions


@pytest.fixture(scope="module")
def capture_part(tmp_path_factory):
    from data_synth.capture import example_capture_spec, write_capture

    folder = tmp_path_factory.mktemp("capture") / "plastic"
    spec = example_capture_spec(
        "plastic", noise_sd=0.003, supersample=1, seed=5, frame=(120, 96), center_px=(60.3, 47.8), radius_px=30.0
    )
    write_capture(spec, folder)
    # two models keep the test short; the command fits every model of MODELS
    return capture_models(folder, models=("strauss", "lambert"))


def test_held_out_error_and_stability_on_a_synthetic_capture(capture_part):
    c = capture_part
    assert c["images"] == 12 and c["fitted_images"] == 6 and c["held_out_images"] == 6
    strauss, lambert = c["models"]["strauss"], c["models"]["lambert"]
    assert strauss["status"] == "ok" and lambert["status"] == "ok"
    # the capture is a Strauss plastic (s = 0.65, m = 0): Strauss predicts the held-out images
    # within one JND and better than a Lambertian surface, and its s and m are stable
    assert strauss["held_out"]["delta_e2000_mean"] < 1.0
    assert strauss["held_out"]["delta_e2000_mean"] < lambert["held_out"]["delta_e2000_mean"]
    assert strauss["values"]["smoothness"] == pytest.approx(0.65, abs=0.03)
    assert strauss["stability"]["stable"] and set(strauss["stability"]["agree"]) == {"smoothness", "metalness"}
    assert lambert["stability"] is None


def test_the_report_section_and_the_verdict(capture_part):
    study = {"capture": capture_part}
    doc = Document()
    add_sections(doc, study, {})
    markdown = doc.markdown()
    assert "## 6. Real photographs" in markdown and "| strauss |" in markdown and "| lambert |" in markdown
    assert "images 2, 4, 6, …" in markdown
    (verdict,) = real_conclusions(study)
    assert verdict["aspect"] == "real photographs" and verdict["verdict"] == "n/a"  # Phong was not fitted here
    assert "Ranked by held-out ΔE: strauss < lambert." in verdict["statements"]
    with_phong = copy.deepcopy(study)
    strauss = with_phong["capture"]["models"]["strauss"]
    with_phong["capture"]["models"]["phong"] = copy.deepcopy(strauss) | {
        "held_out": {"delta_e2000_mean": 0.01, "relative_rms": 0.001},
        "stability": None,
    }
    (verdict,) = real_conclusions(with_phong)
    assert verdict["verdict"] == "Strauss < Phong" and "Phong 0.01" in verdict["key"]
    strauss["held_out"]["delta_e2000_mean"] = 0.005
    assert real_conclusions(with_phong)[0]["verdict"] == "Strauss ≥ Phong"
