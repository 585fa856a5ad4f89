"""A capture's posterior and chain (``strauss-fit sample --fit CAPTURE_RESULT.json``): the
log-posterior against a hand computation, a short chain against the fit's Laplace ±, the
chain file, resuming, and the command line."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from data_synth.capture import example_capture_spec, write_capture
from strauss_fit.capture import capture_inputs, open_capture
from strauss_fit.fitting.capture import CaptureFitOptions
from strauss_fit.fitting.capture_result import fit_capture, predict, reload_capture_fit
from strauss_fit.inference.capture_posterior import (
    DEFAULT_VALUES,
    CapturePosterior,
    capture_chain_summary,
    capture_prior,
    sample_capture,
)
from strauss_fit.inference.sampler import ChainError, SampleSettings, load_chain
from strauss_fit_cli.main import main
from strauss_fit_cli.sample_cmd import _DEFAULT_VALUES

SMALL = dict(frame=(120, 96), center_px=(60.3, 47.8), radius_px=30.0)
#: m inside (0, 1), so that metalness has a two-sided interval.
MATERIAL = {"color": [0.75, 0.35, 0.18], "smoothness": 0.65, "metalness": 0.3}
#: A subsample of about a fifth of the capture's 92 k values.
SUBSAMPLE = 20_000


@pytest.fixture(scope="module")
def capture_fit(tmp_path_factory):
    """A small synthetic capture (12 images, 92 k usable values) and its fit's JSON."""
    folder = tmp_path_factory.mktemp("capture_posterior")
    spec = example_capture_spec("plastic", noise_sd=0.003, supersample=1, seed=5, material=MATERIAL, **SMALL)
    write_capture(spec, folder / "cap")
    # the capture's path recorded relative to the result's folder, as sample reads it
    inputs = capture_inputs(["cap"], None, None)
    result = fit_capture(open_capture([folder / "cap"]), CaptureFitOptions(), inputs=inputs)
    (folder / "fit.json").write_text(json.dumps(result))
    data = json.loads((folder / "fit.json").read_text())
    samples, fit = reload_capture_fit(data, base=folder)
    return folder, data, samples, fit


def _noise_laplace_sd(data, fit):
    """The fit's Laplace ± without the share of the sphere's circle, which the result adds to
    it (``uncertainty_circle``) and a chain, conditional on the circle, does not have."""
    sd = np.sqrt(np.diag(fit.laplace))
    circle = data.get("uncertainty_circle")
    if circle:
        share = np.concatenate([np.atleast_1d(np.asarray(circle[p.name], dtype=float)) for p in fit.params])
        sd = np.sqrt(sd**2 - share**2)
    return sd


def _rss(predicted, samples):
    """Σ (prediction − photograph)² over the usable values, in NumPy."""
    usable = np.asarray(samples.usable)
    return float(np.sum((np.asarray(predicted)[usable] - np.asarray(samples.values)[usable]) ** 2))


@pytest.mark.parametrize("values", [None, SUBSAMPLE])
def test_log_posterior_is_minus_half_rss_over_sigma_squared(capture_fit, values):
    _, data, samples, fit = capture_fit
    x_hat = fit.physical
    prior = capture_prior(fit.params, fit.labels, x_hat)
    post = CapturePosterior.build(samples, fit.model, fit.params, x_hat, prior, values=values)
    rss = _rss(fit.predicted, samples)
    count = int(np.asarray(samples.usable).sum())
    assert count == data["values_used"]
    # σ estimated from the fit's residual, sqrt(RSS/(N - P)); log p(θ̂) = -RSS/(2σ²) exactly
    assert post.sigma == pytest.approx(np.sqrt(rss / (count - len(x_hat))), rel=1e-9)
    assert post(x_hat) == pytest.approx(-0.5 * rss / post.sigma**2, rel=1e-9)
    assert post.subsampled == (values is not None)
    if values is not None:
        assert post.used < values and post.factor == pytest.approx(count / post.used)
    # the walkers' Gaussian is the fit's Laplace covariance (the noise's share)
    sd = _noise_laplace_sd(data, fit)
    assert np.sqrt(np.diag(post.laplace_covariance())) == pytest.approx(sd, rel=1e-6)
    # away from the fit: the exact likelihood is the hand computation's; the subsample's
    # difference estimator is within a small fraction of one unit of it one deviation away
    moved = x_hat + np.array([1.0, -1.0, 0.5, 1.0, -1.0, 0.5]) * sd
    by_hand = -0.5 * _rss(predict(samples, dataclasses.replace(fit, physical=moved))[0], samples) / post.sigma**2
    assert post(moved) == pytest.approx(by_hand, abs=1e-6 if values is None else 0.05)
    assert by_hand - post(x_hat) < -0.5  # and it is lower than at the optimum
    # outside the prior box: -inf (s > 1, m < 0, a negative exposure)
    outside = np.tile(x_hat, (3, 1))
    outside[0, 3], outside[1, 4], outside[2, 5] = 1.0 + 1e-9, -1e-9, -0.1
    assert np.all(post(outside) == -np.inf)
    # with σ given, the same RSS over the given σ²
    given = CapturePosterior.build(samples, fit.model, fit.params, x_hat, prior, 0.004, values=values)
    assert given(x_hat) == pytest.approx(-0.5 * rss / 0.004**2, rel=1e-9)


def test_prior_box(capture_fit):
    _, _, _, fit = capture_fit
    prior = capture_prior(fit.params, fit.labels, fit.physical, {"smoothness": (0.5, 0.8)})
    box = prior.as_dict()
    assert box["color_r"] == [0.0, 1.0] and box["smoothness"] == [0.5, 0.8]
    assert box["exposure"] == pytest.approx([0.0, 10 * fit.physical[5]])
    with pytest.raises(ValueError, match="leaves the range"):
        capture_prior(fit.params, fit.labels, fit.physical, {"metalness": (-0.1, 0.5)})
    with pytest.raises(ValueError, match="not a parameter"):
        capture_prior(fit.params, fit.labels, fit.physical, {"ior": (1.0, 2.0)})


def test_short_chain_matches_the_laplace_deviations_and_resumes(capture_fit):
    folder, data, _, fit = capture_fit
    chain_path = folder / "chain.h5"
    settings = SampleSettings(max_steps=600, min_tau_multiple=10, check_every=100, walkers=24, seed=3)
    result = sample_capture(folder / "fit.json", chain_path, settings=settings, values=SUBSAMPLE, adjust="none")
    summary = result.summary
    assert result.summary_path == folder / "chain.json"
    assert json.loads(result.summary_path.read_text())["kind"] == "capture"
    assert summary["labels"] == fit.labels
    assert summary["likelihood"]["subsampled"] and summary["likelihood"]["values_used"] < SUBSAMPLE
    assert "estimated" in summary["sigma_source"] and summary["adjustment"]["method"] == "none"  # as asked
    assert summary["uncertainty_method"] == "Laplace estimate"
    laplace_sd = _noise_laplace_sd(data, fit)
    assert summary["laplace"]["sd"] == pytest.approx(laplace_sd, rel=1e-6)  # what the chain is set against
    if data.get("uncertainty_circle"):  # the fit's ± add the circle's share, which the chain leaves out
        assert "conditional on where the sphere is" in summary["warnings"][0]
    for label in ("smoothness", "metalness"):
        k = fit.labels.index(label)
        p = summary["posterior"]["parameters"][label]
        assert 1 / 1.5 < p["sd"] / laplace_sd[k] < 1.5, (label, p["sd"], laplace_sd[k])
        assert abs(p["mean"] - fit.physical[k]) < 3 * p["sd"], (label, p["mean"], fit.physical[k])

    chain = load_chain(chain_path, required=True)
    assert chain.meta["kind"] == "capture" and chain.meta["fit"]["values"] == data["values"]
    assert chain.meta["fit_base"] == str(folder.resolve()) and chain.meta["likelihood"]["pixels"]
    assert chain.chain.shape == (600, 24, 6) and chain.labels == fit.labels
    brief = capture_chain_summary(chain)
    assert brief["labels"] == fit.labels and brief["adjustment"] == "none"
    p = brief["parameters"]["smoothness"]
    assert p["p2.5"] < p["p16"] < p["median"] < p["p84"] < p["p97.5"]

    # resuming continues the same chain (its σ, prior and subsample), the first steps untouched
    before = chain.chain.copy()
    more = sample_capture(None, chain_path, settings=dataclasses.replace(settings, max_steps=700), resume=True)
    after = load_chain(chain_path, required=True)
    assert more.run.new_steps == 100 and after.chain.shape == (700, 24, 6)
    assert np.array_equal(after.chain[:600], before)
    assert after.meta["sigma"] == chain.meta["sigma"]
    assert after.meta["likelihood"]["pixels"] == chain.meta["likelihood"]["pixels"]
    with pytest.raises(ChainError, match="--adjust cannot change"):
        sample_capture(None, chain_path, settings=settings, adjust="affine", resume=True)


def run_cli(capsys, *argv):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_sample_command_on_a_capture_result(capture_fit, capsys):
    folder = capture_fit[0]
    chain, summary = folder / "cli-chain.h5", folder / "cli-chain.json"
    code, out, err = run_cli(
        capsys,
        "sample",
        "--fit",
        folder / "fit.json",
        "-o",
        chain,
        "--max-steps",
        "500",
        "--min-tau-multiple",
        "5",
        "--walkers",
        "24",
        "--values",
        SUBSAMPLE,
    )
    assert code == 0, out + err
    assert chain.is_file() and summary.is_file()
    assert "sample [" in err and "likelihood: a fixed random subsample" in err
    # not a mismatch, but the circle's share of the exposure's ± outweighs the likelihood's
    # own: auto maps the chain to the image-cluster sandwich, which includes it
    assert "cluster ±" in out and "trustworthy" in out and "likelihood:" in out
    assert json.loads(summary.read_text())["adjustment"]["method"] == "affine"
    assert json.loads(summary.read_text())["kind"] == "capture"
    assert load_chain(chain, required=True).meta["kind"] == "capture"

    # a single image's inputs do not apply to a capture's result: one line, before any work
    code, out, err = run_cli(capsys, "sample", folder / "target.exr", "--fit", folder / "fit.json", "-o", chain)
    assert code == 2 and "TARGET does not apply to the capture's fit result" in err
    assert len(err.strip().splitlines()) == 1
    code, _, err = run_cli(capsys, "sample", "--fit", folder / "fit.json", "--scene", "s.toml", "-o", chain, "--force")
    assert code == 2 and "--scene does not apply" in err
    # nor --values to a single image
    code, _, err = run_cli(capsys, "sample", "t.exr", "--scene", "s.toml", "-o", folder / "x.h5", "--values", "100")
    assert code == 2 and "--values applies only to a capture's fit result" in err


def test_the_command_line_states_the_library_default():
    assert _DEFAULT_VALUES == DEFAULT_VALUES  # the help text's default (the command line starts without JAX)
