"""Coverage of a robust (Huber) fit's intervals when the model cannot reproduce the target (issue 27.5).

A Huber fit is an M-estimator: with fresh noise it scatters around its own pseudo-truth

    θ* = argmin_θ  E_ε Σ ρ((f(θ) − g − ε)/σ),

g the noise-free image, not around the Huber fit of g. The noise smooths ρ wherever the
misfit is near Huber's threshold (E ρ(r + ε) ≠ ρ(r)), so under a mismatch the two differ:
on the Phong sphere here by about two deviations in s and m, and there the intervals cover
the noise-free Huber fit at 6–13 % for a nominal 68 % (the issue's 8–16 %) while covering θ*
at the nominal rate. θ* is computed here directly: for Gaussian ε, E ρ(r + ε) has a closed
form (:func:`expected_huber`), minimised by Newton's method.

Statistics. DRAWS independent noise draws; for each free entry the number of draws whose
±1σ (±1.96σ) interval holds θ* is binomial(DRAWS, p). The checks, per entry:

- at least the nominal rate (0.683, 0.95) less 3.5 binomial standard errors (0.16 and 0.08
  for 100 draws): what a centre off by the issue's ~2σ, or a ± too narrow, fails;
- at most the rate of intervals 1.25 times as wide as exact ones (0.79 at ±1σ) plus 3.5 of
  its standard errors (0.93): the ± is meant to be a little conservative (per value the
  meat uses E[ψ′(z + ε)²] σ², which for Gaussian noise bounds Var ψ(z + ε) from above; the
  spread over draws measured 0.82–0.90 of the mean ± at σ ≤ 0.01, see docs/uncertainty.md),
  not wider.

3.5 standard errors is a one-sided normal tail of 2·10⁻⁴ per check. Intervals 1.1–1.2 times
the spread, as measured, cover at 0.73–0.78 and 0.97–0.98 per entry, and an entry then fails
by chance with a binomial probability of about 10⁻⁵ (exact intervals: 2·10⁻³). The seeds are
fixed, so the outcome is reproducible. 100 draws are enough to tell right from wrong:
against the noise-free Huber fit the same intervals cover s and m at 0.06–0.13, ten standard
errors below the lower bound, and the test checks that this wrong reference fails — so it
can fail. Intervals twice too narrow (1σ coverage 0.38) fail the lower bound, three times
too wide (1.00) the upper; twice too wide (0.95) fails it eight times in ten.
The deterministic test at the end checks
the meat itself, which a coverage test of 100 draws cannot resolve to 10 %.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.scipy.stats import norm

import strauss_fit as sf
import support
from strauss_fit.fitting.problem import HUBER_K, build_problem
from strauss_fit.rendering.strauss import plan_render
from strauss_fit.stats.laplace import objective_terms

FREE = ("color", "smoothness", "metalness")
SIGMA = 0.01
DRAWS = 100
#: The intervals checked (± this many deviations) and their nominal rates.
LEVELS = ((1.0, 0.683), (1.96, 0.95))
#: The binomial tolerance, in standard errors, of each bound.
TOLERANCE_SE = 3.5
#: The widest the ± may be, relative to exact intervals (its documented conservatism).
CONSERVATIVE = 1.25


def phong_target(size: int) -> tuple[sf.Scene, sf.Target]:
    """A Phong sphere (a highlight no Strauss material reproduces) in the key-and-fill scene."""
    scene = support.key_and_fill_scene(size, source="phong robust coverage")
    image, _ = sf.render_phong(scene, sf.PhongMaterial(kd=0.7, ks=0.3, exponent=20.0, diffuse_color=(0.8, 0.5, 0.3)))
    clean = sf.Target(np.asarray(image), np.ones(np.shape(image)[:2], dtype=bool), "phong", "linear", 0, 0)
    return scene, clean


def expected_huber(r):
    """E ρ(r + ε) for ε ~ N(0, 1), ρ Huber's with k = HUBER_K: the quadratic part over
    ε ∈ [−k − r, k − r] and the two linear tails, each by the Gaussian integrals of 1, ε, ε²."""
    k = HUBER_K
    a, b = -k - r, k - r
    cdf_a, cdf_b, pdf_a, pdf_b = norm.cdf(a), norm.cdf(b), norm.pdf(a), norm.pdf(b)
    inner = 0.5 * ((r * r + 1) * (cdf_b - cdf_a) + 2 * r * (pdf_a - pdf_b) - (b * pdf_b - a * pdf_a))
    upper = (k * r - 0.5 * k * k) * (1 - cdf_b) + k * pdf_b
    lower = (-k * r - 0.5 * k * k) * cdf_a + k * pdf_a
    return inner + upper + lower


def test_the_expected_huber_loss_is_the_monte_carlo_mean():
    r = np.linspace(-6.0, 6.0, 25)
    noise = np.random.default_rng(3).normal(size=(200_000, 1))
    z = np.abs(r + noise)
    mc = np.where(z <= HUBER_K, 0.5 * z * z, HUBER_K * z - 0.5 * HUBER_K**2).mean(axis=0)
    with sf.float64():
        exact = np.asarray(expected_huber(jnp.asarray(r)))
    # the Monte Carlo mean's standard error is below 0.03 at |r| = 6
    np.testing.assert_allclose(exact, mc, atol=4 * np.max(np.abs(r) + 1) / np.sqrt(noise.size))


def robust_pseudo_truth(clean_fit: sf.FitResult) -> np.ndarray:
    """θ* of the Huber fit: the minimiser of the expected loss over the entries the noise-free
    fit left free (those it pinned at a bound stay there), by Newton's method from that fit."""
    problem = clean_fit.problem.unpadded()
    x0 = np.asarray(clean_fit.x, dtype=float)
    free = np.flatnonzero(~np.asarray(problem.pinned))
    with sf.float64():

        def cost(values):
            x = jnp.asarray(x0).at[free].set(values)
            return jnp.sum(expected_huber((problem.render_physical(x) - problem.target) / SIGMA))

        # one compiled call for both (each compilation costs seconds)
        newton = jax.jit(lambda v: (jax.grad(cost)(v), jax.hessian(cost)(v)))
        values = x0[free]
        for _ in range(20):
            gradient, hessian = newton(values)
            step = np.linalg.solve(np.asarray(hessian), np.asarray(gradient))
            values = values - step
            if np.max(np.abs(step)) < 1e-10:
                break
        else:
            raise AssertionError(f"Newton's method did not converge (last step {step})")
    star = x0.copy()
    star[free] = values
    return star


def coverage(results: list[sf.FitResult], reference: np.ndarray) -> dict[float, np.ndarray]:
    """Per interval factor, the share of draws whose interval holds ``reference``, per entry
    (NaN for an entry that never had an interval: pinned at a bound)."""
    x = np.array([np.asarray(r.x, dtype=float) for r in results])
    sd = np.array([np.concatenate([np.atleast_1d(r.uncertainty[n]) for n in FREE]).astype(float) for r in results])
    usable = sd > 0  # an entry pinned at a bound has no interval
    out = {}
    for factor, _ in LEVELS:
        inside = np.abs(x - reference) <= factor * sd
        with np.errstate(invalid="ignore"):
            out[factor] = np.sum(inside & usable, axis=0) / np.sum(usable, axis=0)
    return out


def within_bounds(rates: dict[float, np.ndarray], trials: int) -> bool:
    """Every entry's rate at least nominal and at most that of intervals CONSERVATIVE times
    too wide, each less or more TOLERANCE_SE binomial standard errors (module docstring)."""
    checks = []
    for factor, nominal in LEVELS:
        wide = math.erf(CONSERVATIVE * factor / math.sqrt(2))  # P(|Z| < 1.25 factor)
        low = nominal - TOLERANCE_SE * math.sqrt(nominal * (1 - nominal) / trials)
        high = wide + TOLERANCE_SE * math.sqrt(wide * (1 - wide) / trials)
        rate = rates[factor][np.isfinite(rates[factor])]
        checks.append(np.all((rate >= low) & (rate <= high)))
    return bool(all(checks))


@pytest.mark.slow
def test_huber_intervals_cover_the_robust_pseudo_truth_of_a_phong_sphere():
    scene, clean = phong_target(32)
    # edge pixels included, as "auto" finds for this point-sampled render: held, so that no noisy
    # draw decides otherwise and every fit uses the pixels θ* is defined on
    options = sf.FitOptions(noise=SIGMA, free=FREE, loss="huber", starts=1, edge_pixels="include")
    clean_fit = sf.fit(scene, clean, options)
    assert clean_fit.verdict == "mismatch" and clean_fit.solver["loss"] == "huber"
    star = robust_pseudo_truth(clean_fit)
    rng = np.random.default_rng(27)
    results = []
    for _ in range(DRAWS):
        noisy = clean.pixels + rng.normal(0.0, SIGMA, clean.pixels.shape)
        results.append(sf.fit(scene, sf.Target(noisy, clean.usable, "draw", "linear", 0, 0), options))
    assert all(r.uncertainty_method["name"] == "noise sandwich" for r in results)
    assert all(np.array_equal(r.used_index, clean_fit.used_index) for r in results)
    rates = coverage(results, star)
    used = np.isfinite(rates[1.0])
    assert used.sum() >= 4  # colour g, b, s and m have intervals (the red channel sits on its bound)
    assert within_bounds(rates, DRAWS), {f: np.round(r[used], 2).tolist() for f, r in rates.items()}
    # the reference matters: the noise-free Huber fit is far from θ* in the deviations' units
    # and the same check rejects it, so a ± centred there (or this test against it) would fail
    x = np.array([np.asarray(r.x, dtype=float) for r in results])
    sd = np.array([np.concatenate([np.atleast_1d(r.uncertainty[n]) for n in FREE]).astype(float) for r in results])
    offset = np.abs(np.asarray(clean_fit.x) - star)[used] / np.mean(sd, axis=0)[used]
    assert offset.max() > 1.5, offset
    assert not within_bounds(coverage(results, np.asarray(clean_fit.x, dtype=float)), DRAWS)
    # and the draws' mean is θ* (within 4 standard errors of the mean, per entry)
    error = np.abs(x.mean(axis=0) - star)[used] / (x.std(axis=0, ddof=1)[used] / np.sqrt(DRAWS))
    assert np.all(error < 4), error


@pytest.mark.usefixtures("x64")
@pytest.mark.parametrize("loss", ["linear", "huber"])
def test_the_sandwich_moves_the_optimum_only_by_values_the_loss_lets_move_it(loss):
    """The meat's rows are ∂(gᵢ∇gᵢ)/∂yᵢ. For least squares that is DᵢJᵢ; for Huber's
    ψ-scaled residuals gᵢ = sign(z)√(2ρ(z)) it is ψ′(zᵢ) times the least-squares row: zero
    beyond the threshold, where DᵢJᵢ alone is not (it gave those values the weight
    (k²/gᵢ²)² and widened the ± by 1.2–1.35 times)."""
    scene, clean = phong_target(24)
    material = sf.Material(color=(0.9, 0.6, 0.35), smoothness=0.55, metalness=0.5)
    plan = plan_render(scene, material, transparent=False)
    sigma = np.full(clean.pixels.shape, SIGMA)
    problem, _, _ = build_problem(
        scene, clean, list(FREE), material, plan, sf.FitOptions(), SIGMA, loss=loss, noise_sigma=sigma
    )
    x = np.array([0.95, 0.62, 0.37, 0.56, 0.6])
    j, _, slope, cross = objective_terms(problem, x)
    least_squares = slope[:, None] * j
    if loss == "linear":
        np.testing.assert_allclose(cross, least_squares, rtol=1e-12, atol=0)
        return
    z = ((np.asarray(problem.render_physical(x)) - np.asarray(problem.target)) / SIGMA).ravel()
    inside, beyond = np.abs(z) < HUBER_K * 0.999, np.abs(z) > HUBER_K * 1.001
    assert inside.sum() > 100 and beyond.sum() > 100  # both kinds of value are there
    size = np.max(np.abs(least_squares))
    np.testing.assert_allclose(cross[inside], least_squares[inside], rtol=1e-9, atol=1e-12 * size)
    np.testing.assert_allclose(cross[beyond], 0.0, atol=1e-12 * size)
    assert np.max(np.abs(least_squares[beyond])) > 1e-3 * size  # what the old meat counted there
