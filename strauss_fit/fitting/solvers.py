r"""Solving a fit: the optimistix solvers, the starts, the active-set polish.

Solvers. All are optimistix solvers.

``lm`` is Levenberg–Marquardt built from optimistix's own parts — the damped Newton
descent `(J^\top J + \lambda I)\,\delta = -J^\top r` with `\lambda` the inverse
of a classical trust-region step size — with two changes to the trust-region update of
`optimistix.LevenbergMarquardt`, both towards the textbook (Nocedal & Wright,
*Numerical Optimization*, Algorithm 4.1), in the ratio ρ of the actual reduction of the
cost to the reduction the linearisation predicted:

- the step size grows (×3.5) after every step with ρ ≥ 0.75 (`GROW_RATIO`), where
  optimistix's default asks for 0.99. Why: on this model, after the first rejected steps
  have raised λ, ρ settles between 0.75 and 0.99 for many steps; with a 0.99 cutoff λ
  then never shrinks and the solver creeps towards the optimum (17 steps against 12 on
  the 256² benchmark fit of C, s, m, with the same optimum to 1e-14 in cost);
- a step with ρ below a cutoff is rejected and shrinks the step size (×0.25). The cutoff
  depends on the use, each measured: a fit of an image rejects below 0.01
  (`REJECT_RATIO`, optimistix's default), a conversion between models and a capture
  below 0.1 (`STRICT_REJECT_RATIO`). Why the strict cutoff there: where the model
  cannot match the target by construction (a Phong lobe fitted by Strauss's), undamped
  Gauss–Newton steps overshoot along a valley; with ρ around 0.05 they were all accepted
  and the solver zig-zagged about the optimum, its amplitude shrinking by 11 % a step (49
  steps for one polish of a Phong → Strauss conversion that takes 10 with it, ending at
  the same cost within 1e-12). Why not for images: over the recovery set of
  ``benchmarks/recovery.py`` (48 fits) the two cutoffs took the same steps (385 against
  387) and 0.01 once reached a 58 % lower cost; over the bundled Mitsuba renders 0.01 took
  501 steps against 569, and the README's example 17 against 41 (2026-12-02).

Solving (`solve`). Every start runs `start_steps`
steps (`solve_starts`: one after another with ``lax.map`` on a CPU, vectorised with
``vmap`` elsewhere), on a pixel subsample of a large image
(`strauss_fit.fitting.problem.coarse_problem`); the best one is then finished on every
pixel by the bound-aware polish (`polish`) unless it already converged away from the
bounds on every pixel.

These functions are internal API of the fit (the conversions reuse `polish`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..engine import Call, Kernel, Steps, run
from ..errors import StraussFitError
from ..numerics import value_and_jacobian_rows
from ..precision import uses_float64
from .options import SOLVERS as SOLVERS  # plain data, kept with the options (the CLI reads it)
from .options import FitOptions
from .parameters import Layout, jsonable
from .problem import Problem, costs, physical_values
from .starts import scan_ior_steps, start_points_steps

if TYPE_CHECKING:
    import optimistix as optx

# optimistix is imported where it is used: importing the package (and starting the command
# line) does not pay for it.


#: Actual-to-predicted reduction ratio above which the trust region grows.
GROW_RATIO = 0.75
#: Actual-to-predicted reduction ratio below which a step of a fit of an image is rejected
#: and the region shrinks (see the module).
REJECT_RATIO = 0.01
#: The same for a conversion between models and a capture, where the model cannot match its
#: target by construction and accepted poor steps zig-zag (see the module).
STRICT_REJECT_RATIO = 0.1


def levenberg_marquardt(
    rtol: float, atol: float, *, normal_equations: bool = False, reject_ratio: float = REJECT_RATIO
) -> optx.LevenbergMarquardt:
    """`optimistix.LevenbergMarquardt` with the textbook cutoff `GROW_RATIO` and
    ``reject_ratio`` (`REJECT_RATIO` or `STRICT_REJECT_RATIO`) in its trust
    region (see the module). The one Levenberg–Marquardt of the package: the fits, the
    captures, the Phong → Strauss conversions and the Phong fitter use it.

    ``normal_equations``: solve each damped step from the normal equations (Cholesky of
    JᵀJ + λI) instead of a QR of the stacked Jacobian. Why: with millions of residuals and a
    handful of parameters (a capture) the QR of the tall matrix dominates every step, while
    JᵀJ is a few passes over the data; the squared condition number costs nothing there."""
    import lineax as lx
    import optimistix as optx

    linear_solver = lx.Normal(lx.Cholesky()) if normal_equations else lx.QR()
    solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol, linear_solver=linear_solver)
    search = optx.ClassicalTrustRegion(high_cutoff=GROW_RATIO, low_cutoff=reject_ratio)
    return eqx.tree_at(lambda s: s.search, solver, search)


def make_solver(
    name: str, rtol: float, atol: float, reject_ratio: float = REJECT_RATIO
) -> optx.AbstractLeastSquaresSolver | optx.AbstractMinimiser:
    """The solver called ``name`` (one of `SOLVERS`) with the given tolerances (and,
    for ``lm``, ``reject_ratio``: see `levenberg_marquardt`)."""
    import optimistix as optx

    if name == "lm":
        return levenberg_marquardt(rtol, atol, reject_ratio=reject_ratio)
    if name == "gauss-newton":
        return optx.GaussNewton(rtol=rtol, atol=atol)
    if name == "bfgs":
        return optx.BFGS(rtol=rtol, atol=atol)
    raise StraussFitError(f"unknown solver {name!r}; expected one of {', '.join(SOLVERS)}")


#: optimistix's result codes, in the order `status_name` numbers them.
RESULT_NAMES = (
    "successful",
    "max_steps_reached",
    "nonlinear_max_steps_reached",
    "nonlinear_divergence",
    "nonfinite",
    "singular",
    "breakdown",
    "stagnation",
)


def status_name(code: int) -> str:
    """The name of a result code returned by `solve_starts` or `polish_solve`."""
    return RESULT_NAMES[code]


def _result_code(result: Any) -> Array:
    import optimistix as optx

    return jnp.argmax(jnp.stack([result == getattr(optx.RESULTS, name) for name in RESULT_NAMES]))


def _solve_starts(
    problem: Problem,
    thetas: Array,
    solver_name: str,
    rtol: float,
    atol: float,
    max_steps: int,
    batched: bool,
    reject_ratio: float = REJECT_RATIO,
):
    """Solve from every row of ``thetas``: vectorised (``vmap``) when ``batched``, else one
    after the other (``lax.map``). Why both: under ``vmap`` the solver's branches (step
    accepted or rejected) become selects that evaluate both sides, which on a CPU, where the
    pixels already fill the cores, costs about twice a sequential solve (measured:
    53 ms against 102 ms for one start at 256², 211 ms against 392 ms for four); on a
    GPU the batch fills the device instead. Returns θ, the normalised cost, the step count
    and the result code (`status_name`) per start. ``reject_ratio``: see
    `levenberg_marquardt`."""
    import optimistix as optx

    solver = make_solver(solver_name, rtol, atol, reject_ratio)

    def one(theta0):
        solution = optx.least_squares(problem.residual, solver, theta0, max_steps=max_steps, throw=False)
        r = problem.residual(solution.value)
        return solution.value, jnp.sum(r * r), solution.stats["num_steps"], _result_code(solution.result)

    return jax.vmap(one)(thetas) if batched else jax.lax.map(one, thetas)


#: Solve from every row of ``thetas`` (see `_solve_starts`); a
#: `Kernel`.
solve_starts = Kernel(_solve_starts, "solve_starts")


#: Entries this close to a bound after the first phase are tried pinned to it.
BOUND_SNAP = 0.02


def near_bounds(layout: Layout, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which entries of the physical point ``x`` lie within `BOUND_SNAP` of their
    lower and of their upper bound."""
    return x - layout.lower_bounds() < BOUND_SNAP, layout.upper_bounds() - x < BOUND_SNAP


def _polish_solve(
    problem: Problem,
    theta: Array,
    rtol: float,
    atol: float,
    max_steps: int,
    reject_ratio: float = REJECT_RATIO,
):
    """One Levenberg–Marquardt solve of the polish (`levenberg_marquardt`; the
    Gauss–Newton round is `_gauss_newton_polish`): θ, the normalised cost, the steps, the
    result code, and the gradient Jᵀr and curvature JᵀJ of the normalised cost in physical
    units."""
    import optimistix as optx

    solver = levenberg_marquardt(rtol, atol, reject_ratio=reject_ratio)
    solution = optx.least_squares(problem.residual, solver, theta, max_steps=max_steps, throw=False)
    code = _result_code(solution.result)
    x = problem.physical(solution.value)
    # the residual (= problem.residual(solution.value)) and its Jacobian, materialised once
    # for the two products (`value_and_jacobian_rows`)
    residual, rows = value_and_jacobian_rows(problem.objective_residual, x)
    return solution.value, jnp.sum(residual**2), solution.stats["num_steps"], code, rows @ residual, rows @ rows.T


#: One solve of the polish (`_polish_solve`); a `Kernel`.
polish_solve = Kernel(_polish_solve, "polish_solve")


def _gauss_newton_polish(problem: Problem, x: Array, rtol: float, atol: float, max_steps: int):
    r"""The polish's Gauss–Newton round (nothing pinned, the start converged on the
    subsample), in physical units. At each point, the objective residual r, its Jacobian J
    and the step `\delta = -(J^\top J)^{-1} J^\top r`; the round ends at the first point
    whose step is within the tolerances in x and in its linear prediction of r
    (optimistix's Cauchy test on the step, with ≤: every `|\delta_i| \le atol + rtol\,|x_i|`
    and every `|(J\delta)_j| \le atol + rtol\,|r_j|`), or after ``max_steps``
    evaluations. Returns that point x, the normalised cost, the evaluations, the result
    code (`status_name`: successful, max_steps_reached or nonfinite), Jᵀr and JᵀJ there,
    and the cost at the start.

    Why not `optimistix.GaussNewton` (what this round ran until 2026-12-04): it takes the
    Jacobian in the unconstrained θ through a linearisation and materialises it for a QR
    every step, takes one more step to see that the last one was small, and the caller
    then took J and r at the end again for the errors — five evaluations at about 6 ms on
    a 256² sphere. Here every evaluation's J serves its step and the last one's the errors
    too, and the round stops where the next step would change nothing the tolerances see:
    three evaluations on that sphere. The normal equations are solved scaled by their
    diagonal (the squared condition number of a handful of columns is harmless in
    float64); a singular JᵀJ, or a step that leaves the bounds, gives the code
    ``nonfinite``, and the caller redoes the round with Levenberg–Marquardt, as it does
    when the cost rose."""
    lower = jnp.asarray(problem.layout.lower_bounds())
    upper = jnp.asarray(problem.layout.upper_bounds())

    def evaluate(point):
        residual, columns = value_and_jacobian_rows(problem.objective_residual, point)
        gradient, curvature = columns @ residual, columns @ columns.T
        diagonal = jnp.diag(curvature)
        scale = 1.0 / jnp.sqrt(jnp.where(diagonal > 0, diagonal, 1.0))
        delta = -scale * jnp.linalg.solve(curvature * scale[:, None] * scale[None, :], gradient * scale)
        # ≤, not optimistix's <: a padded pixel set's padding (zero residual, zero Jacobian
        # row) meets its bound with equality, and with atol = 0 a strict test never passed
        small = jnp.all(jnp.abs(delta) <= atol + rtol * jnp.abs(point)) & jnp.all(
            jnp.abs(delta @ columns) <= atol + rtol * jnp.abs(residual)
        )
        finite = (
            jnp.all(jnp.isfinite(residual))
            & jnp.all(jnp.isfinite(delta))
            & jnp.all((point >= lower) & (point <= upper))
        )
        return residual, gradient, curvature, delta, small, finite

    def condition(state):
        count, _, evaluated = state
        *_, small, finite = evaluated
        return (count < max_steps) & ~small & finite

    def step(state):
        count, point, evaluated = state
        point = point + evaluated[3]
        return count + 1, point, evaluate(point)

    first = evaluate(x)
    start_cost = jnp.sum(first[0] * first[0])
    count, x, (residual, gradient, curvature, _, small, finite) = jax.lax.while_loop(
        condition, step, (jnp.asarray(1), x, first)
    )
    code = jnp.where(
        finite, jnp.where(small, 0, RESULT_NAMES.index("max_steps_reached")), RESULT_NAMES.index("nonfinite")
    )
    return x, jnp.sum(residual * residual), count, code, gradient, curvature, start_cost


#: The polish's Gauss–Newton round (`_gauss_newton_polish`); a `Kernel`.
gauss_newton_polish = Kernel(_gauss_newton_polish, "gauss_newton_polish")


def release_gain(information: np.ndarray, gradient: np.ndarray, pinned: np.ndarray, count: int) -> np.ndarray:
    r"""For each pinned entry i, the Newton estimate of how much χ² (at the reference noise)
    would drop if i were released and the free entries F re-optimised with it:
    `N g_i^2 / S_i` with `S_i = H_{ii} - H_{iF} H_{FF}^{-1} H_{Fi}` the Schur
    complement of the Gauss–Newton curvature (g, H of the normalised cost; the free
    entries' slopes vanish at the pinned optimum). Why not `H_{ii}` alone: a pinned
    entry that trades off with a free one (metalness with colour) gains far more when the
    partner may follow — 200× more in a plastic fit where that correlation is 0.995."""
    gain = np.zeros_like(gradient)
    free = ~pinned
    h_ff = information[np.ix_(free, free)]
    for i in np.flatnonzero(pinned):
        schur = information[i, i]
        if free.any():
            h_fi = information[free, i]
            schur = schur - h_fi @ np.linalg.lstsq(h_ff, h_fi, rcond=1e-12)[0]
        gain[i] = count * gradient[i] ** 2 / max(float(schur), 1e-300 + 1e-12 * information[i, i])
    return gain


@uses_float64
def polish(problem: Problem, theta: np.ndarray, options: FitOptions, near: bool = False):
    """`polish_steps`, run directly."""
    return run(polish_steps(problem, theta, options, near))


def polish_steps(
    problem: Problem,
    theta: np.ndarray,
    options: FitOptions,
    near: bool = False,
    reject_ratio: float = REJECT_RATIO,
) -> Steps:
    """Continue the best start with an active set. Entries within `BOUND_SNAP` of a
    bound are pinned to it and the rest re-solved (Levenberg–Marquardt, whatever the
    solver of the starts; Gauss–Newton when ``near``, i.e. the start converged on the
    subsample, nothing is pinned and only the last few digits are left — it gets there in
    fewer steps, and a round where it raised the cost or did not converge is redone with
    Levenberg–Marquardt); a pinned entry is released if moving it inward would lower χ²
    (at the reference noise) by more than 1 — the Newton estimate of
    `release_gain`, the free entries following: a KKT check with a statistical
    tolerance — and entries that reach a bound are pinned, unless released before (an entry
    that a round released and the next pulled back towards its bound would otherwise
    alternate). At most three rounds; the cheapest round stands (ties go to the later).
    ``reject_ratio``: Levenberg–Marquardt's (`levenberg_marquardt`).

    Why: the smooth transforms reach a bound only with zero slope, so an optimum on a bound
    (m = 0, say, or a noisy fit pulling past it) is approached ever more slowly; pinning
    makes it exact and lets the solver converge on the remaining entries.

    Returns θ, the normalised cost, the steps, the status name, the problem with the
    final pins, and JᵀJ of the physical residuals at the end (for the Laplace errors).
    """
    layout = problem.layout
    lower, upper = layout.lower_bounds(), layout.upper_bounds()
    count = problem.value_count()
    x = physical_values(problem, theta)
    start_theta = theta

    def levenberg_marquardt_round(round_problem: Problem, round_start: np.ndarray) -> Call:
        return polish_solve.call(
            round_problem, np.asarray(round_start), options.rtol, options.atol, options.max_steps, reject_ratio
        )

    at_lower, at_upper = near_bounds(layout, x)
    # Gauss–Newton's step would divide by the zero Jacobian column of a pinned entry
    gauss_newton_first = near and not (at_lower | at_upper).any()
    # (Gauss–Newton's round returns the cost at its start: no call of its own for it)
    start_cost = None if gauss_newton_first else float(np.asarray((yield costs.call(problem, x[None])))[0])
    released = np.zeros_like(at_lower)
    total_steps = 0
    best = None
    for round_ in range(3):
        pinned = at_lower | at_upper
        trial = problem.pin(pinned, np.where(at_lower, lower, np.where(at_upper, upper, x)))
        start = np.asarray(theta)
        gauss_newton = gauss_newton_first and not round_
        if gauss_newton:
            x_end, cost, steps, code, gradient, information, start_cost = (
                np.asarray(v)
                for v in (yield gauss_newton_polish.call(trial, x, options.rtol, options.atol, options.max_steps))
            )
            start_cost = float(start_cost)
            theta = layout.to_unconstrained(x_end)
        else:
            theta, cost, steps, code, gradient, information = (
                np.asarray(v) for v in (yield levenberg_marquardt_round(trial, start))
            )
        # (with nothing pinned the trial is the problem itself, so its start cost is start_cost)
        if gauss_newton and not (np.isfinite(cost) and cost <= start_cost and status_name(int(code)) == "successful"):
            theta, cost, more, code, gradient, information = (
                np.asarray(v) for v in (yield levenberg_marquardt_round(trial, start))
            )
            steps = steps + more
        total_steps += int(steps)
        if best is None or (np.isfinite(cost) and cost <= best[1] * (1 + 1e-9)):
            best = theta, cost, code, information, trial
        x = physical_values(trial, theta)
        gain = release_gain(information, gradient, pinned, count)
        release_lower = at_lower & (gradient < 0) & (gain > 1.0)
        release_upper = at_upper & (gradient > 0) & (gain > 1.0)
        released |= release_lower | release_upper
        near_lower, near_upper = near_bounds(layout, x)
        new_lower = ~pinned & ~released & near_lower & (gradient >= 0)
        new_upper = ~pinned & ~released & near_upper & (gradient <= 0)
        if not (release_lower | release_upper | new_lower | new_upper).any():
            break
        at_lower = (at_lower & ~release_lower) | new_lower
        at_upper = (at_upper & ~release_upper) | new_upper
    theta, cost, code, information, trial = best
    if np.asarray(trial.pinned).any() and not float(cost) <= start_cost * (1 + 1e-9):
        # The Newton estimate of the release gain can miss a gain that is far from
        # quadratic (s just below 1, where the highlight's exponent 3/(1 − s) explodes):
        # pinning must never end above the cost the polish started from.
        theta, cost, steps, code, _, information = (
            np.asarray(v) for v in (yield levenberg_marquardt_round(problem, start_theta))
        )
        total_steps += int(steps)
        trial = problem
    # JᵀJ at the end, in physical units, for the Laplace errors (saves recomputing J)
    return (
        theta,
        float(cost),
        total_steps,
        status_name(int(code)),
        trial,
        information * float(trial.residual_scale) ** 2,
    )


@dataclass
class Solved:
    """What `solve` found for one decision of the free parameters."""

    problem: Problem
    x: np.ndarray
    rss: float
    status: str
    steps: int
    polish_steps: int
    best: int
    starts: list[dict[str, Any]]
    spread: dict[str, float]
    #: JᵀJ of the physical residuals at ``x`` when the polish computed it, else None
    information: np.ndarray | None = None


def solve(
    problem: Problem,
    guess: dict[str, Any],
    options: FitOptions,
    say: Callable[[str], None],
    coarse: Problem | None = None,
    exact_first: bool = False,
) -> Solved:
    """`solve_steps`, run directly."""
    return run(solve_steps(problem, guess, options, say, coarse, exact_first))


def solve_steps(
    problem: Problem,
    guess: dict[str, Any],
    options: FitOptions,
    say: Callable[[str], None],
    coarse: Problem | None = None,
    exact_first: bool = False,
) -> Steps:
    """Every start (`FitOptions.start_steps` steps each), then the best one
    polished (`polish`) on every pixel, unless it converged away from the bounds
    on every pixel already.

    With ``coarse`` (`strauss_fit.fitting.problem.coarse_problem`), the index scan and
    the starts run on that subsample: a 256² sphere has 51 000 pixels where every sixth
    (8 500) tells the starts apart as well, and each step there costs a sixth; the polish
    then finishes on the full image in a few steps, so the answer is the full image's
    optimum."""
    layout = problem.layout
    screen = coarse if coarse is not None else problem
    ior_candidates = None
    if "ior" in layout.names:
        say("scanning the index of refraction for starting points")
        ior_candidates = yield from scan_ior_steps(screen, guess)
    thetas, sources = yield from start_points_steps(screen, guess, options, ior_candidates, exact_first, say)
    say(
        f"fitting {', '.join(layout.names)} from {thetas.shape[0]} start(s) with {options.solver}"
        + (f" on {screen.value_count() // 3} of {problem.value_count() // 3} pixels" if coarse is not None else "")
    )
    # A single start too stops after start_steps and is finished by the polish: run on,
    # a start creeping towards a bound (the transforms flatten there) took a median of 63
    # steps on the trade-off set against 25 when the polish pins it (23 ms against 46 ms).
    values, costs_, steps, results = (
        np.asarray(v)
        for v in (
            yield solve_starts.call(
                screen,
                np.asarray(thetas),
                options.solver,
                options.rtol,
                options.atol,
                options.start_steps,
                jax.default_backend() != "cpu",
            )
        )
    )
    physical = layout.to_physical_numpy(values)
    finite = np.isfinite(costs_)
    if not finite.any():
        raise StraussFitError("every start of the fit diverged to non-finite values")
    best = int(np.argmin(np.where(finite, costs_, np.inf)))
    statuses = [status_name(int(r)) for r in results]
    start_points = layout.to_physical_numpy(thetas)
    start_records = [
        {
            "start": jsonable(layout.split(start_points[i])),
            "end": jsonable(layout.split(physical[i])),
            "cost": float(costs_[i]),
            "steps": int(steps[i]),
            "status": statuses[i],
            "source": sources[i],
        }
        for i in range(len(costs_))
    ]
    # "equally good": within Δχ² = 1 of the best at the reference noise (costs are χ²/N)
    # (on a subsample the costs are the same χ² per value, so the full image's Δχ² = 1
    # is still 1 / N of them)
    agree = finite & (costs_ <= costs_[best] + 1.0 / problem.value_count())
    spread = {label: float(np.ptp(physical[agree, k])) for k, label in enumerate(layout.labels())}
    near_lower, near_upper = near_bounds(layout, physical[best])
    interior = not (near_lower | near_upper).any()
    if coarse is None and statuses[best] == "successful" and interior:
        # converged away from every bound: the active-set polish would only repeat it
        theta_best, cost_best, polish_count, status, information = values[best], costs_[best], 0, statuses[best], None
    else:
        say("polishing the best start (parameters at a bound held there)")
        theta_best, cost_best, polish_count, status, problem, information = yield from polish_steps(
            problem, values[best], options, near=coarse is not None and statuses[best] == "successful"
        )
    x_best = physical_values(problem, theta_best)
    rss = float(cost_best) * float(problem.residual_scale) ** 2
    return Solved(
        problem,
        x_best,
        rss,
        status,
        int(steps[best]) + polish_count,
        polish_count,
        best,
        start_records,
        spread,
        information,
    )
