"""The report of a capture's fit: one grid row per image (the held-out ones last, predicted),
the residual panels are fit − target, the page is self-contained and escapes the result's
text, equivalence ranges are shown when present, and ``strauss-fit report`` writes it or
fails in one line when the recorded capture is gone; with a capture's chain, the posterior
section is the chain's, and a chain of another fit or whose capture moved is refused."""

from __future__ import annotations

import copy
import json
import re
import shutil

import numpy as np
import pytest

from data_synth.capture import example_capture_spec, write_capture
from strauss_fit.capture import capture_inputs, open_capture
from strauss_fit.fitting.capture import CaptureFitOptions
from strauss_fit.fitting.capture_result import fit_capture, predict, reload_capture_fit, reload_held_out
from strauss_fit.inference.capture_posterior import capture_chain_summary, sample_capture
from strauss_fit.inference.sampler import SampleSettings, load_chain, write_metadata
from strauss_fit.reporting.capture_report import build_capture_report, open_recorded_capture
from strauss_fit.reporting.fit_report import ReportError
from strauss_fit_cli.main import main

SMALL = dict(frame=(120, 96), center_px=(60.3, 47.8), radius_px=30.0)


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """A 12-image capture fitted with every 3rd image held out (Lambert compared); the result
    records the capture relative to its own folder."""
    folder = tmp_path_factory.mktemp("capture_report")
    write_capture(example_capture_spec("plastic", noise_sd=0.003, supersample=1, seed=5, **SMALL), folder / "cap")
    result = fit_capture(
        open_capture([folder / "cap"]),
        CaptureFitOptions(),
        holdout="3",
        compare=("lambert",),
        inputs=capture_inputs(["cap"], None, None),
    )
    (folder / "fit.json").write_text(json.dumps(result))
    return folder, json.loads((folder / "fit.json").read_text())


@pytest.fixture(scope="module")
def reloaded(fitted):
    folder, result = fitted
    capture = open_recorded_capture(result, folder / "fit.json")
    samples, fit = reload_capture_fit(result, capture=capture)
    held = reload_held_out(result, fit, capture)
    assert held is not None
    return samples, fit, held


@pytest.fixture(scope="module")
def built(fitted, reloaded):
    _, result = fitted
    samples, fit, held = reloaded
    return build_capture_report(result, samples, fit, held=held)


def test_grid_has_one_row_per_image_the_held_out_ones_last(fitted, built):
    _, result = fitted
    grid = built.data["grid"]
    rows = grid["rows"]
    assert len(rows) == result["images"] == 12
    assert [r["number"] for r in rows] == [1, 2, 4, 5, 7, 8, 10, 11, 3, 6, 9, 12]
    assert [r["held_out"] for r in rows] == [False] * 8 + [True] * 4
    # the rows' numbers are those the fit recorded: the fitted images' and the held-out prediction's
    recorded = result["per_image"] + result["holdout"]["models"]["strauss"]["per_image"]
    assert [r["file"] for r in rows] == [r["file"] for r in recorded]
    for row, expected in zip(rows, recorded):
        assert row["relative_rms"] == pytest.approx(expected["relative_rms"], rel=1e-9)
        assert row["delta_e2000_mean"] == pytest.approx(expected["delta_e2000_mean"], rel=1e-9)
    assert grid["figures"] == ["lights-1.png"]
    assert grid["residual"].shape[0] == 12
    assert sum(len(png) for png in built.images.values()) < 1_500_000
    assert built.data["verdict"] == result["residual"]["verdict"]
    assert built.data["holdout"]["rows"][0][0] == "strauss" and built.data["holdout"]["rows"][1][0] == "lambert"
    markdown = built.markdown
    order = [
        "## Verdict and warnings",
        "## The capture",
        "## Parameters",
        "## Residual",
        "## Target, fit and residual per light",
        "## Per image",
        "## Held-out images",
        "## Correlations",
    ]
    assert [markdown.index(heading) for heading in order] == sorted(markdown.index(heading) for heading in order)


def test_residual_panels_are_fit_minus_target(reloaded, built):
    samples, fit, (held_samples, held_predicted) = reloaded
    grid = built.data["grid"]
    assert grid["factor"] == 1  # a 60 px sphere: thumbnails at full resolution
    r0, _, c0, _ = grid["crop"]
    residual = grid["residual"]
    expected = (fit.predicted - samples.values).mean(axis=-1)
    usable = samples.usable.all(axis=-1)
    for i in range(samples.count):
        shown = residual[i][samples.rows - r0, samples.cols - c0]
        np.testing.assert_allclose(shown[usable[i]], expected[i][usable[i]], rtol=0, atol=1e-12)
        assert np.isnan(shown[~usable[i]]).all()
    assert (~usable).any()  # the capture has saturated values, shown as not used
    # the held-out rows show the fit's prediction of images it never saw
    predicted, _ = predict(held_samples, fit)
    np.testing.assert_allclose(held_predicted, predicted)
    i = samples.count  # the first held-out row
    keep = held_samples.usable[0].all(axis=-1)
    shown = residual[i][held_samples.rows - r0, held_samples.cols - c0]
    np.testing.assert_allclose(shown[keep], (predicted[0] - held_samples.values[0]).mean(axis=-1)[keep], atol=1e-12)
    # off the sphere there is no residual
    outside = np.ones(residual.shape[1:], dtype=bool)
    outside[samples.rows - r0, samples.cols - c0] = False
    assert np.isnan(residual[:, outside]).all()


def test_text_from_the_result_is_escaped(fitted, reloaded):
    _, result = fitted
    samples, fit, _ = reloaded
    hostile = copy.deepcopy(result)
    hostile["warnings"].append({"code": "odd", "message": "<script>alert(1)</script> & more"})
    report = build_capture_report(hostile, samples, fit, title="<b>title</b>")
    assert "<script>" not in report.html and "<b>title</b>" not in report.html
    assert "&lt;script&gt;alert(1)&lt;/script&gt; &amp; more" in report.html
    assert "[odd] <script>alert(1)</script> & more" in report.data["warnings"]
    # without the held-out images, only the fitted ones are in the grid
    assert len(report.data["grid"]["rows"]) == samples.count


def test_equivalence_ranges_get_a_column_and_a_figure(fitted, reloaded):
    _, result = fitted
    samples, fit, _ = reloaded
    ranges = {"color": [[0.7, 0.8], [0.3, 0.4], [0.15, 0.2]], "smoothness": [0.6, 0.7], "metalness": [0.0, 0.1]}
    report = build_capture_report(result, samples, fit, equivalence=ranges)
    assert "looks the same (ΔE ≤ 1)" in report.markdown
    assert report.data["intervals"]["bands"]["color_g"] == (0.3, 0.4)
    assert set(report.data["intervals"]["bands"]) == {"color_r", "color_g", "color_b", "smoothness", "metalness"}
    assert "intervals.png" in report.images
    assert f"| smoothness | {result['smoothness']:.4g} |" in report.markdown and "0.6 – 0.7" in report.markdown
    # without ranges: no column, no figure
    plain = build_capture_report(result, samples, fit)
    assert "looks the same" not in plain.markdown and "intervals.png" not in plain.images


def test_cli_writes_a_self_contained_report(fitted, tmp_path, capsys):
    folder, result = fitted
    out = tmp_path / "r.html"
    code = main(["report", "--fit", str(folder / "fit.json"), "-o", str(out)])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert f"fit verdict: {result['residual']['verdict']}" in captured.err
    assert "wrote " in captured.out
    assert out.is_file() and (tmp_path / "r.md").is_file()
    assert sorted(p.name for p in (tmp_path / "r_files").iterdir()) == ["correlation.png", "lights-1.png"]
    page = out.read_text()
    assert "<script" not in page and "http://" not in page and "https://" not in page
    sources = re.findall(r'src="([^"]*)"', page)
    assert len(sources) == 2 and all(s.startswith("data:image/png;base64,") for s in sources)
    assert "held out" in page and "lights-1.png" in (tmp_path / "r.md").read_text()


def test_cli_one_line_error_when_the_recorded_capture_is_gone(fitted, tmp_path, capsys):
    folder, _ = fitted
    shutil.copy(folder / "fit.json", tmp_path / "fit.json")  # no 'cap' beside this copy
    code = main(["report", "--fit", str(tmp_path / "fit.json"), "-o", str(tmp_path / "r.html")])
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.startswith("strauss-fit: error: ") and err.count("\n") == 1, err
    assert "records the capture cap, which no longer exists" in err and "--capture" in err
    assert not (tmp_path / "r.html").exists() and not (tmp_path / "r_files").exists()
    # a chain that is not there: one line too, before the capture is read
    code = main(["report", "--fit", str(tmp_path / "fit.json"), "--chain", "c.h5", "-o", str(tmp_path / "r.html")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "chain file not found: c.h5" in err, err


def test_stability_section_lists_halves_and_disagreeing_images(fitted, reloaded):
    _, result = fitted
    samples, fit, _ = reloaded
    stable = copy.deepcopy(result)
    stable["stability"] = {
        "halves": [
            {
                "half": "odd",
                "images": ["a", "b"],
                "values": {"smoothness": 0.61},
                "equivalence": {"smoothness": [0.5, 0.7]},
            },
            {
                "half": "even",
                "images": ["c"],
                "values": {"smoothness": 0.64},
                "equivalence": {"smoothness": [0.55, 0.72]},
            },
        ],
        "agree": {"smoothness": True},
        "stable": True,
        "delta_e": 1.0,
        "single_images": {
            "fits": [
                {"file": "/x/001.png", "disagrees": ["smoothness"], "reasons": ["<script>x</script> grazes"]},
                {"file": "/x/002.png", "disagrees": []},
            ],
            "rule": "the rule",
        },
    }
    report = build_capture_report(stable, samples, fit)
    assert report.data["stability"]["rows"] == [
        ["odd (2 images)", "smoothness", "0.61", "0.5 – 0.7"],
        ["even (1 images)", "smoothness", "0.64", "0.55 – 0.72"],
    ]
    assert "1 of 2 disagree" in report.markdown and "001.png" in report.markdown
    assert "<script>x</script>" not in report.html and "&lt;script&gt;x&lt;/script&gt; grazes" in report.html
    # no stability in the result: no section
    assert "stability" not in build_capture_report(result, samples, fit).data


# --- with a chain -----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def chain_path(fitted):
    """A short chain of the fit (300 steps, not converged), its likelihood a subsample."""
    folder, _ = fitted
    settings = SampleSettings(max_steps=300, min_tau_multiple=50, check_every=100, walkers=16, seed=2)
    sample_capture(folder / "fit.json", folder / "chain.h5", settings=settings, values=20_000, adjust="none")
    return folder / "chain.h5"


def test_posterior_section_is_the_chains(fitted, reloaded, chain_path):
    _, result = fitted
    samples, fit, held = reloaded
    chain = load_chain(chain_path, required=True)
    report = build_capture_report(result, samples, fit, held=held, chain=chain)
    summary = capture_chain_summary(chain)
    rows = report.data["posterior"]
    assert [row["label"] for row in rows] == fit.labels == summary["labels"]
    for row in rows:
        p = summary["parameters"][row["label"]]
        for key in ("median", "p16", "p84", "p2.5", "p97.5"):
            assert row[key] == pytest.approx(p[key], rel=1e-12, abs=1e-15), (row["label"], key)
    assert [row["value"] for row in rows] == pytest.approx(list(fit.physical), rel=1e-12)
    assert report.data["chain"]["adjustment"] == "none" and report.data["chain"]["sigma"] == chain.meta["sigma"]
    assert "not adjusted" in report.markdown and "Gaussian noise of σ = " in report.markdown
    assert {"corner.png", "trace.png"} <= set(report.images)
    # the chain's verdict: an untrustworthy chain is the first warning
    diagnostics = chain.diagnostics()
    assert report.data["diagnostics"]["trustworthy"] == diagnostics.trustworthy
    assert report.data["warnings"][0].startswith("The chain is not trustworthy yet") == (not diagnostics.trustworthy)
    assert not diagnostics.trustworthy  # 300 steps are not 50 autocorrelation times
    markdown = report.markdown
    order = ["## Parameters", "## Correlations", "## Posterior", "### Sampler diagnostics"]
    assert [markdown.index(heading) for heading in order] == sorted(markdown.index(heading) for heading in order)
    # a fit the chain was not sampled from is refused
    other = copy.deepcopy(result)
    other["smoothness"] *= 1.01
    if "values" in other:
        other["values"]["smoothness"] *= 1.01
    with pytest.raises(ReportError, match="sampled from another fit.*smoothness"):
        build_capture_report(other, samples, fit, chain=chain)


def test_cli_reports_a_capture_chain(fitted, chain_path, tmp_path, capsys):
    folder, _ = fitted
    out = tmp_path / "r.html"
    code = main(["report", "--chain", str(chain_path), "-o", str(out)])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "warning: The chain is not trustworthy yet" in captured.err
    page = out.read_text()
    assert "<h2>Posterior</h2>" in page and "held out" in page
    assert sorted(p.name for p in (tmp_path / "r_files").iterdir()) == [
        "corner.png",
        "correlation.png",
        "lights-1.png",
        "trace.png",
    ]
    # with the fit result it was sampled from, too
    code = main(["report", "--fit", str(folder / "fit.json"), "--chain", str(chain_path), "-o", str(out), "--force"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "<h2>Posterior</h2>" in out.read_text()


def test_cli_refuses_a_capture_chain_in_one_line(fitted, chain_path, tmp_path, capsys):
    folder, result = fitted

    def refused(*argv):
        code = main([str(a) for a in argv])
        err = capsys.readouterr().err
        assert code == 2, err
        assert err.startswith("strauss-fit: error: ") and err.count("\n") == 1, err
        assert not (tmp_path / "r.html").exists() and not (tmp_path / "r_files").exists()
        return err

    # the fit the chain was sampled from moved, and its capture with it
    moved = tmp_path / "moved.h5"
    shutil.copy(chain_path, moved)
    meta = load_chain(moved, required=True).meta
    write_metadata(moved, {**meta, "fit_base": str(tmp_path / "gone")})
    err = refused("report", "--chain", moved, "-o", tmp_path / "r.html")
    assert "records the capture cap, which no longer exists" in err and "--capture" in err, err
    # a fit result the chain was not sampled from (refused before the capture is read)
    other = copy.deepcopy(result)
    other["smoothness"] *= 1.01
    if "values" in other:
        other["values"]["smoothness"] *= 1.01
    (tmp_path / "other.json").write_text(json.dumps(other))
    err = refused("report", "--fit", tmp_path / "other.json", "--chain", chain_path, "-o", tmp_path / "r.html")
    assert "was sampled from another fit" in err and "smoothness" in err, err
    # the fit result of one image with a capture's chain
    (tmp_path / "single.json").write_text(json.dumps({"free": ["color", "smoothness"]}))
    err = refused("report", "--fit", tmp_path / "single.json", "--chain", chain_path, "-o", tmp_path / "r.html")
    assert "is a capture's but" in err and "different fits" in err, err
