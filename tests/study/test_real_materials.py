"""The study on measured materials (part 5, strauss_fit.study.real): the MERL pipeline on a
made-up stand-in of bbm's fits_parsed.json (tests/data/merl_fits_synthetic.json, three
invented materials, no MERL data), run once through the command line, and verdicts that
follow the numbers. Part 6 (real photographs): test_real_photographs.py."""

import copy
import json
from pathlib import Path
from types import SimpleNamespace

import pytest

from strauss_fit.errors import StraussFitError
from strauss_fit.study.real import CLASSES, FITTED, _strauss_record, material_class, out_of_reach, read_ngan_fits
from strauss_fit.study.real_report import real_conclusions
from strauss_fit_cli.main import main

FIXTURE = Path(__file__).resolve().parents[1] / "data" / "merl_fits_synthetic.json"


@pytest.fixture(scope="module")
def cli_run(tmp_path_factory):
    """``strauss-fit study --size tiny --merl-fits FITS -o OUT`` once, on the fixture plus a
    fourth material whose image cannot be rendered (its roughness underflows m²)."""
    folder = tmp_path_factory.mktemp("merl")
    data = json.loads(FIXTURE.read_text())
    broken = copy.deepcopy(data["ngan_cooktorrance"]["synthetic-red-paint"])
    broken["params"]["roughness"] = 1e-200
    data["ngan_cooktorrance"]["synthetic-broken-fabric"] = broken
    fits = folder / "fits_parsed.json"
    fits.write_text(json.dumps(data))
    outdir = folder / "report"
    import io
    from contextlib import redirect_stdout

    stdout = io.StringIO()
    with redirect_stdout(stdout):
        code = main(["study", "--size", "tiny", "--merl-fits", str(folder), "-o", str(outdir), "--quiet"])
    assert code == 0
    study = json.loads((outdir / "study.json").read_text())
    return SimpleNamespace(outdir=outdir, study=study, stdout=stdout.getvalue())


def _material(study, name):
    return next(r for r in study["merl"]["materials"] if r["name"] == name)


def test_the_command_writes_the_measured_material_table(cli_run):
    study, outdir = cli_run.study, cli_run.outdir
    assert (outdir / "fig-merl.png").is_file()
    markdown = (outdir / "study.md").read_text()
    assert "## 5. Expressiveness on measured materials" in markdown
    assert "| class | materials | Strauss: ΔE ≤ 1 |" in markdown and "](fig-merl.png)" in markdown
    html = (outdir / "study.html").read_text()
    assert html.count("data:image/png;base64,") == 5 and "Expressiveness on measured materials" in html
    merl = study["merl"]
    assert merl["scenes"] == ["two_lights.toml", "key_and_fill.toml"] and merl["image_size"] == 24
    assert len(study["conclusions"]) == 5
    verdict = study["conclusions"][-1]
    assert verdict["aspect"] == "expressiveness on measured materials"
    assert verdict["key"] in cli_run.stdout and verdict["verdict"] in cli_run.stdout
    assert "timing" in study and study["timing"]["merl_s"] > 0


def test_a_lambertian_material_is_matched_by_both_models(cli_run):
    matte = _material(cli_run.study, "synthetic-matte-plastic")
    assert matte["class"] == "plastics"
    for model in ("strauss", "strauss_default", "phong"):
        assert matte[model]["status"] == "ok"
        assert matte[model]["delta_e2000_mean"] <= 1.0
        for scene in matte["scenes"].values():
            assert scene[model]["delta_e2000_mean"] <= 1.0
    assert not matte["strauss"]["out_of_reach"]
    # nothing on it is brighter than white: the fits to the clipped image are those to the image
    for scene in matte["scenes"].values():
        assert scene["clipped_pixels"] == 0 and scene["strauss_clipped"] == scene["strauss"]


def test_a_mirror_like_metal_is_out_of_strauss_reach(cli_run):
    steel = _material(cli_run.study, "synthetic-mirror-steel")
    assert steel["class"] == "metals"
    assert steel["strauss"]["out_of_reach"]
    reasons = {scene["strauss"]["out_of_reach_reason"] for scene in steel["scenes"].values()}
    assert "highlight-out-of-reach" in reasons
    # its highlight is brighter than white: clipped, both models fit the rest, judged on every pixel
    for scene in steel["scenes"].values():
        assert scene["clipped_pixels"] > 0
        assert scene["strauss_clipped"]["status"] == "ok" and scene["phong_clipped"]["status"] == "ok"
    # the worst scene's ΔE is the material's
    assert steel["strauss"]["delta_e2000_mean"] == max(
        scene["strauss"]["delta_e2000_mean"] for scene in steel["scenes"].values()
    )


def test_a_failing_material_is_recorded_and_the_others_go_on(cli_run):
    merl = cli_run.study["merl"]
    broken = _material(cli_run.study, "synthetic-broken-fabric")
    assert broken["strauss"]["status"] == "error" and "NaN or infinite" in broken["strauss"]["message"]
    assert broken["class"] == "fabrics"
    assert merl["all"]["materials"] == 4 and merl["all"]["strauss"]["fitted"] == 3
    assert all(merl["all"][model]["errors"] == 1 for model in FITTED)
    by_class = merl["by_class"]
    assert set(by_class) == set(CLASSES)
    assert by_class["fabrics"]["strauss"]["fitted"] == 0 and by_class["fabrics"]["strauss"]["matched"] is None
    assert by_class["metals"]["strauss"]["out_of_reach"] == 1.0 and by_class["metals"]["strauss"]["matched"] == 0.0
    assert by_class["plastics"]["phong"]["matched"] == 1.0
    assert "error:" in (cli_run.outdir / "study.md").read_text()


def test_merl_conclusions_follow_the_numbers(cli_run):
    study = copy.deepcopy(cli_run.study)

    def verdict(changed):
        return real_conclusions(changed)[0]["verdict"]

    a = study["merl"]["all"]

    def set_(model, matched, median):
        a[model].update(matched=matched, median_delta_e=median)

    set_("strauss", 0.8, 0.5)
    set_("phong", 0.6, 0.9)
    set_("strauss_clipped", 0.9, 0.3)
    set_("phong_clipped", 0.7, 0.6)
    assert verdict(study) == "Strauss ≥ Phong"
    set_("strauss", 0.4, 1.5)
    set_("strauss_clipped", 0.5, 1.0)
    assert verdict(study) == "Strauss < Phong"
    set_("strauss", 0.7, 1.5)  # more matched, but a larger median: mixed as rendered
    assert verdict(study) == "mixed"
    statements = " ".join(real_conclusions(study)[0]["statements"])
    assert "70.0 %" in statements and "60.0 %" in statements  # built from the numbers
    # less expressive as rendered, not once clipped at white: the gap is in the highlights
    set_("strauss", 0.4, 1.5)
    set_("strauss_clipped", 0.9, 0.3)
    assert verdict(study) == "mixed"
    assert "brighter than white" in real_conclusions(study)[0]["statements"][-1]


def test_material_classes_follow_the_documented_rule():
    assert material_class("gold-metallic-paint2") == "paints"
    assert material_class("silver-paint") == "paints"
    assert material_class("pink-felt") == "fabrics"
    assert material_class("alum-bronze") == "metals"
    assert material_class("ss440") == "metals"
    assert material_class("black-oxidized-steel") == "metals"
    assert material_class("specular-violet-phenolic") == "plastics"
    assert material_class("neoprene-rubber") == "plastics"
    assert material_class("cherry-235") == "other" and material_class("hematite") == "other"


def test_reading_the_fits_file(tmp_path):
    materials, file = read_ngan_fits(FIXTURE)
    assert file == FIXTURE and [m.name for m in materials] == [
        "synthetic-matte-plastic",
        "synthetic-red-paint",
        "synthetic-mirror-steel",
    ]
    steel = materials[2]
    assert steel.f0 == 0.6 and steel.roughness == 0.008 and steel.ks == (0.08, 0.06, 0.03)
    with pytest.raises(StraussFitError, match="does not exist"):
        read_ngan_fits(tmp_path)  # a folder without fits_parsed.json
    (tmp_path / "fits_parsed.json").write_text(json.dumps({"ngan_ward": {}}))
    with pytest.raises(StraussFitError, match="no 'ngan_cooktorrance' entry"):
        read_ngan_fits(tmp_path)
    bad = {"ngan_cooktorrance.fit": {"x": {"lambertian_albedo": [0.1, 0.1], "model": "NganCookTorrance"}}}
    (tmp_path / "fits_parsed.json").write_text(json.dumps(bad))
    with pytest.raises(StraussFitError, match="material 'x'"):
        read_ngan_fits(tmp_path)


def test_out_of_reach_reads_the_fit_diagnosis():
    def result(codes, at_bound=(), color=(0.5, 0.5, 0.5), smoothness=0.5, highlight=0.0):
        regions = {
            "highlight": {"pixels": 10, "share_of_chi2": highlight},
            "highlight wings": {"pixels": 10, "share_of_chi2": 0.0},
            "body": {"pixels": 80, "share_of_chi2": 1.0 - highlight},
        }
        return SimpleNamespace(
            warnings=[{"code": c, "message": ""} for c in codes],
            material=SimpleNamespace(color=color, smoothness=smoothness, metalness=0.0),
            at_bound=list(at_bound),
            residual={"regions": regions, "delta_e2000_mean": 2.0, "rms": 0.1},
            free=["color", "smoothness"],
        )

    assert out_of_reach(result(["highlight-out-of-reach"])) == (True, "highlight-out-of-reach")
    # a colour at 1 with the residual in the highlight (90 % of χ² on 20 % of the pixels)
    reach, why = out_of_reach(result([], at_bound=["color_r"], color=(1.0, 0.4, 0.2), highlight=0.9))
    assert reach and "color_r" in why
    # the same bound with the residual spread evenly is not the highlight's doing
    assert out_of_reach(result([], at_bound=["color_r"], color=(1.0, 0.4, 0.2), highlight=0.2)) == (False, None)
    # a colour pinned at 0 is a colour without that primary, not a bound pushed against
    assert not out_of_reach(result([], at_bound=["color_b"], color=(0.5, 0.4, 0.0), highlight=0.9))[0]
    assert out_of_reach(result([], at_bound=["smoothness"], smoothness=1.0, highlight=0.9))[0]
    failed = _strauss_record(SimpleNamespace(target="x", message="the fit broke"))
    assert failed == {"status": "error", "message": "the fit broke"}


def test_bad_measured_inputs_are_refused_before_the_study_runs(tmp_path, capsys):
    outdir = tmp_path / "report"
    assert main(["study", "--size", "tiny", "-o", str(outdir), "--merl-fits", str(tmp_path / "none.json")]) == 2
    assert "does not exist" in capsys.readouterr().err
    (tmp_path / "fits.json").write_text(json.dumps({"ngan_ward": {}}))
    assert main(["study", "--size", "tiny", "-o", str(outdir), "--merl-fits", str(tmp_path / "fits.json")]) == 2
    assert "no 'ngan_cooktorrance' entry" in capsys.readouterr().err
    assert main(["study", "--size", "tiny", "-o", str(outdir), "--capture", str(tmp_path / "no-capture")]) == 2
    assert capsys.readouterr().err
    assert not outdir.exists()
