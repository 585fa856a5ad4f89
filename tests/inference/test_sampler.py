"""Posterior sampling: the likelihood and priors, Laplace against emcee, coverage of the
credible intervals over noise draws, the extremes, resuming and interrupting, bad chains
(``strauss-fit sample`` end to end: tests/cli/test_cli_sample.py)."""

import os
import signal

import h5py
import numpy as np
import pytest

import strauss_fit as sf
from strauss_fit.errors import StraussFitError
from strauss_fit.fitting.api import fit
from strauss_fit.fitting.parameters import Layout
from strauss_fit.inference.posterior import LogPosterior, PosteriorError, check_sigma, default_prior, estimate_sigma
from strauss_fit.inference.sampler import ChainError, SampleSettings, diagnose, initial_walkers, load_chain, run_sampler
from strauss_fit.stats.laplace import laplace_covariance
from support import legacy_options, noisy_target

pytestmark = pytest.mark.usefixtures("x64")

TRUTH = dict(color=(0.7, 0.4, 0.2), smoothness=0.6, metalness=0.4)
FREE = legacy_options(free=("color", "smoothness", "metalness"))
NOISE = 0.01


@pytest.fixture(scope="module")
def scene(small_key_and_fill):
    """key_and_fill.toml at 24 × 24 pixels (two directional lights and ambient light:
    colour, smoothness and metalness are all constrained)."""
    return small_key_and_fill


def make_target(scene, material, noise=NOISE, seed=0):
    return noisy_target(scene, material, noise, seed)


def truth_vector(layout: Layout, truth: dict) -> np.ndarray:
    return layout.join(truth)


@pytest.fixture(scope="module")
def well_constrained(scene):
    result = fit(scene, make_target(scene, sf.Material(**TRUTH), seed=11), FREE)
    assert result.free == ["color", "smoothness", "metalness"]
    return result


# --- likelihood, prior, sigma ---------------------------------------------------------------


def test_log_posterior_is_the_gaussian_likelihood_inside_the_box(well_constrained):
    problem, x = well_constrained.problem, well_constrained.x
    prior = default_prior(problem.layout, x)
    lp = LogPosterior(problem, prior, 0.02)
    xs = np.stack([x, x + 0.01, np.clip(x - 0.02, 0, 1)])
    expected = [-0.5 * float(np.sum(np.asarray(problem.residual_physical(v)) ** 2)) / 0.02**2 for v in xs]
    np.testing.assert_allclose(lp(xs), expected, rtol=1e-12)
    assert lp(x) == pytest.approx(expected[0], rel=1e-12)
    outside = x.copy()
    outside[3] = 1.0 + 1e-9  # smoothness just above 1
    below = x.copy()
    below[0] = -1e-9
    assert np.all(lp(np.stack([outside, below])) == -np.inf)


def test_default_prior_ranges_and_overrides():
    layout = Layout(("color", "smoothness", "ior", "directional_intensity_1"))
    x = np.array([0.5, 0.5, 0.5, 0.3, 1.4, 0.8])
    prior = default_prior(layout, x)
    np.testing.assert_array_equal(prior.lower, [0, 0, 0, 0, 1, 0])
    np.testing.assert_array_equal(prior.upper, [1, 1, 1, 1, 3, 8])
    assert default_prior(layout, np.array([0.5, 0.5, 0.5, 0.3, 2.5, 0.0])).upper[4:].tolist() == [3.75, 1.0]
    narrowed = default_prior(layout, x, {"color": (0.2, 0.9), "smoothness": (0.1, 0.6)})
    np.testing.assert_array_equal(narrowed.lower[:4], [0.2, 0.2, 0.2, 0.1])
    np.testing.assert_array_equal(narrowed.upper[:4], [0.9, 0.9, 0.9, 0.6])
    with pytest.raises(PosteriorError, match="leaves the range"):
        default_prior(layout, x, {"smoothness": (-0.1, 0.5)})
    with pytest.raises(PosteriorError, match="not a free parameter"):
        default_prior(layout, x, {"metalness": (0.1, 0.5)})
    with pytest.raises(PosteriorError, match="LOW < HIGH"):
        default_prior(layout, x, {"ior": (2.0, 1.5)})


@pytest.mark.parametrize("sigma", [0.0, -0.01, float("nan"), float("inf")])
def test_sigma_must_be_positive_and_finite(sigma):
    with pytest.raises(PosteriorError, match="sigma must be a finite number > 0"):
        check_sigma(sigma)


def test_sigma_estimated_from_the_residual(well_constrained):
    sigma = estimate_sigma(well_constrained.problem, well_constrained.x)
    # 448 pixels x 3 values: the estimate's relative error is about 1/sqrt(2N) = 2 %
    assert sigma == pytest.approx(NOISE, rel=0.08)


def test_noise_free_target_needs_a_given_sigma(scene):
    result = fit(scene, make_target(scene, sf.Material(**TRUTH), noise=0.0), FREE)
    with pytest.raises(PosteriorError, match="give the noise level with --sigma"):
        estimate_sigma(result.problem, np.asarray(result.x))


# --- Laplace against emcee ------------------------------------------------------------------


def test_laplace_and_emcee_agree_on_a_well_constrained_case(well_constrained):
    problem, x = well_constrained.problem, well_constrained.x
    sigma = NOISE
    prior = default_prior(problem.layout, x)
    lp = LogPosterior(problem, prior, sigma)
    covariance = laplace_covariance(problem, x, sigma)
    # start 10 times narrower than the posterior: the sampler must find its width itself
    start = initial_walkers(x, covariance / 100, prior, 64, np.random.default_rng(1), lp)
    run = run_sampler(lp, None, start=start, settings=SampleSettings(max_steps=2000, seed=1))
    d = run.diagnostics
    assert d.steps == 2000 and d.walkers == 64
    assert 0.2 < d.acceptance_mean < 0.8 and min(d.ess) > 1000
    samples = run.chain[500:].reshape(-1, x.size)
    sd_laplace = np.sqrt(np.diag(covariance))
    # ESS > 1000: the sampled deviation is within ~2 % of the truth; 10 % allows for the
    # model's slight non-linearity over +-3 sd
    np.testing.assert_allclose(samples.std(axis=0), sd_laplace, rtol=0.10)
    assert np.all(np.abs(samples.mean(axis=0) - x) < 0.2 * sd_laplace)
    corr_samples = np.corrcoef(samples, rowvar=False)
    corr_laplace = covariance / np.outer(sd_laplace, sd_laplace)
    np.testing.assert_allclose(corr_samples, corr_laplace, atol=0.1)
    # the fit's own Laplace deviations (sigma estimated from its residual) agree too
    fitted_sd = np.r_[
        well_constrained.uncertainty["color"],
        well_constrained.uncertainty["smoothness"],
        well_constrained.uncertainty["metalness"],
    ]
    np.testing.assert_allclose(fitted_sd, sd_laplace, rtol=0.1)


@pytest.mark.slow
def test_credible_intervals_cover_the_truth_at_their_nominal_rate(scene):
    """50 noise draws of one synthetic target with known sigma: for each, fit, then sample
    (a short chain: 96 walkers x 300 steps started at half the Laplace width, burn-in 100,
    about 400 effective samples per parameter), and count how often the 68 % and 95 % intervals
    contain the truth. Pooled over the 5 parameters (250 intervals) the expected spread of
    the 68 % count is +-7.4 (binomial), so [60 %, 76 %] is about +-2.2 standard deviations
    (more, allowing for the correlation of parameters within a draw); per parameter
    (50 intervals) +-3 binomial deviations."""
    material = sf.Material(**TRUTH)
    draws = 50
    hits = {"emcee68": [], "emcee95": [], "laplace68": [], "laplace95": []}
    truth = None
    for seed in range(draws):
        result = fit(scene, make_target(scene, material, seed=1000 + seed), FREE)
        problem, x = result.problem, np.asarray(result.x)
        truth = truth_vector(problem.layout, TRUTH) if truth is None else truth
        prior = default_prior(problem.layout, x)
        lp = LogPosterior(problem, prior, NOISE)
        covariance = laplace_covariance(problem, x, NOISE)
        # walkers start at half the Laplace width, so the intervals' width is the sampler's doing
        start = initial_walkers(x, covariance / 4, prior, 96, np.random.default_rng(seed), lp)
        run = run_sampler(lp, None, start=start, settings=SampleSettings(max_steps=300, seed=seed))
        samples = run.chain[100:].reshape(-1, x.size)
        assert np.all(np.isfinite(run.log_prob))
        q = np.percentile(samples, [2.5, 16, 84, 97.5], axis=0)
        sd = np.sqrt(np.diag(covariance))
        hits["emcee68"].append((q[1] <= truth) & (truth <= q[2]))
        hits["emcee95"].append((q[0] <= truth) & (truth <= q[3]))
        hits["laplace68"].append(np.abs(x - truth) <= sd)
        hits["laplace95"].append(np.abs(x - truth) <= 1.96 * sd)
    rates = {k: np.mean(v, axis=0) for k, v in hits.items()}  # per parameter
    pooled = {k: float(np.mean(v)) for k, v in hits.items()}
    print("coverage per parameter", {k: v.round(2).tolist() for k, v in rates.items()}, "pooled", pooled)
    for method in ("emcee", "laplace"):
        assert 0.60 <= pooled[f"{method}68"] <= 0.76, pooled
        assert 0.90 <= pooled[f"{method}95"] <= 0.99, pooled
        assert np.all((rates[f"{method}68"] >= 0.48) & (rates[f"{method}68"] <= 0.88)), rates
        assert np.all(rates[f"{method}95"] >= 0.84), rates


# --- the extremes -----------------------------------------------------------------------------


@pytest.mark.parametrize(
    "truth",
    [
        dict(color=(0.5, 0.7, 0.2), smoothness=1.0, metalness=1.0),
        dict(color=(0.5, 0.7, 0.2), smoothness=0.0, metalness=0.0),
        dict(color=(1.0, 0.0, 0.5), smoothness=0.7, metalness=0.0),
    ],
)
def test_sampler_stays_finite_at_the_extremes(scene, truth):
    result = fit(scene, make_target(scene, sf.Material(**truth), noise=0.005, seed=5), FREE)
    problem, x = result.problem, np.asarray(result.x)
    prior = default_prior(problem.layout, x)
    lp = LogPosterior(problem, prior, 0.005)
    # every corner of the prior box has a finite log-probability
    corners = np.array(np.meshgrid(*[[lo, hi] for lo, hi in zip(prior.lower, prior.upper)])).reshape(x.size, -1).T
    assert np.all(np.isfinite(lp(corners)))
    start = initial_walkers(x, laplace_covariance(problem, x, 0.005), prior, 32, np.random.default_rng(0), lp)
    assert np.all(start > prior.lower) and np.all(start < prior.upper)  # pinned entries start just inside
    run = run_sampler(lp, None, start=start, settings=SampleSettings(max_steps=150))
    assert np.all(np.isfinite(run.chain)) and np.all(np.isfinite(run.log_prob))
    assert np.all(run.chain >= prior.lower) and np.all(run.chain <= prior.upper)
    assert run.diagnostics.acceptance_mean > 0.05
    assert all(np.isfinite(run.diagnostics.tau))


# --- storing, resuming, interrupting -------------------------------------------------------------


@pytest.fixture(scope="module")
def small_posterior(well_constrained):
    problem, x = well_constrained.problem, np.asarray(well_constrained.x)
    prior = default_prior(problem.layout, x)
    lp = LogPosterior(problem, prior, NOISE)
    start = initial_walkers(x, laplace_covariance(problem, x, NOISE), prior, 16, np.random.default_rng(3), lp)
    return lp, start


# a huge multiple: these short chains never stop early
SHORT = dict(min_tau_multiple=1e6, check_every=10, seed=7)


def test_resuming_continues_the_same_chain(tmp_path, small_posterior):
    lp, start = small_posterior
    run_sampler(
        lp,
        tmp_path / "whole.h5",
        start=start,
        settings=SampleSettings(max_steps=40, **SHORT),
        metadata={"note": "whole"},
    )
    first = run_sampler(
        lp, tmp_path / "part.h5", start=start, settings=SampleSettings(max_steps=17, **SHORT), metadata={"note": "part"}
    )
    assert first.new_steps == 17
    resumed = run_sampler(lp, tmp_path / "part.h5", settings=SampleSettings(max_steps=40, **SHORT), resume=True)
    assert resumed.new_steps == 23
    a, b = load_chain(tmp_path / "whole.h5"), load_chain(tmp_path / "part.h5")
    assert b.chain.shape == (40, 16, 5)
    # bit for bit: the resumed run starts from the stored walkers, log-probabilities and
    # random state, so step 18 is what the uninterrupted run drew
    np.testing.assert_array_equal(b.chain, a.chain)
    np.testing.assert_array_equal(b.log_prob, a.log_prob)
    np.testing.assert_array_equal(b.accepted, a.accepted)
    assert b.meta["note"] == "part" and b.labels == list(lp.prior.labels)
    # the file is emcee's own format: emcee reads it without strauss-fit
    import emcee

    backend = emcee.backends.HDFBackend(str(tmp_path / "part.h5"), read_only=True)
    assert backend.iteration == 40 and backend.get_chain().shape == (40, 16, 5)
    with h5py.File(tmp_path / "part.h5", "r") as f:
        assert f["mcmc/chain"].shape[0] == 40  # no unused reserved rows


def test_interrupt_keeps_every_step_and_resumes(tmp_path, small_posterior):
    lp, start = small_posterior
    path = tmp_path / "chain.h5"

    def press_ctrl_c(progress):
        if progress.steps == 20:
            os.kill(os.getpid(), signal.SIGINT)

    handler = signal.getsignal(signal.SIGINT)
    with pytest.raises(KeyboardInterrupt):
        run_sampler(
            lp, path, start=start, settings=SampleSettings(max_steps=40, **SHORT), metadata={}, progress=press_ctrl_c
        )
    kept = load_chain(path)
    # the step in progress when Ctrl-C arrived is finished and stored, nothing is lost
    assert kept.chain.shape[0] == 21
    assert signal.getsignal(signal.SIGINT) is handler  # restored
    run_sampler(lp, path, settings=SampleSettings(max_steps=40, **SHORT), resume=True)
    whole = run_sampler(
        lp, tmp_path / "whole.h5", start=start, settings=SampleSettings(max_steps=40, **SHORT), metadata={}
    )
    np.testing.assert_array_equal(load_chain(path).chain, whole.chain)


def test_diagnostics_flag_a_short_chain_and_pass_a_long_one():
    rng = np.random.default_rng(0)
    # independent draws: tau = 1
    chain = rng.normal(size=(400, 20, 2))
    good = diagnose(chain, np.zeros((400, 20)), np.full(20, 200), ["a", "b"], 50)
    assert good.trustworthy and good.converged and good.reasons == []
    assert good.tau == pytest.approx([1.0, 1.0], abs=0.3)
    assert good.ess[0] == pytest.approx(20 * (400 - good.burn_in) / good.tau[0])
    # a random walk: tau of the order of the chain's length
    walk = np.cumsum(rng.normal(size=(400, 20, 2)), axis=0)
    bad = diagnose(walk, np.zeros((400, 20)), np.full(20, 200), ["a", "b"], 50)
    assert not bad.trustworthy and not bad.converged
    assert any("autocorrelation times long" in r for r in bad.reasons)
    stuck = diagnose(chain, np.zeros((400, 20)), np.r_[np.full(19, 200), 0], ["a", "b"], 50)
    assert not stuck.trustworthy and any("stuck" in r for r in stuck.reasons)


@pytest.mark.parametrize(
    "case,pattern",
    [
        ("missing", "chain file not found"),
        ("corrupt", "corrupt or truncated HDF5 file"),
        ("empty", "not an HDF5 file"),
        ("foreign", "not a strauss-fit chain"),
        ("directory", "is a directory"),
    ],
)
def test_bad_chain_files_are_one_line_errors(tmp_path, case, pattern):
    path = tmp_path / "chain.h5"
    if case == "corrupt":
        path.write_bytes(b"\x89HDF\r\n\x1a\n" + os.urandom(200))
    elif case == "empty":
        path.write_bytes(b"")
    elif case == "foreign":
        with h5py.File(path, "w") as f:
            f.create_dataset("data", data=np.arange(10))
    elif case == "directory":
        path.mkdir()
    with pytest.raises(ChainError, match=pattern) as info:
        load_chain(path)
    assert "\n" not in str(info.value)


def test_all_errors_are_strauss_fit_errors():
    assert issubclass(ChainError, StraussFitError) and issubclass(PosteriorError, StraussFitError)
