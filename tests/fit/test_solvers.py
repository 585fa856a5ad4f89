"""The solvers of :mod:`strauss_fit.fitting.solvers`: the Levenberg–Marquardt variant reaches the
same optimum as optimistix's stock one, in fewer steps on this model."""

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest

import strauss_fit as sf
from strauss_fit import FitOptions, plan_render
from strauss_fit.fitting.problem import build_problem
from strauss_fit.fitting.solvers import (
    GROW_RATIO,
    REJECT_RATIO,
    SOLVERS,
    STRICT_REJECT_RATIO,
    _gauss_newton_polish,
    levenberg_marquardt,
    make_solver,
    polish,
    status_name,
)
from support import noisy_target

pytestmark = pytest.mark.usefixtures("x64")


def _problem(scene, pad=False):
    truth = sf.Material(color=(0.7, 0.4, 0.2), smoothness=0.6, metalness=0.3)
    target = noisy_target(scene, truth, noise=0.01, seed=1)
    plan = plan_render(scene, scene.material)
    # every sphere pixel, as when the step counts below were measured (the solver, not the
    # pixel rule, is under test)
    options = FitOptions(edge_pixels="include")
    problem, _, _ = build_problem(
        scene,
        target,
        ["color", "smoothness", "metalness"],
        scene.material,
        plan,
        options,
        reference_noise=0.01,
        pad=pad,
    )
    return problem


def _solve(problem, solver, start):
    theta = jnp.asarray(problem.layout.to_unconstrained(np.asarray(start, dtype=float)))
    solution = optx.least_squares(problem.residual, solver, theta, max_steps=200, throw=False)
    residual = problem.residual(solution.value)
    return int(solution.stats["num_steps"]), float(jnp.sum(residual**2)), solution.result


def test_textbook_growth_cutoff_reaches_the_same_optimum_in_fewer_steps(key_and_fill):
    problem = _problem(key_and_fill)
    starts = [(0.5, 0.5, 0.5, 0.4, 0.5), (0.3, 0.3, 0.3, 0.2, 0.8), (0.9, 0.9, 0.9, 0.9, 0.1)]
    stock_steps, our_steps = 0, 0
    for start in starts:
        steps_stock, cost_stock, result_stock = _solve(problem, optx.LevenbergMarquardt(rtol=1e-6, atol=1e-8), start)
        steps_ours, cost_ours, result_ours = _solve(problem, levenberg_marquardt(1e-6, 1e-8), start)
        assert result_stock == optx.RESULTS.successful and result_ours == optx.RESULTS.successful
        assert cost_ours == pytest.approx(cost_stock, rel=1e-9)
        assert steps_ours <= steps_stock
        stock_steps, our_steps = stock_steps + steps_stock, our_steps + steps_ours
    assert our_steps < stock_steps


def test_poor_steps_are_rejected_where_gauss_newton_overshoots():
    # r(t) = k (t - 1, a (t^2 + d)): the second residual stays large at the optimum, and its
    # curvature (which J^T J leaves out) makes the true Hessian 1.92 J^T J there, so an
    # undamped Gauss-Newton step overshoots by 92 % and achieves only 1 - 1.92/2 = 4 % of its
    # predicted decrease. Accepting such steps (optimistix's 1 % cutoff) zig-zags about the
    # optimum; rejecting them below STRICT_REJECT_RATIO (a conversion's and a capture's
    # cutoff) damps the solver, which then converges.
    a, d, k = 0.5, 2.0262064194175182, 10.0

    def residual(theta, args=None):
        t = theta[0]
        return k * jnp.stack([t - 1.0, a * (t * t + d)])

    optimum = 0.4708230122141235  # where (t - 1) + 2 a^2 t (t^2 + d) = 0
    curvature = (1 + 4 * a * a * optimum**2 + 2 * a * a * (optimum**2 + d)) / (1 + 4 * a * a * optimum**2)
    assert curvature == pytest.approx(1.92)
    accepting = levenberg_marquardt(1e-4, 1e-6)  # a fit's cutoff, optimistix's 1 %
    assert accepting.search.low_cutoff == REJECT_RATIO == 0.01
    strict = levenberg_marquardt(1e-4, 1e-6, reject_ratio=STRICT_REJECT_RATIO)
    steps = {}
    for name, solver in (("accepting", accepting), ("ours", strict)):
        solution = optx.least_squares(residual, solver, jnp.array([2.0]), max_steps=500, throw=False)
        assert solution.result == optx.RESULTS.successful
        assert float(solution.value[0]) == pytest.approx(optimum, abs=1e-4)
        steps[name] = int(solution.stats["num_steps"])
    assert steps["ours"] <= steps["accepting"] // 2, steps


def test_make_solver_knows_every_name_and_sets_the_growth_cutoff():
    for name in SOLVERS:
        solver = make_solver(name, 1e-5, 1e-7)
        assert (solver.rtol, solver.atol) == (1e-5, 1e-7)
    assert make_solver("lm", 1e-5, 1e-7).search.high_cutoff == GROW_RATIO
    assert make_solver("lm", 1e-5, 1e-7).search.low_cutoff == REJECT_RATIO
    assert make_solver("lm", 1e-5, 1e-7, STRICT_REJECT_RATIO).search.low_cutoff == STRICT_REJECT_RATIO
    with pytest.raises(sf.StraussFitError, match="unknown solver 'newton'"):
        make_solver("newton", 1e-5, 1e-7)


def _optimum(problem):
    theta = jnp.asarray(problem.layout.to_unconstrained(np.array([0.5, 0.5, 0.5, 0.4, 0.5])))
    solution = optx.least_squares(problem.residual, levenberg_marquardt(1e-12, 1e-14), theta, max_steps=200)
    return np.asarray(problem.physical(solution.value))


def test_gauss_newton_polish_reaches_the_optimum_and_returns_the_derivatives_there(key_and_fill):
    problem = _problem(key_and_fill)
    optimum = _optimum(problem)
    start = optimum + np.array([2e-3, -1e-3, 1e-3, 3e-3, -2e-3])  # a subsample's optimum is this far off
    run = jax.jit(_gauss_newton_polish, static_argnums=(2, 3, 4))
    x, cost, count, code, gradient, curvature, start_cost = run(problem, jnp.asarray(start), 1e-6, 1e-8, 100)
    assert status_name(int(code)) == "successful"
    assert 2 <= int(count) <= 5  # evaluations, the start's included
    np.testing.assert_allclose(np.asarray(x), optimum, atol=1e-6)
    best = problem.objective_residual(jnp.asarray(optimum))
    assert float(cost) == pytest.approx(float(jnp.sum(best**2)), rel=1e-10)
    # the derivatives returned are those at the point returned, not at the one before it
    jac = np.asarray(jax.jacfwd(problem.objective_residual)(x))
    residual = np.asarray(problem.objective_residual(x))
    np.testing.assert_allclose(np.asarray(curvature), jac.T @ jac, rtol=1e-10)
    np.testing.assert_allclose(np.asarray(gradient), jac.T @ residual, rtol=1e-8, atol=1e-12 * np.abs(jac).max())
    assert float(start_cost) == pytest.approx(float(jnp.sum(problem.objective_residual(jnp.asarray(start)) ** 2)))
    assert float(start_cost) > float(cost)
    # out of evaluations before the tolerances are met: said so, at the last point evaluated
    for limit in (1, 2):
        x_at, _, count, code, *_ = run(problem, jnp.asarray(start), 1e-6, 1e-8, limit)
        assert status_name(int(code)) == "max_steps_reached" and int(count) == limit
        if limit == 1:
            np.testing.assert_array_equal(np.asarray(x_at), start)


def test_gauss_newton_polish_converges_with_a_zero_absolute_tolerance_on_a_padded_pixel_set(key_and_fill):
    """A padded pixel set's padding has a zero residual and a zero Jacobian row: the test
    |Jδ| ≤ atol + rtol |r| holds there with equality, so with ``atol = 0`` a strict test
    never passed and the round always ran out of steps (and was redone with LM)."""
    problem = _problem(key_and_fill, pad=True)
    assert problem.valid is not None and float(jnp.min(problem.valid)) == 0.0  # there is padding
    optimum = _optimum(problem)
    start = optimum + np.array([2e-3, -1e-3, 1e-3, 3e-3, -2e-3])
    run = jax.jit(_gauss_newton_polish, static_argnums=(2, 3, 4))
    x, _, count, code, *_ = run(problem, jnp.asarray(start), 1e-6, 0.0, 100)
    assert status_name(int(code)) == "successful" and int(count) <= 6
    np.testing.assert_allclose(np.asarray(x), optimum, atol=1e-6)


def test_gauss_newton_polish_reports_a_point_outside_the_bounds_and_the_polish_redoes_it(key_and_fill):
    problem = _problem(key_and_fill)
    optimum = _optimum(problem)
    outside = optimum.copy()
    outside[-1] = 1.2  # metalness above 1
    run = jax.jit(_gauss_newton_polish, static_argnums=(2, 3, 4))
    *_, code, _, _, _ = run(problem, jnp.asarray(outside), 1e-6, 1e-8, 100)
    assert status_name(int(code)) == "nonfinite"
    # the polish's Gauss-Newton round ("near") and its Levenberg-Marquardt rounds end at the
    # same optimum, from a start Gauss-Newton takes and from one it cannot
    options = FitOptions(rtol=1e-6, atol=1e-8, max_steps=100)
    for start in (optimum + 1e-3, np.array([0.45, 0.5, 0.55, 0.3, 0.6])):
        theta = problem.layout.to_unconstrained(start)
        near_theta, near_cost, *_ = polish(problem, theta, options, near=True)
        far_theta, far_cost, *_ = polish(problem, theta, options, near=False)
        assert near_cost == pytest.approx(far_cost, rel=1e-9)
        np.testing.assert_allclose(
            problem.layout.to_physical_numpy(near_theta), problem.layout.to_physical_numpy(far_theta), atol=1e-5
        )
