"""Coverage of the fit's intervals when the model cannot reproduce the target (issue 13.1).

The fit's ± under mismatch is the noise sandwich (:func:`strauss_fit.stats.laplace.problem_sandwich`):
the spread of the fitted values over fresh noise around the *pseudo-true* values — the fit to
the noise-free image. Here targets the Strauss model cannot reproduce (a Phong sphere, a
Mitsuba rough plastic) get many independent noise draws; the ±1.96 σ intervals must cover
the pseudo-truth at about 95 % and the ±1 σ ones at about 68 %, pooled over the parameters
(binomial bounds at ~3.5 standard errors, so the test fails by chance about once in a few
thousand runs). The Laplace intervals from RSS/(N − P), which count the misfit as noise,
are checked to be the wider ones there.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import strauss_fit as sf
import support

FREE = ("color", "smoothness", "metalness")


def pseudo_truth_and_draws(scene, clean, sigma, draws, seed):
    options = sf.FitOptions(noise=sigma, free=FREE, loss="linear", starts=1)
    truth = sf.fit(scene, clean, options)
    rng = np.random.default_rng(seed)
    results = []
    for _ in range(draws):
        noisy = clean.pixels + rng.normal(0.0, sigma, clean.pixels.shape)
        target = sf.Target(noisy, clean.usable, "draw", "linear", 0, 0)
        results.append(sf.fit(scene, target, options))
    return truth, results


def vector(result, key):
    values = getattr(result, key) if key != "x" else None
    if key == "x":
        return np.asarray(result.x, dtype=float)
    return np.concatenate([np.atleast_1d(np.asarray(values[name], dtype=float)) for name in FREE])


def coverage(truth, results, key="uncertainty", factor=1.0):
    star = vector(truth, "x")
    inside = []
    for result in results:
        sd = vector(result, key)
        usable = sd > 0  # entries pinned at a bound have no interval
        inside.append(np.where(usable, np.abs(vector(result, "x") - star) <= factor * sd, np.nan))
    inside = np.asarray(inside)
    return float(np.nanmean(inside)), int(np.sum(np.isfinite(inside)))


def check(truth, results):
    for factor, nominal in ((1.96, 0.95), (1.0, 0.683)):
        rate, trials = coverage(truth, results, factor=factor)
        bound = 3.5 * np.sqrt(nominal * (1 - nominal) / trials)
        assert abs(rate - nominal) <= bound + 0.02, (factor, rate, trials)
    assert all(r.uncertainty_method["name"] == "noise sandwich" for r in results)


def test_sandwich_intervals_cover_the_pseudo_truth_of_a_phong_sphere():
    scene = support.key_and_fill_scene(32, source="phong coverage")
    image, mask = sf.render_phong(scene, sf.PhongMaterial(kd=0.7, ks=0.3, exponent=20.0, diffuse_color=(0.8, 0.5, 0.3)))
    clean = sf.Target(np.asarray(image), np.ones(np.shape(image)[:2], dtype=bool), "phong", "linear", 0, 0)
    truth, results = pseudo_truth_and_draws(scene, clean, 0.01, 60, seed=11)
    assert truth.verdict == "mismatch"  # noise-free: the Phong misfit stands out against σ = 0.01
    check(truth, results)
    sandwich = np.mean([vector(r, "uncertainty") for r in results], axis=0)
    laplace = np.mean([vector(r, "uncertainty_laplace") for r in results], axis=0)
    assert np.all(laplace[sandwich > 0] >= sandwich[sandwich > 0])  # RSS counts the misfit as noise


def test_sandwich_intervals_cover_the_pseudo_truth_of_a_mitsuba_rough_plastic():
    folder = support.SCENES.parent / "bundled_mitsuba"
    sidecar = json.loads((folder / "mitsuba-roughplastic-blue-0000.json").read_text())
    scene = sf.parse_scene(sidecar["scene"]["definition"], base_dir=folder)
    clean = sf.load_target(folder / sidecar["files"]["exr"])  # Monte Carlo noise ~5e-5: nearly clean
    truth, results = pseudo_truth_and_draws(scene, clean, 0.005, 40, seed=12)
    check(truth, results)


@pytest.mark.parametrize("seed", [0])
def test_a_model_the_target_follows_gives_sandwich_and_laplace_alike(seed, key_and_fill):
    material = sf.Material(color=(0.6, 0.4, 0.3), smoothness=0.5, metalness=0.2)
    image, _ = sf.render(key_and_fill, material)
    noisy = np.asarray(image) + np.random.default_rng(seed).normal(0, 0.01, np.shape(image))
    target = sf.Target(noisy, np.ones(noisy.shape[:2], dtype=bool), "strauss", "linear", 0, 0)
    result = sf.fit(key_and_fill, target, sf.FitOptions(noise=0.01, free=FREE, loss="linear"))
    assert result.verdict == "consistent"
    np.testing.assert_allclose(vector(result, "uncertainty"), vector(result, "uncertainty_laplace"), rtol=0.1)
