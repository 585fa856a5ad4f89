"""Posterior summaries: the comparison rules of the fit's ± against the posterior (notes
that name the fit's kind of interval) and the degeneracy warnings in words, on synthetic
samples."""

import re

import numpy as np
import pytest

from strauss_fit.inference.summaries import (
    LAPLACE,
    SANDWICH,
    Laplace,
    compare,
    degeneracy_warnings,
    loss_warning,
    posterior_summary,
)


def laplace_of(x_hat, sd, at_bound=()):
    labels = [f"p{i}" for i in range(len(x_hat))]
    return Laplace(labels, np.asarray(x_hat, float), np.asarray(sd, float), np.eye(len(x_hat)), list(at_bound))


def compare_samples(laplace, samples, lower=0.0, upper=1.0):
    k = samples.shape[1]
    summary = posterior_summary(samples, laplace.labels)
    return compare(laplace, summary, samples, np.full(k, lower), np.full(k, upper))


def test_gaussian_posterior_matching_laplace_raises_no_note():
    rng = np.random.default_rng(0)
    samples = rng.normal([0.5, 0.3], [0.02, 0.01], size=(40000, 2))
    rows, notes = compare_samples(laplace_of([0.5, 0.3], [0.02, 0.01]), samples)
    assert notes == [] and all(r.issues == [] for r in rows)
    assert rows[0].width_ratio == pytest.approx(1.0, abs=0.03)


def test_wider_posterior_shift_and_skew_are_named():
    rng = np.random.default_rng(1)
    wide = rng.normal(0.5, 0.04, size=(40000, 1))
    rows, notes = compare_samples(laplace_of([0.5], [0.02]), wide)
    assert rows[0].issues == ["width"] and re.search(r"the posterior is 1\.9\d times as wide as", notes[0])
    shifted = rng.normal(0.52, 0.02, size=(40000, 1))
    rows, notes = compare_samples(laplace_of([0.5], [0.02]), shifted)
    assert "shift" in rows[0].issues and "1.0 posterior standard deviations" in " ".join(notes)
    skewed = 0.4 + rng.lognormal(np.log(0.05), 0.6, size=(40000, 1))
    rows, notes = compare_samples(laplace_of([0.45], [0.03]), skewed)
    assert "skew" in rows[0].issues and "upper tail" in " ".join(notes)


def test_a_posterior_cut_by_a_bound_gets_a_one_sided_limit():
    rng = np.random.default_rng(2)
    pinned = np.abs(rng.normal(0.0, 0.02, size=(40000, 1)))  # the fit put m on 0
    rows, notes = compare_samples(laplace_of([0.0], [0.0], at_bound=["p0"]), pinned)
    assert rows[0].issues == ["bound"]
    assert "one-sided with a 95 % upper limit of 0.04" in notes[0]
    near = rng.normal(0.99, 0.01, size=(80000, 1))
    near = near[near <= 1.0][:, None]  # truncated at the upper bound 1
    rows, notes = compare_samples(laplace_of([0.99], [0.01]), near)
    assert "bound" in rows[0].issues and "runs into the bound 1" in notes[0] and "lower limit" in notes[0]


def test_a_width_due_to_a_pinned_partner_is_blamed_on_it():
    # the fit pinned p0 on 0; p1 moves with p0 in the posterior, so the Laplace deviation of
    # p1 (p0 held fixed) is too small, and not because of any non-linearity
    rng = np.random.default_rng(6)
    p0 = np.abs(rng.normal(0.0, 0.02, 40000))
    p1 = 0.5 + p0 + rng.normal(0, 0.005, 40000)
    rows, notes = compare_samples(laplace_of([0.0, 0.5], [0.0, 0.005], at_bound=["p0"]), np.column_stack([p0, p1]))
    assert "width" in rows[1].issues
    width_note = next(n for n in notes if n.startswith("p1: the posterior is"))
    assert "the Laplace estimate holds p0 fixed on its bound" in width_note and "not linear" not in width_note


def test_the_notes_name_the_fits_interval():
    # a fit whose ± is the noise sandwich: its notes must not call it the Laplace estimate
    rng = np.random.default_rng(7)
    on_bound = np.abs(rng.normal(0.0, 0.02, size=(40000, 1)))
    sandwich = Laplace(["p0"], np.array([0.0]), np.array([0.0]), np.eye(1), ["p0"], SANDWICH)
    _, notes = compare_samples(sandwich, on_bound)
    assert "where the noise sandwich gives no interval" in notes[0] and "Laplace" not in notes[0]
    wide = rng.normal(0.5, 0.04, size=(40000, 1))
    _, notes = compare_samples(Laplace(["p0"], np.array([0.5]), np.array([0.02]), np.eye(1), [], SANDWICH), wide)
    assert "times as wide as the noise sandwich" in notes[0] and "Laplace" not in notes[0]
    # the name comes from the fit's uncertainty_method
    fit = {"color": [0.5] * 3, "smoothness": 0.5, "metalness": 0.0, "transparency": 0.0, "ior": 1.5}
    fit.update(free=["smoothness"], uncertainty={"smoothness": 0.01})
    assert Laplace.from_fit({**fit, "uncertainty_method": {"name": "noise sandwich"}}).method == SANDWICH
    assert Laplace.from_fit({**fit, "uncertainty_method": {"name": "laplace"}}).method == LAPLACE
    assert Laplace.from_fit(fit).method == LAPLACE
    # a fit with another loss than the chain's least squares is named; a least-squares one
    # (or one written before fits had a choice of loss) is not
    assert "huber loss" in loss_warning({**fit, "solver": {"loss": "huber"}})
    assert loss_warning({**fit, "solver": {"loss": "linear"}}) is None and loss_warning(fit) is None


def test_a_banana_shaped_posterior_is_named():
    rng = np.random.default_rng(3)
    a = rng.normal(0.5, 0.05, 40000)
    b = 0.3 + 20 * (a - 0.5) ** 2 + rng.normal(0, 0.005, 40000)
    rows, notes = compare_samples(laplace_of([0.5, 0.35], [0.05, 0.05]), np.column_stack([a, b]))
    assert any("banana-shaped" in n and "p0" in n and "p1" in n for n in notes)


# --- degeneracy warnings ------------------------------------------------------------------------


def test_transparency_trading_with_the_brightness_of_c_is_said_in_words():
    # t moves with the overall brightness of C; no single channel pair is the story
    rng = np.random.default_rng(4)
    brightness = rng.normal(0, 1, 20000)
    channels = [brightness + 0.2 * rng.normal(size=20000) for _ in range(3)]
    t = brightness + 0.1 * rng.normal(size=20000)
    s = rng.normal(size=20000)
    samples = np.column_stack(channels + [s, t]) * 0.1 + 0.5  # deviations 0.1: loose
    labels = ["color_r", "color_g", "color_b", "smoothness", "transparency"]
    held = {
        "ior": {"value": 1.5, "reason": "no refraction is traced"},
        "metalness": {"value": 0.0, "reason": "fixed by the user (--fix)"},
    }
    warnings = degeneracy_warnings(labels, np.cov(samples, rowvar=False), held)
    assert warnings[0].startswith("t (transparency) and the brightness of C trade off")
    assert "this scene cannot separate them" in warnings[0]
    # channel-against-channel and channel-against-t pairs are explained by the first warning
    assert not any("channel of C" in w for w in warnings)
    assert any(w.startswith("n (index of refraction) was not fitted: no refraction is traced") for w in warnings)
    assert not any("m (metalness)" in w for w in warnings)  # the user's own choice is not a warning
    independent = np.random.default_rng(5).normal(size=(20000, 5))
    assert degeneracy_warnings(labels, np.cov(independent, rowvar=False)) == []
