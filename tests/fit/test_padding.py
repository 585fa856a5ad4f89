"""Padded pixel sets (issue 16.2): targets of one scene whose usable pixels differ in number
share one compilation, and the padding changes nothing a fit reports."""

from __future__ import annotations

import importlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import strauss_fit as sf
import support
from strauss_fit.fitting.problem import build_problem, pixel_bucket
from strauss_fit.rendering.strauss import plan_render
from strauss_fit.stats.laplace import problem_laplace, problem_sandwich

pytestmark = pytest.mark.usefixtures("x64")

problem_module = importlib.import_module("strauss_fit.fitting.problem")

FREE = ["color", "smoothness", "metalness"]
TRUTH = dict(color=(0.6, 0.4, 0.3), smoothness=0.6, metalness=0.3)


def test_buckets_hold_their_pixels_with_little_padding_and_few_sizes():
    sizes = [pixel_bucket(n) for n in range(1, 40_000)]
    assert all(size >= n for n, size in zip(range(1, 40_000), sizes))
    assert all(size % 8 == 0 for size in sizes)
    assert max(size / n for n, size in zip(range(1000, 40_000), sizes[999:])) < 1.195
    # the usable pixels of a 64x64 sphere's targets (clipping, masks) fall in a few sizes
    assert len({pixel_bucket(n) for n in range(2000, 3300)}) <= 4


def _target(image, rows_masked: int) -> sf.Target:
    """The image with ``rows_masked`` rows of 8 pixels masked out in the sphere's middle."""
    usable = np.ones(image.shape[:2], dtype=bool)
    usable[12 : 12 + rows_masked, 12:20] = False
    return sf.Target(image, usable, f"masked-{rows_masked}.exr", "linear", 0, 0)


@pytest.fixture(scope="module")
def scene_and_image():
    scene = support.key_and_fill_scene(32, material=TRUTH)
    image, _ = sf.render(scene, sf.Material(**TRUTH))
    image = np.asarray(image) + np.random.default_rng(3).normal(0.0, 0.004, np.shape(image))
    return scene, image


@pytest.mark.parametrize("loss", ["linear", "huber"])
def test_a_padded_problem_has_the_same_residuals_costs_and_intervals(scene_and_image, loss):
    scene, image = scene_and_image
    target = _target(image, 3)
    material = sf.Material(**TRUTH)
    plan = plan_render(scene, material, transparent=False)
    options = sf.FitOptions()
    sigma = np.full(image.shape, 0.004)
    built = {
        pad: build_problem(scene, target, FREE, material, plan, options, 0.01, loss=loss, noise_sigma=sigma, pad=pad)
        for pad in (False, True)
    }
    plain, padded = built[False][0], built[True][0]
    n = plain.target.shape[0]
    assert padded.target.shape[0] == pixel_bucket(n) > n  # there is padding to test
    np.testing.assert_array_equal(built[False][2], built[True][2])  # the real pixels' indices
    x = np.array([0.55, 0.42, 0.28, 0.58, 0.35])
    r_plain = np.asarray(plain.objective_residual(x))
    r_padded = np.asarray(padded.objective_residual(x))
    np.testing.assert_allclose(r_padded[: r_plain.size], r_plain, rtol=1e-12, atol=1e-15)
    assert np.all(r_padded[r_plain.size :] == 0.0)
    assert padded.value_count() == plain.value_count() == 3 * n
    np.testing.assert_array_equal(padded.real(padded.target), plain.target)
    rss = float(np.sum(np.asarray(plain.residual_physical(x)) ** 2))
    sd_plain, _, cov_plain = problem_laplace(plain, x, rss)
    sd_padded, _, cov_padded = problem_laplace(padded, x, rss)
    np.testing.assert_allclose(cov_padded, cov_plain, rtol=1e-10)
    noise_sd = np.full(3 * n, 0.004)
    np.testing.assert_allclose(
        problem_sandwich(padded, x, noise_sd)[2], problem_sandwich(plain, x, noise_sd)[2], rtol=1e-9
    )


def test_a_fit_on_a_padded_pixel_set_reports_what_it_would_without_padding(scene_and_image, monkeypatch):
    scene, image = scene_and_image
    target = _target(image, 3)
    options = sf.FitOptions(free=tuple(FREE), noise=0.004, equivalence=True)
    padded = sf.fit(scene, target, options).to_json()
    monkeypatch.setattr(problem_module, "pixel_bucket", lambda count: count)  # no padding
    plain = sf.fit(scene, target, options).to_json()
    np.testing.assert_allclose(padded["color"], plain["color"], atol=1e-7)
    for key in ("smoothness", "metalness"):
        assert padded[key] == pytest.approx(plain[key], abs=1e-7)
        assert padded["uncertainty"][key] == pytest.approx(plain["uncertainty"][key], rel=1e-5)
    for key in ("chi2_per_dof", "rms", "delta_e2000_mean", "sum_of_squares"):
        assert padded["residual"][key] == pytest.approx(plain["residual"][key], rel=1e-6)
    assert padded["residual"]["verdict"] == plain["residual"]["verdict"]
    assert padded["pixels_used"] == plain["pixels_used"]
    for name in ("smoothness", "metalness"):
        np.testing.assert_allclose(padded["equivalence"][name], plain["equivalence"][name], atol=1e-4)


def test_targets_with_other_pixel_counts_compile_nothing_new(scene_and_image):
    scene, image = scene_and_image
    options = sf.FitOptions(free=tuple(FREE), noise=0.004)
    counts = {rows: int(_target(image, rows).usable.sum()) for rows in (1, 2, 4)}
    assert len(set(counts.values())) == 3 and len({pixel_bucket(c) for c in counts.values()}) == 1
    sf.fit(scene, _target(image, 1), options)

    def fewer_pixels() -> None:
        for rows in (2, 4):  # fewer usable pixels, the same bucket
            sf.fit(scene, _target(image, rows), options)

    assert support.compiled_during(fewer_pixels) == []


def test_least_squares_huber_and_cauchy_share_one_program_with_each_losss_own_values(scene_and_image):
    """A problem's loss is data in the programs it runs (:meth:`Problem.kernel_form`):
    problems of the linear, Huber and Cauchy losses batch together and compile one program,
    whose residuals, costs, Jacobians and Hessians are each loss's own (the loss as
    structure, compiled on its own, to 1e-12)."""
    from strauss_fit.engine import batch_key
    from strauss_fit.fitting.problem import LOSS_BY_CODE, costs
    from strauss_fit.stats.laplace import _objective_terms, objective_terms_kernel

    scene, image = scene_and_image
    target = _target(image, 3)
    material = sf.Material(**TRUTH)
    plan = plan_render(scene, material, transparent=False)
    sigma = np.full(image.shape, 0.004) * np.linspace(0.8, 1.2, image.size).reshape(image.shape)
    problems = {
        loss: build_problem(
            scene, target, FREE, material, plan, sf.FitOptions(), 0.004, loss=loss, noise_sigma=sigma, pad=True
        )[0]
        for loss in ("linear", "huber", "cauchy")
    }
    # far enough from the truth that Huber's and Cauchy's values differ from their squares
    xs = np.array([[0.55, 0.42, 0.28, 0.58, 0.35], [0.6, 0.4, 0.3, 0.6, 0.3], [0.3, 0.6, 0.5, 0.9, 0.0]])
    keys = {batch_key(costs.call(problem, xs)) for problem in problems.values()}
    assert len(keys) == 1
    assert {problem.kernel_form().loss for problem in problems.values()} == {LOSS_BY_CODE}
    costs(problems["linear"], xs)  # compiles the program every loss shares
    found = {}

    def others() -> None:
        for loss in ("huber", "cauchy"):
            found[loss] = costs(problems[loss], xs)

    assert support.compiled_during(others) == []
    found["linear"] = costs(problems["linear"], xs)
    for loss, problem in problems.items():
        # the loss as structure (the problem as it is, not its kernel form), compiled apart
        own = jax.jit(lambda x, problem=problem: jnp.sum(problem.objective_residual(x) ** 2))
        np.testing.assert_allclose(found[loss], [own(x) for x in xs], rtol=1e-12)
        shared = objective_terms_kernel(problem, xs[2])
        separate = jax.jit(lambda x, problem=problem: _objective_terms(problem, x))(xs[2])
        for a, b in zip(shared, separate):
            np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-12 * float(np.max(np.abs(b))))
    assert not np.allclose(found["huber"], found["linear"])  # the losses do differ here
    assert not np.allclose(found["cauchy"], found["huber"])
