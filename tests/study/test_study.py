"""The intuitive-parameter study end to end (the tiny size), its figures against closed
forms, and conclusions that follow the numbers."""

import copy
import json

import pytest

from strauss_fit import run_study, study_config
from strauss_fit.errors import StraussFitError
from strauss_fit.reporting.study_report import check_outputs, conclusions, write_report


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    """The tiny study, run and written by the library (the command does the same:
    tests/cli/test_cli_study.py)."""
    outdir = tmp_path_factory.mktemp("study") / "report"
    write_report(run_study(study_config("tiny")), outdir)
    return outdir


def test_study_writes_a_self_contained_report(report):
    names = {p.name for p in report.iterdir()}
    assert {
        "study.json",
        "study.md",
        "study.html",
        "fig-consistency.png",
        "fig-independence.png",
        "fig-uniformity.png",
        "fig-expressiveness.png",
    } <= names
    html = (report / "study.html").read_text()
    assert html.count("data:image/png;base64,") == 4 and "<img" in html and 'src="fig-' not in html
    markdown = (report / "study.md").read_text()
    assert "](fig-consistency.png)" in markdown and "## Conclusions" in markdown
    study = json.loads((report / "study.json").read_text())
    assert study["config"]["name"] == "tiny" and len(study["conclusions"]) == 4
    for verdict in study["conclusions"][:3]:
        assert verdict["verdict"] in ("holds", "does not hold", "mixed")
        assert verdict["verdict"] in markdown
    # a second run into the same folder is refused without force
    with pytest.raises(StraussFitError, match="pass --force"):
        check_outputs(report, force=False)


def test_study_figures_are_consistent_with_closed_forms(report):
    study = json.loads((report / "study.json").read_text())
    accuracy = study["consistency"]["accuracy"]
    assert accuracy["lambertian_closed_form"] < 1e-4 and accuracy["stated"] < 1e-3
    white = study["consistency"]["strauss_white_matte_albedo"]
    assert white[0] == pytest.approx(1.0, abs=1e-6)
    # Phong as users set it: only kd Cd and ks Cs reach the image, so the 9 parameters have rank 7
    independence = study["independence"]
    assert independence["images"] >= 4
    for image in independence["per_image"]:
        assert image["phong_user"]["rank"] == 7 and image["phong_user"]["condition_scale_free"] is None
        assert image["phong"]["rank"] == 7 and image["phong"]["condition_scale_free"] is not None
    assert independence["summary"]["phong_user"]["singular_fraction"] == 1.0
    # uniformity: the steps of a sweep add up to its total
    sweep = study["uniformity"]["strauss"]["smoothness"]
    assert sum(sweep["mean_profile"]) == pytest.approx(sweep["total"])
    assert len(sweep["mean_profile"]) == study["config"]["uniformity_steps"] - 1


def test_conclusions_follow_the_numbers(report):
    study = json.loads((report / "study.json").read_text())

    def verdict(changed, aspect):
        return {v["aspect"]: v["verdict"] for v in conclusions(changed)}[aspect]

    consistency = copy.deepcopy(study)
    consistency["consistency"]["strauss"]["count"] = 10000
    for key, fraction in (("phong", 0.3), ("phong_log_exponent", 0.4), ("strauss", 0.01)):
        consistency["consistency"][key]["caps"]["80"]["fraction"] = fraction
    assert verdict(consistency, "consistency (energy)") == "holds"
    consistency["consistency"]["strauss"]["caps"]["80"]["fraction"] = 0.6
    assert verdict(consistency, "consistency (energy)") == "does not hold"

    uniform = copy.deepcopy(study)
    uniform["uniformity"]["strauss"]["smoothness"]["cv"] = 0.1
    uniform["uniformity"]["phong"]["exponent (linear steps)"]["cv"] = 2.0
    uniform["uniformity"]["phong"]["exponent (geometric steps)"]["cv"] = 1.0
    assert verdict(uniform, "uniformity") == "holds"
    uniform["uniformity"]["strauss"]["smoothness"]["cv"] = 1.5
    assert verdict(uniform, "uniformity") == "mixed"
    uniform["uniformity"]["strauss"]["smoothness"]["cv"] = 3.0
    assert verdict(uniform, "uniformity") == "does not hold"

    independent = copy.deepcopy(study)
    independent["independence"]["summary"]["strauss"]["condition_scale_free_median"] = 2.0
    independent["independence"]["summary"]["phong"]["condition_scale_free_median"] = 50.0
    assert verdict(independent, "independence") == "holds"
    independent["independence"]["summary"]["strauss"]["condition_scale_free_median"] = 500.0
    assert verdict(independent, "independence") == "mixed"  # Phong as set by users is singular
