"""The sampler's adjustment to the fit's noise sandwich (issue 13.1, ``sample --adjust``):
the algebra by hand, then whole chains — on a Phong sphere (which Strauss cannot reproduce)
the affine adjustment gives the sandwich's per-parameter widths within the chain's Monte
Carlo error, on draws the adjustment matrix was not computed from; on a Strauss target the
chain already has those widths and the adjustment is close to the identity; the
temperature is never narrower than the sandwich, also with entries pinned at a bound, and
never below 1; a fit made with another loss than least squares is refused (and the fit
sample makes itself is least squares); the CLI's option and messages."""

from __future__ import annotations

import json

import numpy as np
import pytest

import strauss_fit as sf
import support
from strauss_fit.inference.adjustment import (
    adjust_samples,
    adjustment_matrix,
    default_method,
    full_matrix,
    generalized_eigenvalues,
    temperature,
)
from strauss_fit.inference.sampler import ChainError, SampleSettings, burn_in, load_chain, sample
from strauss_fit.io.images import write_image
from strauss_fit_cli.main import main

pytestmark = pytest.mark.usefixtures("x64")

FREE = ("color", "smoothness", "metalness")
NOISE = 0.01
SETTINGS = SampleSettings(max_steps=1500, walkers=32, seed=1, min_tau_multiple=1000)  # runs to max_steps


# --- the algebra ------------------------------------------------------------------------------


def random_spd(rng, size):
    m = rng.normal(size=(size, size))
    return m @ m.T + 0.1 * np.eye(size)


def test_adjustment_matrix_maps_the_chain_covariance_onto_the_target_exactly():
    rng = np.random.default_rng(0)
    post, target = random_spd(rng, 4), random_spd(rng, 4)
    a = adjustment_matrix(post, target)
    np.testing.assert_allclose(a @ post @ a.T, target, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(adjustment_matrix(post, post), np.eye(4), atol=1e-12)  # nothing to do
    # on draws: their own covariance as Σ_post gives exactly V
    draws = rng.multivariate_normal(np.zeros(4), post, size=5000)
    moved, dropped = adjust_samples(draws, np.zeros(4), full_matrix(draws, target), -np.inf, np.inf)
    assert dropped == 0
    np.testing.assert_allclose(np.cov(moved, rowvar=False), target, rtol=1e-9, atol=1e-12)


def test_temperature_is_the_largest_generalised_eigenvalue_by_hand():
    # diagonal case: the variance ratios are the eigenvalues, T the largest of them
    post, target = np.diag([1.0, 4.0, 0.25]), np.diag([2.0, 2.0, 1.0])
    np.testing.assert_allclose(generalized_eigenvalues(post, target), [0.5, 2.0, 4.0])
    t = temperature(post, target)
    assert t == pytest.approx(4.0)
    # T Σ_post - V is positive semi-definite (no interval narrower than the sandwich's), and
    # singular: in one direction it is exactly as wide
    rng = np.random.default_rng(1)
    post, target = random_spd(rng, 5), random_spd(rng, 5)
    assert generalized_eigenvalues(post, target)[-1] > 1
    gap = np.linalg.eigvalsh(temperature(post, target) * post - target)
    assert gap.min() == pytest.approx(0.0, abs=1e-9 * gap.max()) and gap.min() > -1e-9 * gap.max()


def test_temperature_never_narrows_a_chain_already_wider_than_the_sandwich():
    # every variance ratio below 1 (largest 0.25): the chain is wider than V in every
    # direction, and T = 0.25 would halve its intervals, making them narrower than V's
    post, target = np.diag([1.0, 4.0]), np.diag([0.25, 0.5])
    assert generalized_eigenvalues(post, target)[-1] == pytest.approx(0.25)
    assert temperature(post, target) == 1.0
    assert np.linalg.eigvalsh(temperature(post, target) * post - target).min() > 0


def test_adjusted_draws_outside_the_prior_are_dropped_and_counted():
    # A = 2 I about 0.5: 0.2 -> -0.1 (out), 0.4 -> 0.3, 0.6 -> 0.7, 0.9 -> 1.3 (out)
    draws = np.array([[0.2], [0.4], [0.6], [0.9]])
    kept, dropped = adjust_samples(draws, np.array([0.5]), np.array([[2.0]]), np.array([0.0]), np.array([1.0]))
    np.testing.assert_allclose(kept.ravel(), [0.3, 0.7])
    assert dropped == 2


def test_entries_pinned_at_a_bound_are_not_adjusted():
    rng = np.random.default_rng(2)
    draws = rng.normal(size=(4000, 3)) * [1.0, 2.0, 3.0]
    target = np.diag([4.0, 0.0, 1.0])  # the middle entry was pinned by the fit: V = 0 there
    a = full_matrix(draws, target)
    assert a[1, 1] == 1.0 and a[1, [0, 2]].tolist() == [0.0, 0.0] and a[[0, 2], 1].tolist() == [0.0, 0.0]
    moved, _ = adjust_samples(draws, np.zeros(3), a, -np.inf, np.inf)
    np.testing.assert_allclose(moved.std(axis=0, ddof=1), [2.0, draws[:, 1].std(ddof=1), 1.0], rtol=1e-9)


def test_the_default_is_affine_only_for_a_sandwich_under_mismatch():
    sandwich = {"name": "noise sandwich"}
    assert default_method({"uncertainty_method": sandwich, "residual": {"verdict": "mismatch"}})[0] == "affine"
    assert default_method({"uncertainty_method": sandwich, "residual": {"verdict": "consistent"}})[0] == "none"
    assert default_method({"uncertainty_method": {"name": "laplace"}, "residual": {"verdict": "mismatch"}})[0] == "none"


# --- whole chains -------------------------------------------------------------------------------


def write_case(folder, kind, seed=3):
    scene = support.key_and_fill_scene(32, source=kind)
    (folder / "scene.toml").write_text(support.key_and_fill_toml(32, material=support.SMALL_MATERIAL))
    if kind == "phong":
        image, _ = sf.render_phong(
            scene, sf.PhongMaterial(kd=0.7, ks=0.3, exponent=20.0, diffuse_color=(0.8, 0.5, 0.3))
        )
    else:
        image, _ = sf.render(scene, sf.Material(color=(0.6, 0.4, 0.3), smoothness=0.5, metalness=0.2))
    pixels = np.asarray(image) + np.random.default_rng(seed).normal(0, NOISE, np.shape(image))
    write_image(folder / f"{kind}.exr", pixels)
    target = sf.load_target(folder / f"{kind}.exr")
    loaded, _ = sf.match_scene(sf.load_scene(folder / "scene.toml"), target)
    result = sf.fit(loaded, target, sf.FitOptions(noise=NOISE, free=FREE, loss="linear"))
    return result


@pytest.fixture(scope="module")
def phong_chain(tmp_path_factory):
    folder = tmp_path_factory.mktemp("phong")
    result = write_case(folder, "phong")
    assert result.verdict == "mismatch" and result.uncertainty_method["name"] == "noise sandwich"
    out = sample(folder / "phong.exr", folder / "scene.toml", folder / "chain.h5", fit=result, settings=SETTINGS)
    return folder, result, out


def fit_covariance(chain):
    return np.asarray(chain.meta["adjustment"]["target_covariance"])


def halves(chain):
    """The draws after burn-in of the first and of the second half of the walkers."""
    discard = burn_in(np.asarray(chain.diagnostics().tau), chain.chain.shape[0])
    walkers = chain.chain.shape[1]
    size = chain.chain.shape[-1]
    return (
        chain.chain[discard:, : walkers // 2].reshape(-1, size),
        chain.chain[discard:, walkers // 2 :].reshape(-1, size),
        discard,
    )


def test_affine_adjustment_gives_the_sandwich_widths_on_a_phong_target(phong_chain):
    folder, result, out = phong_chain
    chain = load_chain(out.path, required=True)
    assert chain.adjustment["method"] == "affine" and "mismatch" in chain.adjustment["reason"]
    # the likelihood's sigma is the noise the fit knew, not RSS/(N - P), which counts the misfit
    assert chain.meta["sigma"] == pytest.approx(NOISE, rel=1e-9) and "noise" in chain.meta["sigma_source"]
    target = fit_covariance(chain)
    sd_fit = np.sqrt(np.diag(target))
    used = sd_fit > 0
    assert used.sum() >= 4
    # A computed from one half of the walkers, applied to the other half: a check on draws
    # the matrix was not made from. Their widths match the sandwich's within the Monte Carlo
    # error of a standard deviation from that half's effective samples, sd / sqrt(2 ESS).
    first, second, _ = halves(chain)
    ess = np.asarray(chain.diagnostics().ess)[used] / 2
    moved, _ = adjust_samples(second, np.asarray(chain.meta["x_hat"]), full_matrix(first, target), -np.inf, np.inf)
    ratio = moved.std(axis=0, ddof=1)[used] / sd_fit[used]
    np.testing.assert_array_less(np.abs(ratio - 1), 4 / np.sqrt(2 * ess))
    # ... while the raw chain's widths are off by more than that: the adjustment matters here
    raw = second.std(axis=0, ddof=1)[used] / sd_fit[used]
    assert np.max(np.abs(raw - 1)) > 0.2
    # what the summary reports: the adjusted chain, draws dropped counted
    summary = json.loads(out.summary_path.read_text())
    adjustment = summary["adjustment"]
    assert adjustment["method"] == "affine" and adjustment["dropped"] + adjustment["kept"] == second.shape[0] * 2
    np.testing.assert_allclose(np.asarray(adjustment["sd_adjusted"])[used], sd_fit[used], rtol=0.05)
    for k, label in enumerate(summary["labels"]):
        assert summary["posterior"]["parameters"][label]["sd"] == pytest.approx(adjustment["sd_adjusted"][k])
    assert summary["fit_verdict"] == "mismatch" and summary["uncertainty_method"] == "noise sandwich"
    assert any(w["code"] == "model-mismatch" for w in summary["fit_warnings"])


def test_the_raw_chain_is_kept_and_the_matrix_stored(phong_chain):
    folder, result, out = phong_chain
    chain = load_chain(out.path, required=True)
    info = chain.adjustment
    assert info["steps"] == chain.chain.shape[0] and len(info["matrix"]) == chain.chain.shape[-1]
    discard = info["burn_in"]
    raw = chain.samples(discard, adjusted=False)
    np.testing.assert_array_equal(raw, chain.chain[discard:].reshape(-1, raw.shape[1]))  # untouched
    adjusted, dropped = chain.adjusted(discard)
    center, matrix = np.asarray(info["center"]), np.asarray(info["matrix"])
    expected = center + (raw - center) @ matrix.T
    prior = chain.meta["prior"]
    lower = np.array([prior[label][0] for label in chain.labels])
    upper = np.array([prior[label][1] for label in chain.labels])
    inside = np.all((expected >= lower) & (expected <= upper), axis=1)
    assert dropped == int(np.sum(~inside)) == info["dropped"]
    np.testing.assert_allclose(adjusted, expected[inside], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(chain.samples(discard), adjusted)


def test_a_resumed_chain_keeps_its_adjustment(phong_chain, tmp_path):
    folder, result, out = phong_chain
    import shutil

    copy = tmp_path / "chain.h5"
    shutil.copy(out.path, copy)
    with pytest.raises(ChainError, match="--adjust cannot change when resuming"):
        sample(folder / "phong.exr", folder / "scene.toml", copy, resume=True, adjust="none", settings=SETTINGS)
    longer = sample(
        folder / "phong.exr",
        folder / "scene.toml",
        copy,
        resume=True,
        settings=SampleSettings(max_steps=1600, walkers=32, seed=1, min_tau_multiple=1000),
    )
    chain = load_chain(longer.path, required=True)
    assert chain.chain.shape[0] == 1600 and chain.adjustment["steps"] == 1600
    np.testing.assert_array_equal(chain.chain[:1500], load_chain(out.path).chain)  # raw steps unchanged


def test_without_mismatch_the_adjustment_is_close_to_the_identity(tmp_path):
    result = write_case(tmp_path, "strauss")
    assert result.verdict == "consistent" and result.uncertainty_method["name"] == "noise sandwich"
    auto = sample(
        tmp_path / "strauss.exr", tmp_path / "scene.toml", tmp_path / "auto.h5", fit=result, settings=SETTINGS
    )
    assert auto.summary["adjustment"]["method"] == "none"  # the default leaves a consistent fit alone
    forced = sample(
        tmp_path / "strauss.exr",
        tmp_path / "scene.toml",
        tmp_path / "forced.h5",
        fit=result,
        settings=SETTINGS,
        adjust="affine",
    )
    chain = load_chain(forced.path, required=True)
    target = fit_covariance(chain)
    discard = chain.adjustment["burn_in"]
    raw = chain.samples(discard, adjusted=False)
    adjusted = chain.samples(discard)
    ess = np.asarray(chain.diagnostics().ess)
    # the chain already has the sandwich's widths, so the adjustment changes them by no
    # more than the Monte Carlo error of a standard deviation
    ratio = adjusted.std(axis=0, ddof=1) / raw.std(axis=0, ddof=1)
    np.testing.assert_array_less(np.abs(ratio - 1), 4 / np.sqrt(2 * ess))
    np.testing.assert_allclose(np.sqrt(np.diag(target)), raw.std(axis=0, ddof=1), rtol=0.1)


def test_temperature_is_never_narrower_than_the_sandwich(phong_chain, tmp_path):
    folder, result, _ = phong_chain
    out = sample(
        folder / "phong.exr",
        folder / "scene.toml",
        tmp_path / "tempered.h5",
        fit=result,
        settings=SETTINGS,
        adjust="temperature",
    )
    chain = load_chain(out.path, required=True)
    info = chain.adjustment
    assert info["method"] == "temperature" and info["temperature"] > 1
    assert chain.meta["sigma"] == pytest.approx(info["sigma_untempered"] * np.sqrt(info["temperature"]))
    target = fit_covariance(chain)
    used = np.diag(target) > 0
    samples = chain.samples(info.get("burn_in"))
    np.testing.assert_array_equal(samples, chain.samples(None, adjusted=False))  # nothing mapped on read
    ess = np.asarray(chain.diagnostics().ess)[used]
    ratio = samples.std(axis=0, ddof=1)[used] / np.sqrt(np.diag(target))[used]
    assert np.all(ratio > 1 - 4 / np.sqrt(2 * ess))


def test_affine_needs_the_fits_noise_sandwich(phong_chain, tmp_path):
    folder, result, _ = phong_chain
    fit_json = result.to_json()
    fit_json["uncertainty_method"] = {"name": "laplace"}
    with pytest.raises(ChainError, match="needs|Laplace approximation"):
        sample(
            folder / "phong.exr",
            folder / "scene.toml",
            tmp_path / "c.h5",
            fit=fit_json,
            settings=SETTINGS,
            adjust="affine",
        )


def test_sample_command_prints_the_adjustment_the_verdict_and_the_warnings(phong_chain, capsys, tmp_path):
    folder, result, _ = phong_chain
    fit_path = tmp_path / "fit.json"
    fit_path.write_text(json.dumps({**result.to_json(), "target": "phong.exr"}))
    base = ["sample", folder / "phong.exr", "--scene", folder / "scene.toml", "-o", tmp_path / "cli.h5", "--quiet"]
    code = main([str(a) for a in base + ["--fit", fit_path, "--max-steps", "300", "--walkers", "32"]])
    out = capsys.readouterr().out
    assert code in (0, 1)
    assert "adjusted (affine) to the fit's noise sandwich" in out
    assert "fit verdict: mismatch" in out and "fit warning [model-mismatch]" in out
    assert "sandwich ±" in out
    # changing --adjust on resume is refused in one line
    code = main([str(a) for a in base + ["--resume", "--adjust", "none"]])
    assert code == 2 and "--adjust cannot change when resuming" in capsys.readouterr().err


# --- temperature with entries pinned at a bound; fits with another loss -------------------------

BUNDLED = support.SCENES.parent / "bundled"


def test_temperature_with_entries_pinned_at_a_bound_is_never_narrower_than_the_sandwich(tmp_path):
    # A Phong highlight Strauss cannot reproduce, fitted by least squares: C is pinned at 1 in
    # red and green and m at 0. V holds those entries there; the full Laplace covariance lets
    # them move, so its block on the free entries is wider than the chain and gave T = 0.047,
    # a chain 4 times narrower than the sandwich (the docs writer's repro).
    target_path, scene_path = BUNDLED / "phong-noisy-0002.exr", support.SCENES / "two_lights.toml"
    target = sf.load_target(target_path)
    scene, _ = sf.match_scene(sf.load_scene(scene_path), target)
    result = sf.fit(scene, target, sf.FitOptions(loss="linear"))
    assert result.verdict == "mismatch" and {"color_r", "color_g", "metalness"} <= set(result.at_bound)
    settings = SampleSettings(max_steps=1000, walkers=32, seed=1, min_tau_multiple=1000)
    out = sample(target_path, scene_path, tmp_path / "t.h5", fit=result, settings=settings, adjust="temperature")
    chain = load_chain(out.path, required=True)
    info = chain.adjustment
    assert info["temperature"] >= 1
    assert chain.meta["sigma"] >= info["sigma_untempered"]
    target_cov = fit_covariance(chain)
    used = np.diag(target_cov) > 0
    assert used.sum() == 2  # the blue channel and s
    samples = chain.samples()
    ess = np.asarray(chain.diagnostics().ess)[used]
    ratio = samples.std(axis=0, ddof=1)[used] / np.sqrt(np.diag(target_cov))[used]
    assert np.all(ratio > 1 - 4 / np.sqrt(2 * ess)), ratio


def huber_fit(folder):
    target = sf.load_target(folder / "phong.exr")
    loaded, _ = sf.match_scene(sf.load_scene(folder / "scene.toml"), target)
    return sf.fit(loaded, target, sf.FitOptions(noise=NOISE, free=FREE, loss="huber"))


def test_a_fit_made_with_another_loss_is_refused(phong_chain, tmp_path, capsys):
    # the likelihood is least squares: a Huber fit's optimum is not the chain's, and its
    # sandwich is the Huber fit's spread, so neither the start nor the adjustment fits
    folder, _, _ = phong_chain
    huber = huber_fit(folder)
    assert huber.solver["loss"] == "huber"
    with pytest.raises(ChainError, match="huber loss, but sample's likelihood is least squares.*--loss linear"):
        sample(folder / "phong.exr", folder / "scene.toml", tmp_path / "c.h5", fit=huber, settings=SETTINGS)
    fit_path = tmp_path / "huber.json"
    fit_path.write_text(json.dumps({**huber.to_json(), "target": "phong.exr"}))
    argv = ["sample", folder / "phong.exr", "--scene", folder / "scene.toml", "-o", tmp_path / "h.h5"]
    argv += ["--fit", fit_path]
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert code == 2 and "--loss linear" in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "h.h5").exists()


def test_sample_fits_first_by_least_squares(phong_chain, tmp_path, monkeypatch):
    # the fit loss "auto" switches to Huber on a visible mismatch: not for the fit sample makes
    import strauss_fit.inference.sampler._workflow as sampler_module

    folder, _, _ = phong_chain
    losses = []

    class Fitted(Exception):
        pass

    def fit_and_stop(scene, target, options, progress=None):
        losses.append(options.loss)
        raise Fitted

    monkeypatch.setattr(sampler_module, "run_fit", fit_and_stop)
    with pytest.raises(Fitted):
        sample(folder / "phong.exr", folder / "scene.toml", tmp_path / "own.h5", settings=SETTINGS)
    assert losses == ["linear"]
    with pytest.raises(ChainError, match="least squares"):
        sample(
            folder / "phong.exr",
            folder / "scene.toml",
            tmp_path / "own.h5",
            fit_options=sf.FitOptions(loss="huber"),
            settings=SETTINGS,
        )
    assert losses == ["linear"]  # refused before fitting


def test_a_chain_of_a_huber_fit_is_named_in_its_summary_and_not_resumed(phong_chain, tmp_path):
    # chains written before such fits were refused: the summary says what the chain is
    import shutil

    from strauss_fit.inference.sampler import write_metadata
    from strauss_fit.inference.summaries import summarise_chain

    folder, _, out = phong_chain
    copy = tmp_path / "old.h5"
    shutil.copy(out.path, copy)
    chain = load_chain(copy, required=True)
    meta = json.loads(json.dumps(chain.meta))
    meta["fit"]["solver"]["loss"] = "huber"
    write_metadata(copy, meta)
    assert "least squares" not in " ".join(summarise_chain(load_chain(out.path, required=True))["warnings"])
    warnings = summarise_chain(load_chain(copy, required=True))["warnings"]
    assert "likelihood is least squares, but the fit minimised the huber loss" in warnings[0]
    with pytest.raises(ChainError, match="huber loss.*--loss linear"):
        sample(folder / "phong.exr", folder / "scene.toml", copy, resume=True, settings=SETTINGS)
