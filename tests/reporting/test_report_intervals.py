"""The report's two kinds of interval and its warnings (issue 13.2, 13.3): on a Phong sphere
(which Strauss cannot reproduce) fitted with the noise known and the equivalence ranges
computed, the parameter table names the statistical interval (the noise sandwich), shows
each parameter's equivalence band beside it as the fit computed it, says in one sentence
what each means, draws both; every warning of the fit (code and message) and its verdict
are in the Warnings section; a Laplace fit says its ± is conditional on the model; a chain
adjusted to the sandwich is labelled so, and a Huber fit set against a chain (whose
likelihood is least squares) is warned about."""

from __future__ import annotations

import html

import numpy as np
import pytest

import strauss_fit as sf
import support
from strauss_fit.inference.sampler import SampleSettings, load_chain, sample
from strauss_fit.io.images import write_image
from strauss_fit.reporting.fit_report import build_report, render_fit

pytestmark = pytest.mark.usefixtures("x64")

FREE = ("color", "smoothness", "metalness")


@pytest.fixture(scope="module")
def phong_fit(tmp_path_factory):
    folder = tmp_path_factory.mktemp("intervals")
    scene = support.key_and_fill_scene(24, source="phong")
    (folder / "scene.toml").write_text(support.key_and_fill_toml(24, material=support.SMALL_MATERIAL))
    image, _ = sf.render_phong(scene, sf.PhongMaterial(kd=0.7, ks=0.3, exponent=20.0, diffuse_color=(0.8, 0.5, 0.3)))
    pixels = np.asarray(image) + np.random.default_rng(0).normal(0, 0.01, np.shape(image))
    write_image(folder / "phong.exr", pixels)
    target = sf.load_target(folder / "phong.exr")
    loaded, _ = sf.match_scene(sf.load_scene(folder / "scene.toml"), target)
    result = sf.fit(loaded, target, sf.FitOptions(noise=0.01, free=FREE, equivalence=True))
    assert result.verdict == "mismatch" and result.uncertainty_method["name"] == "noise sandwich"
    assert result.equivalence is not None and result.warnings
    fitted, used = render_fit(loaded, target, result.to_json())
    return folder, loaded, target, result, fitted, used


def bands_by_label(equivalence):
    out = {}
    for name, value in equivalence.items():
        if name == "color":
            out.update({f"color_{c}": tuple(pair) for c, pair in zip("rgb", value)})
        else:
            out[name] = tuple(value)
    return out


def test_the_table_shows_the_sandwich_and_the_equivalence_band_with_their_meanings(phong_fit):
    _, _, target, result, fitted, used = phong_fit
    report = build_report(result.to_json(), target.pixels, fitted, used)
    md = report.markdown
    header = next(line for line in md.splitlines() if line.startswith("| parameter | fit |"))
    assert "± (noise sandwich)" in header and "looks the same (ΔE ≤ 1)" in header
    bands = bands_by_label(result.equivalence)
    assert report.data["intervals"]["bands"] == {k: tuple(v) for k, v in bands.items()}
    for label, (low, high) in bands.items():
        row = next(line for line in md.splitlines() if line.startswith(f"| {label} |"))
        assert f"{low:.3g} – {high:.3g}" in row
    sd = result.uncertainty["smoothness"]
    row = next(line for line in md.splitlines() if line.startswith("| smoothness |"))
    assert f"| {sd:.2g} |" in row  # the sandwich's ±, not the Laplace one
    assert result.uncertainty_laplace["smoothness"] != pytest.approx(sd, rel=0.05)
    meanings = report.data["intervals"]["meanings"]
    assert len(meanings) == 2
    assert "fresh noise" in meanings[0] and "best Strauss approximation" in meanings[0]
    assert "not for the true material" in meanings[0]  # the verdict is a mismatch
    assert "CIEDE2000 of 1" in meanings[1] and "nobody sees" in meanings[1]
    for sentence in meanings:
        assert sentence in md and html.escape(sentence) in report.html
    assert "intervals.png" in report.images and report.images["intervals.png"].startswith(b"\x89PNG")


def test_every_warning_of_the_fit_and_its_verdict_are_in_the_warnings_section(phong_fit):
    _, _, target, result, fitted, used = phong_fit
    report = build_report(result.to_json(), target.pixels, fitted, used)
    section = report.markdown.split("## Warnings", 1)[1].split("\n## ", 1)[0]
    assert "Verdict: mismatch" in section
    codes = [w["code"] for w in result.warnings]
    assert "model-mismatch" in codes
    for w in result.warnings:
        line = f"[{w['code']}] {w['message']}"
        assert line in section and html.escape(line) in report.html
    assert report.data["fit_warnings"] == result.warnings


def test_a_laplace_fit_says_its_interval_is_conditional_on_the_model(phong_fit):
    _, _, target, result, fitted, used = phong_fit
    payload = result.to_json()
    payload["uncertainty_method"] = {"name": "laplace", "conditional_on_model": True}
    payload.pop("equivalence")
    report = build_report(payload, target.pixels, fitted, used)
    header = next(line for line in report.markdown.splitlines() if line.startswith("| parameter | fit |"))
    assert "± (Laplace)" in header and "looks the same" not in header
    [meaning] = report.data["intervals"]["meanings"]
    assert "only if the model reproduces the target" in meaning
    assert "intervals.png" not in report.images


def test_a_chain_adjusted_to_the_sandwich_is_labelled_so(phong_fit):
    folder, loaded, target, result, _, _ = phong_fit
    # sample takes a least-squares fit (its likelihood is least squares); the fixture's
    # fit switched to Huber on this visible mismatch
    assert result.solver["loss"] == "huber"
    linear = sf.fit(loaded, target, sf.FitOptions(noise=0.01, free=FREE, equivalence=True, loss="linear"))
    fitted, used = render_fit(loaded, target, linear.to_json())
    out = sample(
        folder / "phong.exr",
        folder / "scene.toml",
        folder / "chain.h5",
        fit=linear,
        settings=SampleSettings(max_steps=300, walkers=32, seed=2),
    )
    chain = load_chain(out.path, required=True)
    assert chain.adjustment["method"] == "affine"
    report = build_report(linear.to_json(), target.pixels, fitted, used, chain=chain)
    header = next(line for line in report.markdown.splitlines() if line.startswith("| parameter | fit |"))
    assert "median (posterior, adjusted)" in header and "looks the same" in header
    assert any(m.startswith("Posterior, adjusted") for m in report.data["intervals"]["meanings"])
    assert "The fit's ± (noise sandwich) against the posterior" in report.markdown
    assert not any("least squares" in w for w in report.data["warnings"])
    # the Huber fit set against that chain: the report says first that they differ
    report = build_report(result.to_json(), target.pixels, fitted, used, chain=chain)
    assert "but the fit minimised the huber loss" in report.data["warnings"][0]
