r"""Least-squares recovery of the Strauss parameters from a reference image (optimistix).

The fit minimises :math:`\tfrac12\sum_p \lVert I_\text{model}(p;\theta) - I_\text{target}(p)\rVert^2`
over the usable sphere pixels p (linear RGB), in float64, with θ the unconstrained
parameters of :mod:`strauss_fit.parameters`. Solvers: Levenberg–Marquardt (default),
Gauss–Newton, or the quasi-Newton minimiser BFGS, all from optimistix.

Speed: everything that does not depend on the material (pixel geometry, the angular terms
F, G and j of every light, backgrounds seen along mirror directions) is computed once
(:func:`strauss_fit.render.prepare`) and restricted to the usable pixels; the solver then
evaluates only the material-dependent part. The starts run on a pixel subsample of a
large image, one after another on a CPU and vectorised with ``vmap`` elsewhere
(:func:`_solve_all`, :func:`_solve`).

Only what the scene constrains is fitted (:mod:`strauss_fit.identifiability`); held
parameters keep the scene file's ``[material]`` values and the result says why.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jax import Array

from .colour_difference import delta_e_2000
from .errors import StraussFitError
from .guess import initial_guess
from .identifiability import DEFAULT_REFERENCE_NOISE, DEFAULT_THRESHOLD, Decision, numerical_decision, structural_reasons
from .lights import Lights
from .material import PARAMETER_NAMES, Material
from .model import DEFAULT_TABLE_SIZE
from .parameters import MATERIAL_SIZES, Layout, light_parameter_names, lights_with, material_with
from .render import Prepared, RenderPlan, plan_render, prepare, shade_prepared, take_pixels
from .scene import Scene
from .solvers import SOLVERS, make_solver
from .target import Target

#: Fixed starting points (smoothness, metalness, transparency) tried besides the guess.
START_GRID = ((0.3, 0.1, 0.2), (0.8, 0.1, 0.6), (0.6, 0.9, 0.4), (0.2, 0.6, 0.8), (0.9, 0.5, 0.1), (0.5, 0.3, 0.5))
#: Unit-interval starts are kept this far inside the bounds (the transform is flat there).
START_MARGIN = 0.02


@dataclass(frozen=True)
class FitOptions:
    """Settings of a fit; every field is recorded in the result."""

    solver: str = "lm"
    starts: int = 4
    max_steps: int = 100
    start_steps: int = 12
    rtol: float = 1e-6
    atol: float = 1e-8
    mode: str = "exact"
    table_size: int = DEFAULT_TABLE_SIZE
    free: tuple[str, ...] | None = None
    fixed: tuple[tuple[str, float | tuple[float, ...]], ...] = ()
    fit_lights: bool = False
    reference_noise: float | None = None
    threshold: float = DEFAULT_THRESHOLD

    def as_dict(self) -> dict[str, Any]:
        return {
            "solver": self.solver, "starts": self.starts, "max_steps": self.max_steps,
            "start_steps": self.start_steps, "rtol": self.rtol,
            "atol": self.atol, "mode": self.mode, "table_size": self.table_size,
            "free": list(self.free) if self.free is not None else None,
            "fixed": {k: v for k, v in self.fixed}, "fit_lights": self.fit_lights,
            "reference_noise": self.reference_noise, "threshold": self.threshold, "precision": "float64",
        }


class Problem(eqx.Module):
    """A fit's data: prepared (material-independent) terms at the usable pixels, the
    target there, the scene, the material and lights that held parameters come from."""

    prepared: Prepared
    target: Array
    scene: Scene
    material: Material
    lights: Lights
    pinned: Array
    pinned_values: Array
    residual_scale: Array
    layout: Layout = eqx.field(static=True)
    plan: RenderPlan = eqx.field(static=True)

    def physical(self, theta: Array) -> Array:
        """Physical values of θ, with pinned entries (at a bound, see :func:`fit`) replaced."""
        return jnp.where(self.pinned, self.pinned_values, self.layout.to_physical(theta))

    def pin(self, mask: np.ndarray, values: np.ndarray) -> "Problem":
        return dataclasses.replace(self, pinned=jnp.asarray(mask), pinned_values=jnp.asarray(values))

    def render_physical(self, x: Array) -> Array:
        """Model radiance (N, 3) at the usable pixels for physical parameters ``x``."""
        values = self.layout.split(x)
        material = material_with(self.material, values)
        prepared = _scaled(self.prepared, lights_with(self.lights, values))
        return shade_prepared(material, prepared, self.scene, self.plan)

    def residual_physical(self, x: Array) -> Array:
        return (self.render_physical(x) - self.target).ravel()

    def residual(self, theta: Array, _args: Any = None) -> Array:
        """What the solver minimises: residuals divided by ``residual_scale`` (the
        reference noise times sqrt(N)), so that tolerances do not depend on image size
        or brightness."""
        return self.residual_physical(self.physical(theta)) / self.residual_scale


def _unit_intensity_scene(scene: Scene) -> Scene:
    """The scene with every light's intensity 1, so that prepared irradiance holds only
    the geometric attenuation and intensities can be applied (or fitted) later."""
    ones = {k: jnp.ones_like(v) for k, v in scene.lights.intensities().items()}
    return eqx.tree_at(lambda s: s.lights, scene, scene.lights.with_intensities(ones))


@eqx.filter_jit
def _solve_all(problem: Problem, thetas: Array, solver_name: str, rtol: float, atol: float, max_steps: int,
               batched: bool):
    """Solve from every row of ``thetas``: vectorised (``vmap``) when ``batched``, else one
    after the other (``lax.map``). Why both: under ``vmap`` the solver's branches (step
    accepted or rejected) become selects that evaluate both sides, which on a CPU, where the
    pixels already fill the cores, costs about twice a sequential solve (measured:
    53 ms against 102 ms for one start at 256², 211 ms against 392 ms for four); on a
    GPU the batch fills the device instead."""
    solver = make_solver(solver_name, rtol, atol)

    def one(theta0):
        solution = optx.least_squares(problem.residual, solver, theta0, max_steps=max_steps, throw=False)
        r = problem.residual(solution.value)
        code = jnp.argmax(jnp.stack([solution.result == getattr(optx.RESULTS, name) for name in _RESULT_NAMES]))
        return solution.value, jnp.sum(r * r), solution.stats["num_steps"], code

    return jax.vmap(one)(thetas) if batched else jax.lax.map(one, thetas)


#: Entries this close to a bound after the first phase are tried pinned to it.
BOUND_SNAP = 0.02


def _near_bounds(layout: Layout, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which entries of the physical point ``x`` lie within :data:`BOUND_SNAP` of their
    lower and of their upper bound."""
    return x - layout.lower_bounds() < BOUND_SNAP, layout.upper_bounds() - x < BOUND_SNAP


@eqx.filter_jit
def _polish_solve(problem: Problem, theta: Array, rtol: float, atol: float, max_steps: int, solver_name: str):
    solver = make_solver(solver_name, rtol, atol)
    solution = optx.least_squares(problem.residual, solver, theta, max_steps=max_steps, throw=False)
    code = jnp.argmax(jnp.stack([solution.result == getattr(optx.RESULTS, name) for name in _RESULT_NAMES]))
    x = problem.physical(solution.value)
    jac = jax.jacfwd(problem.residual_physical)(x) / problem.residual_scale
    residual = problem.residual_physical(x) / problem.residual_scale  # = problem.residual(solution.value)
    return solution.value, jnp.sum(residual**2), solution.stats["num_steps"], code, jac.T @ residual, jac.T @ jac


def _release_gain(information: np.ndarray, gradient: np.ndarray, pinned: np.ndarray, count: int) -> np.ndarray:
    r"""For each pinned entry i, the Newton estimate of how much χ² (at the reference noise)
    would drop if i were released and the free entries F re-optimised with it:
    :math:`N g_i^2 / S_i` with :math:`S_i = H_{ii} - H_{iF} H_{FF}^{-1} H_{Fi}` the Schur
    complement of the Gauss–Newton curvature (g, H of the normalised cost; the free
    entries' slopes vanish at the pinned optimum). Why not :math:`H_{ii}` alone: a pinned
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


def _polish(problem: Problem, theta: np.ndarray, options: FitOptions, near: bool = False):
    """Continue the best start with an active set. Entries within :data:`BOUND_SNAP` of a
    bound are pinned to it and the rest re-solved (Levenberg–Marquardt, whatever the
    solver of the starts; Gauss–Newton when ``near``, i.e. the start converged on the
    subsample, nothing is pinned and only the last few digits are left — it gets there in
    fewer steps, and a round where it raised the cost or did not converge is redone with
    Levenberg–Marquardt); a pinned entry is released if moving it inward would lower χ²
    (at the reference noise) by more than 1 — the Newton estimate of
    :func:`_release_gain`, the free entries following: a KKT check with a statistical
    tolerance — and entries that reach a bound are pinned, unless released before (an entry
    that a round released and the next pulled back towards its bound would otherwise
    alternate). At most three rounds; the cheapest round stands (ties go to the later).

    Why: the smooth transforms reach a bound only with zero slope, so an optimum on a bound
    (m = 0, say, or a noisy fit pulling past it) is approached ever more slowly; pinning
    makes it exact and lets the solver converge on the remaining entries.
    """
    layout = problem.layout
    lower, upper = layout.lower_bounds(), layout.upper_bounds()
    count = problem.target.size
    x = np.asarray(problem.physical(jnp.asarray(theta)))
    start_theta = theta
    start_cost = float(np.asarray(_costs(problem, jnp.asarray(x[None])))[0])
    at_lower, at_upper = _near_bounds(layout, x)
    released = np.zeros_like(at_lower)
    total_steps = 0
    best = None
    for round_ in range(3):
        pinned = at_lower | at_upper
        trial = problem.pin(pinned, np.where(at_lower, lower, np.where(at_upper, upper, x)))
        start = jnp.asarray(theta)
        # Gauss–Newton's QR would divide by the zero Jacobian column of a pinned entry
        gauss_newton = near and not round_ and not pinned.any()
        theta, cost, steps, code, gradient, information = (np.asarray(v) for v in _polish_solve(
            trial, start, options.rtol, options.atol, options.max_steps, "gauss-newton" if gauss_newton else "lm"))
        # (with nothing pinned the trial is the problem itself, so its start cost is start_cost)
        if gauss_newton and not (np.isfinite(cost) and cost <= start_cost and _status(int(code)) == "successful"):
            theta, cost, more, code, gradient, information = (np.asarray(v) for v in _polish_solve(
                trial, start, options.rtol, options.atol, options.max_steps, "lm"))
            steps = steps + more
        total_steps += int(steps)
        if best is None or (np.isfinite(cost) and cost <= best[1] * (1 + 1e-9)):
            best = theta, cost, code, information, trial
        x = np.asarray(trial.physical(jnp.asarray(theta)))
        gain = _release_gain(information, gradient, pinned, count)
        release_lower = at_lower & (gradient < 0) & (gain > 1.0)
        release_upper = at_upper & (gradient > 0) & (gain > 1.0)
        released |= release_lower | release_upper
        near_lower, near_upper = _near_bounds(layout, x)
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
        theta, cost, steps, code, _, information = (np.asarray(v) for v in _polish_solve(
            problem, jnp.asarray(start_theta), options.rtol, options.atol, options.max_steps, "lm"))
        total_steps += int(steps)
        trial = problem
    # JᵀJ at the end, in physical units, for the Laplace errors (saves recomputing J)
    return theta, float(cost), total_steps, _status(int(code)), trial, information * float(trial.residual_scale) ** 2


# Jitted once per shape: run eagerly, these would compile dozens of small XLA programs.
@eqx.filter_jit
def _prepare(scene: Scene, plan: RenderPlan, mode: str, table_size: int) -> Prepared:
    return prepare(scene, plan, mode, table_size, jnp.float64)


_take_pixels = eqx.filter_jit(take_pixels)


@eqx.filter_jit
def _shade_full(material: Material, prepared: Prepared, lights: Lights, scene: Scene, plan: RenderPlan) -> Array:
    return shade_prepared(material, _scaled(prepared, lights), scene, plan)


@eqx.filter_jit
def _to_physical(layout: Layout, theta: Array) -> Array:
    return layout.to_physical(theta)


@eqx.filter_jit
def _jacobian(problem: Problem, x: Array) -> Array:
    return jax.jacfwd(problem.residual_physical)(x)


@eqx.filter_jit
def _render_at(problem: Problem, x: Array) -> Array:
    return problem.render_physical(x)


@dataclass
class FitResult:
    """What a fit found; :meth:`to_json` follows ``shared/formats.md``."""

    material: Material
    free: list[str]
    held: dict[str, dict[str, Any]]
    lights: dict[str, float]
    uncertainty: dict[str, Any]
    correlation: dict[str, Any]
    residual: dict[str, float]
    solver: dict[str, Any]
    starts: list[dict[str, Any]]
    start_spread: dict[str, float]
    wall_time_s: float
    compile_and_solve: dict[str, float]
    pixels_used: int
    notes: list[str] = field(default_factory=list)
    settings: dict[str, Any] = field(default_factory=dict)
    fitted_image: np.ndarray | None = None
    mask: np.ndarray | None = None
    #: The solved problem (entries pinned at bounds included) and the optimum ``x``
    #: (physical values in ``problem.layout`` order), for sampling and reports.
    problem: Problem | None = None
    x: np.ndarray | None = None

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = self.material.to_dict()
        out.update({
            "free": self.free,
            "held": self.held,
            "uncertainty": self.uncertainty,
            "correlation": self.correlation,
            "residual": self.residual,
            "solver": self.solver,
            "starts": self.starts,
            "start_spread": self.start_spread,
            "lights": self.lights,
            "pixels_used": self.pixels_used,
            "wall_time_s": self.wall_time_s,
            "timing": self.compile_and_solve,
            "notes": self.notes,
            "settings": self.settings,
        })
        return out


def _candidate_names(scene: Scene, options: FitOptions) -> list[str]:
    names = list(PARAMETER_NAMES)
    if options.fit_lights:
        names += light_parameter_names(scene.lights)
    return names


def _parse_fixed(options: FitOptions, allowed: list[str]) -> dict[str, Any]:
    fixed = {}
    for name, value in options.fixed:
        if name not in allowed:
            raise StraussFitError(f"cannot fix unknown parameter {name!r}; known: {', '.join(allowed)}")
        fixed[name] = value
    return fixed


def build_problem(scene: Scene, target: Target, names: list[str], material: Material, plan: RenderPlan,
                  options: FitOptions, reference_noise: float = 1.0,
                  cache: dict | None = None) -> tuple[Problem, Prepared, np.ndarray]:
    """The :class:`Problem` for the free ``names``, the full prepared image and the
    flat indices of the pixels used.

    ``cache`` (a dict owned by one :func:`fit` call) keeps the prepared scene per render
    plan: preparing depends only on the camera, the background, where the lights are and
    the plan — not on the material or the lights' intensities, which is all that changes
    between the problems of one fit."""
    key = (plan, options.mode, options.table_size)
    if cache is not None and key in cache:
        prepared_full, index, prepared, pixels = cache[key]
    else:
        prepared_full = _prepare(_unit_intensity_scene(scene), plan, options.mode, options.table_size)
        hit = np.asarray(prepared_full.hit)
        used = hit & target.usable
        if not used.any():
            raise StraussFitError(f"target {target.path} has no usable sphere pixels "
                                  "(all masked, clipped or outside the sphere)")
        index = np.flatnonzero(used.ravel())
        pixels = jnp.asarray(target.pixels.reshape(-1, 3)[index])
        if float(jnp.max(pixels)) <= 0:
            raise StraussFitError(f"target {target.path} is black on every usable sphere pixel: nothing to fit")
        prepared = _take_pixels(prepared_full, jnp.asarray(index))
        if cache is not None:
            cache[key] = prepared_full, index, prepared, pixels
    problem = Problem(
        prepared=prepared,
        target=pixels,
        scene=scene,
        material=material.astype(jnp.float64),
        lights=scene.lights,
        pinned=jnp.zeros(Layout(tuple(names)).size, dtype=bool),
        pinned_values=jnp.zeros(Layout(tuple(names)).size),
        residual_scale=jnp.asarray(reference_noise * np.sqrt(pixels.size)),
        layout=Layout(tuple(names)),
        plan=plan,
    )
    return problem, prepared_full, index


def _starts(layout: Layout, guess: dict[str, Any], count: int, ior_candidates: list[float] | None = None,
            exact_first: bool = False) -> np.ndarray:
    """The guess first, then points of :data:`START_GRID` (colour always from the guess).
    With ``ior_candidates`` (from :func:`_scan_ior`), each candidate index gets its own
    copy of those starts. Starts are kept :data:`START_MARGIN` inside the bounds, except
    the first with ``exact_first``: a refit starts from the optimum before it, where the
    held values were taken, and must be able to stay there (a mirror at s = 0.99995 is
    not one at s = 0.98)."""
    rows = []
    for ior in ior_candidates or [guess.get("ior")]:
        base = dict(guess, ior=ior)
        rows.append(layout.join(base))
        for s, m, t in START_GRID[: max(count - 1, 0)]:
            rows.append(layout.join(dict(base, smoothness=s, metalness=m, transparency=t)))
    thetas = layout.to_unconstrained(np.stack(rows), margin=START_MARGIN)
    if exact_first:
        thetas[0] = layout.to_unconstrained(rows[0])
    return thetas


#: Indices of refraction scanned for starting points when n is fitted.
IOR_SCAN = np.linspace(1.0, 3.0, 81)


@eqx.filter_jit
def _costs(problem: Problem, xs: Array) -> Array:
    return jax.vmap(lambda x: jnp.sum((problem.residual_physical(x) / problem.residual_scale) ** 2))(xs)


def _scan_ior(problem: Problem, guess: dict[str, Any], keep: int = 3) -> list[float]:
    """The ``keep`` best local minima of the cost over :data:`IOR_SCAN`, the other
    parameters at the guess. Why: a patterned background seen through the sphere makes the
    cost oscillate in n, so a local solver must start near the right basin."""
    layout = problem.layout
    # n only shows through transmitted light: scan it at several transparencies (when t is
    # fitted) and keep, per n, the best of them.
    t_values = (0.25, 0.5, 0.75, 1.0) if "transparency" in layout.names else (guess["transparency"],)
    xs = np.stack([layout.join(dict(guess, ior=float(n), transparency=t)) for n in IOR_SCAN for t in t_values])
    costs = np.asarray(_costs(problem, jnp.asarray(xs))).reshape(IOR_SCAN.size, len(t_values))
    costs = np.min(np.where(np.isfinite(costs), costs, np.inf), axis=1)
    interior = np.r_[True, costs[1:] <= costs[:-1]] & np.r_[costs[:-1] <= costs[1:], True]
    minima = sorted(np.flatnonzero(interior), key=lambda i: costs[i])[:keep]
    return [float(IOR_SCAN[i]) for i in minima]


def _laplace(problem: Problem, x: np.ndarray, rss: float, sigma: float | None,
             information: np.ndarray | None = None) -> tuple[dict, dict, np.ndarray | None]:
    """Standard deviations and correlations from the Gauss–Newton approximation
    :math:`\\Sigma = \\sigma^2 (J^\\top J)^{-1}` at the optimum (σ² = RSS/(N − P) unless given).
    Entries pinned at a bound get deviation 0 (they are reported in ``solver.at_bound``).
    ``information``: :math:`J^\\top J` of the physical residuals at ``x`` if already
    computed (the polish does)."""
    layout = problem.layout
    if layout.size == 0:
        return {}, {}, None
    if information is None:
        jacobian = np.asarray(_jacobian(problem, jnp.asarray(x)))
        information = jacobian.T @ jacobian
    free = ~np.asarray(problem.pinned)
    information = np.asarray(information) * np.outer(free, free)
    n, p = problem.target.size, layout.size
    variance = sigma**2 if sigma else rss / max(n - p, 1)
    covariance = variance * np.linalg.pinv(information, rcond=1e-14, hermitian=True)
    sd = np.sqrt(np.maximum(np.diag(covariance), 0.0))
    norm = np.outer(sd, sd)
    corr = np.divide(covariance, norm, out=np.zeros_like(covariance), where=norm > 0)
    uncertainty: dict[str, Any] = {}
    for name, size, offset in zip(layout.names, layout.sizes, layout.offsets):
        values = sd[offset:offset + size]
        uncertainty[name] = values.tolist() if size > 1 else float(values[0])
    correlation = {"labels": layout.labels(), "matrix": np.round(corr, 6).tolist()}
    return uncertainty, correlation, covariance


def decide_free(scene: Scene, target: Target, options: FitOptions, material: Material, guess: dict[str, Any],
                candidates: list[str], fixed: dict[str, Any], sigma: float, margin: float = 0.15,
                at_bound: frozenset[str] = frozenset(), cache: dict | None = None) -> Decision:
    """Which of ``candidates`` to fit (see :mod:`strauss_fit.identifiability`), probing at
    ``guess`` with unit-interval values kept ``margin`` inside their bounds. At a first
    guess a margin keeps a rough estimate off the bounds, where some sensitivities vanish
    (m has no effect at s = 0); at an optimum the fit calls it with margin 0 on purpose:
    if the fit lands on s = 0, m really is invisible."""
    if options.free is not None:
        return Decision(free=[n for n in candidates if n in options.free and n not in fixed],
                        held={n: "held by the user (--free)" for n in candidates if n not in options.free and n not in fixed})
    names = [n for n in candidates if n not in fixed]
    background = scene.background
    black = background.kind == "color" and not np.any(np.asarray(background.color))
    transparency_may_vary = "transparency" in names or float(np.asarray(material.transparency)) > 0
    held = structural_reasons(names, depth=scene.depth, background_kind=background.kind, background_black=black,
                              transparency_may_vary=transparency_may_vary)
    names = [n for n in names if n not in held]
    if not names:
        return Decision(free=[], held=held)
    plan = plan_render(scene, material, transparent="transparency" in names or transparency_may_vary)
    probe_values = dict(guess)
    for key in ("smoothness", "metalness", "transparency"):
        probe_values[key] = float(np.clip(probe_values[key], margin, 1 - margin))
    probe_values["color"] = np.clip(np.asarray(probe_values["color"], dtype=float), margin, 1 - margin)
    problem, _, _ = build_problem(scene, target, names, material, plan, options, cache=cache)
    probe = problem.layout.join(probe_values)
    jacobian = np.asarray(_jacobian(problem, jnp.asarray(probe)))
    decision = numerical_decision(problem.layout, jacobian, probe, sigma, options.threshold, at_bound)
    decision.held = {**held, **decision.held}
    return decision


def _reference_noise(target: Target, options: FitOptions) -> float:
    if options.reference_noise is not None:
        return options.reference_noise
    values = target.pixels[target.usable]
    level = float(np.percentile(values, 98)) if values.size else 1.0
    return DEFAULT_REFERENCE_NOISE * max(level, 1e-6)


def fit(scene: Scene, target: Target, options: FitOptions = FitOptions(), *, progress=None) -> FitResult:
    """Fit the material (and optionally light intensities) of ``scene`` to ``target``.

    ``scene`` must already match the target's size (:func:`strauss_fit.target.match_scene`).
    ``progress``, if given, is called with short status strings.
    """
    say = progress or (lambda message: None)
    started = time.perf_counter()
    if options.solver not in SOLVERS:
        raise StraussFitError(f"unknown solver {options.solver!r}; expected one of {', '.join(SOLVERS)}")
    if options.starts < 1:
        raise StraussFitError(f"the number of starts must be at least 1, got {options.starts}")
    candidates = _candidate_names(scene, options)
    fixed = _parse_fixed(options, candidates)
    base_values = {**scene.material.to_dict(), **{k: v for k, v in fixed.items() if k in MATERIAL_SIZES}}
    material = Material.from_dict(base_values)
    lights = lights_with(scene.lights, {k: jnp.asarray(float(v)) for k, v in fixed.items() if k not in MATERIAL_SIZES})
    scene = eqx.tree_at(lambda s: s.lights, scene, lights)
    scene = eqx.tree_at(lambda s: s.material, scene, material)

    if options.free is not None:
        unknown = [n for n in options.free if n not in candidates]
        if unknown:
            raise StraussFitError(f"cannot free unknown parameter(s) {', '.join(unknown)}; known: {', '.join(candidates)}")
    probe_plan = plan_render(scene, material, transparent=False)
    prepared_cache: dict = {}  # one prepared scene per render plan, for every problem of this fit
    guess_problem, prepared_full, index = build_problem(scene, target, ["color"], material, probe_plan, options,
                                                        cache=prepared_cache)
    say("computing the first guess")
    direct = guess_problem.prepared.direct
    guess = initial_guess(
        np.asarray(guess_problem.target), np.ones(index.size, dtype=bool),
        None if direct is None else np.asarray(direct.cos_alpha),
        None if direct is None else np.asarray(direct.cos_beta),
        None if direct is None else np.asarray(guess_problem.prepared.irradiance) * _intensity_vector(scene.lights),
        float(np.asarray(scene.lights.ambient)) if scene.lights.ambient is not None else 0.0,
        {**material.to_dict(), **{n: float(v) for n, v in zip(light_parameter_names(scene.lights),
                                                                _all_intensities(scene.lights))}},
    )

    sigma_ref = _reference_noise(target, options)
    say("deciding which parameters the image constrains")
    decision = decide_free(scene, target, options, material, guess, candidates, fixed, sigma_ref,
                           cache=prepared_cache)
    solve_started = time.perf_counter()
    kept = None  # the fit that stands: (decision, problem, prepared_full, index, solved, plan, material, scene)
    tried = [_decision_key(decision, material, scene.lights)]
    best_rss = np.inf
    for attempt in range(MAX_DECISIONS):
        if not decision.free and kept is not None:
            break  # nothing left to refit: the fit before stands
        if not decision.free:
            raise StraussFitError("no parameter is left to fit: the scene constrains none of the candidates "
                                  f"({'; '.join(f'{k}: {v}' for k, v in decision.held.items())})")
        transparent = "transparency" in decision.free or float(np.asarray(material.transparency)) > 0
        plan = plan_render(scene, material, transparent=transparent)
        problem, prepared_full, index = build_problem(scene, target, decision.free, material, plan, options, sigma_ref,
                                                      cache=prepared_cache)
        solved = _solve(problem, guess, options, say, coarse_problem(problem, prepared_full, index),
                        exact_first=attempt > 0)
        fits_done = attempt + 1
        # Holding a parameter never lowers the cost; a refit under a new decision stands
        # unless it costs significantly more at the reference noise than the best fit before:
        # Δχ² above the 95 % point of χ² with as many degrees of freedom as it holds values
        # that fit had free (3.84 for one). A stricter Δχ² = 1 rejected holds the analysis
        # had good reason for (a mirror's m at 1, at Δχ² = 1.4) and left C and m "free" at ±2.
        if kept is not None and solved.rss > best_rss + _chi2_95(_newly_held(kept[1].layout, decision)) * sigma_ref**2:
            say("the refit was worse: keeping the fit before it")
            break
        kept = (decision, problem, prepared_full, index, solved, plan, material, scene)
        best_rss = min(solved.rss, best_rss)
        if options.free is not None or attempt == MAX_DECISIONS - 1:
            break
        # The decision was taken at the first guess, which may be far from the truth (a
        # metal mistaken for plastic, say): take it again at the optimum, probing exactly
        # where the fit landed, bounds included (a mirror, s = 1, or an opaque glass, t = 0,
        # must be seen as such, not as the generic material a first guess is), and refit
        # from there if the answer is new.
        fitted = {**guess, **{name: _value_of(name, material, scene.lights) for name in decision.held},
                  **_jsonable(problem.layout.split(solved.x))}
        pinned = np.asarray(solved.problem.pinned)
        at_bound = frozenset(name for name, size, offset in zip(problem.layout.names, problem.layout.sizes,
                                                                problem.layout.offsets)
                             if size == 1 and pinned[offset])
        again = decide_free(scene, target, options, material, fitted, candidates, fixed, sigma_ref, margin=0.0,
                            at_bound=at_bound, cache=prepared_cache)
        _hold_ior_without_significant_transparency(again, solved)
        held_values, reasons_at_optimum = held_at_optimum(again, decision, fitted)
        _hold_jointly_dead_at_fit(again, decision, fitted, solved, material, scene.lights, sigma_ref,
                                  held_values, reasons_at_optimum)
        again.held.update(reasons_at_optimum)
        next_material = material_with(material, {k: v for k, v in held_values.items() if k in MATERIAL_SIZES})
        next_scene = eqx.tree_at(lambda s: s.lights, scene, lights_with(
            scene.lights, {k: jnp.asarray(float(v)) for k, v in held_values.items() if k not in MATERIAL_SIZES}))
        # a decision is new if it frees other parameters or holds one at another value
        # (a mirror's metalness held at 1 rather than at the scene's 0, say)
        key = _decision_key(again, next_material, next_scene.lights)
        if key in tried:
            break
        tried.append(key)
        say(f"at the optimum the image constrains {', '.join(again.free) or 'nothing'}: fitting again from there")
        decision, guess, material, scene = again, {**fitted, **held_values}, next_material, next_scene
    decision, problem, prepared_full, index, solved, plan, material, scene = kept
    solve_time = time.perf_counter() - solve_started
    held = {name: {"value": _value_of(name, material, scene.lights), "reason": reason}
            for name, reason in decision.held.items()}
    for name, value in fixed.items():
        held[name] = {"value": value, "reason": "fixed by the user (--fix)"}
    problem, x_best, rss = solved.problem, solved.x, solved.rss
    layout, pinned, status = problem.layout, np.asarray(solved.problem.pinned), solved.status
    starts, spread = solved.starts, solved.spread
    notes = [f"equally good fits (within Δχ² = 1 of the best) disagree on {label} by {value:.2g}: "
             "the image may not pin it down" for label, value in spread.items() if value > 0.05]
    uncertainty, correlation, _ = _laplace(problem, x_best, rss, None, solved.information)
    fitted_values = layout.split(x_best)
    fitted_material = material_with(material, fitted_values)
    fitted_lights = lights_with(scene.lights, fitted_values)
    full_fit = np.asarray(_shade_full(fitted_material, prepared_full, fitted_lights, scene, plan)).reshape(-1, 3)
    model = full_fit[index]  # the fitted radiance at the pixels used
    residual = model - np.asarray(problem.target)
    delta_e = delta_e_2000(model, np.asarray(problem.target))
    full = np.where(np.asarray(prepared_full.hit).reshape(-1, 1), full_fit,
                    np.asarray(prepared_full.miss_radiance).reshape(-1, 3))

    if status != "successful":
        notes.append(f"the solver ended with status '{status}'")
    for name in layout.names:
        lo, hi = layout.lower_bounds()[layout.offsets[layout.names.index(name)]], \
            layout.upper_bounds()[layout.offsets[layout.names.index(name)]]
        value = np.atleast_1d(np.asarray(fitted_values[name]))
        if np.any(np.isclose(value, lo, atol=1e-6)) or np.any(np.isclose(value, hi, atol=1e-6)):
            notes.append(f"{name} sits on its bound; its Laplace deviation is not a symmetric interval there")
    result = FitResult(
        material=fitted_material,
        free=list(layout.names),
        held=held,
        lights={n: float(v) for n, v in zip(light_parameter_names(fitted_lights), _all_intensities(fitted_lights))},
        uncertainty=uncertainty,
        correlation=correlation,
        residual={
            "rms": float(np.sqrt(np.mean(residual**2))),
            "max_abs": float(np.max(np.abs(residual))),
            "delta_e2000_mean": float(np.mean(delta_e)),
            "delta_e2000_p95": float(np.percentile(delta_e, 95)),
            "sum_of_squares": rss,
        },
        solver={"name": options.solver, "steps": solved.steps, "status": status, "best_start": solved.best,
                "polish_steps": solved.polish_steps, "attempts": fits_done,
                "at_bound": [label for label, p in zip(layout.labels(), pinned) if p]},
        starts=starts,
        start_spread=spread,
        wall_time_s=time.perf_counter() - started,
        compile_and_solve={"solve_s": solve_time},
        pixels_used=int(index.size),
        notes=notes,
        settings={**options.as_dict(), "reference_noise_used": sigma_ref, "target_encoding": target.encoding,
                  "clipped_pixels_excluded": target.clipped_count, "mask_excluded": target.masked_out_count,
                  "depth": scene.depth, "traced": {"reflection": plan.reflect, "transmission": plan.transmit}},
        fitted_image=full.reshape(target.pixels.shape),
        mask=np.asarray(prepared_full.hit),
        problem=problem,
        x=x_best,
    )
    return result


#: 95 % points of χ² with 1 to 10 degrees of freedom.
_CHI2_95 = (3.841, 5.991, 7.815, 9.488, 11.070, 12.592, 14.067, 15.507, 16.919, 18.307)


def _chi2_95(dof: int) -> float:
    """The 95 % point of χ² with ``dof`` (≥ 1) degrees of freedom (Wilson–Hilferty above 10)."""
    dof = max(int(dof), 1)
    if dof <= len(_CHI2_95):
        return _CHI2_95[dof - 1]
    return dof * (1 - 2 / (9 * dof) + 1.6449 * np.sqrt(2 / (9 * dof))) ** 3


def _newly_held(before: Layout, decision: Decision) -> int:
    """How many scalar values ``before`` fitted that ``decision`` holds."""
    return sum(size for name, size in zip(before.names, before.sizes) if name not in decision.free)


#: How many times the free set is decided and fitted at most: at the first guess, then at
#: each optimum while the answer is new.
MAX_DECISIONS = 3
#: A fitted smoothness at least this is a mirror (see :func:`held_at_optimum`): above it the
#: diffuse term (1 − s³) and the highlight (exponent 3/(1 − s) ≥ 300) are nearly invisible,
#: and the rule applies only where the analysis found metalness trading off with colour.
MIRROR_SMOOTHNESS = 0.99


def held_at_optimum(again: Decision, before: Decision, fitted: dict[str, Any]) -> tuple[dict[str, Any], dict[str, str]]:
    """Values for the parameters that the decision at the optimum (``again``) holds and the
    first one (``before``) fitted, and reasons that replace the analysis's.

    A parameter that *trades off* with another, or that the image depends on only barely, is
    held at the value the fit reached: the image pins only a combination (or nothing
    useful), and the refit from there reproduces it. One such
    combination has a canonical choice: over a uniform backdrop a mirror (s ≈ 1) shows no
    diffuse light and no highlight, only the backdrop tinted by C_s = 1 + m(1 − F)(C − 1),
    so metalness and colour enter only as the tint m·(C − 1). Metalness is held at 1 there,
    which reproduces every tint with C = 1 + m(C − 1) in [0, 1], so that the colour reported
    *is* the mirror's tint. A parameter the image does not depend on at all keeps the value
    it had (the scene's): the fit's value of it means nothing.
    """
    values: dict[str, Any] = {}
    reasons: dict[str, str] = {}
    for name in again.held:
        if name in before.held:
            reasons[name] = before.held[name]  # held before, at the value it still has
            continue
        if name in again.dead or name not in again.partner:
            continue
        if name == "metalness" and again.partner[name] == "color" and "color" in again.free \
                and float(fitted["smoothness"]) >= MIRROR_SMOOTHNESS:
            metalness = float(fitted["metalness"])
            tint = metalness * (np.asarray(fitted["color"], dtype=float) - 1.0)
            values["metalness"] = 1.0
            values["color"] = np.clip(1.0 + tint, 0.0, 1.0).tolist()
            reasons["metalness"] = (f"the fit found a mirror (s = {float(fitted['smoothness']):.4g}), which shows "
                                    "only the backdrop tinted by "
                                    "C_s = 1 + m(1 − F)(C − 1): metalness and colour enter only as the tint "
                                    "m·(C − 1). Held at 1, so that the colour reported is the mirror's tint "
                                    f"({again.held[name]})")
        else:
            values[name] = fitted[name]
            reasons[name] = f"{again.held[name]}; held at the value the fit reached"
    return values, reasons


def _hold_ior_without_significant_transparency(again: Decision, solved: "_Solved") -> None:
    """Hold n at the scene's value — whether the analysis found it free or held it as
    barely visible — when the fitted transparency is within two Laplace deviations of 0.
    Why: the local analysis sees n's effect at the fitted t, however small — and with
    t = 0.003 ± 0.002 noise alone can buy a χ² gain through n (an opaque sphere
    before a checkerboard, fitted n = 1.02 ± 0.002 against a true 1.7) — but that effect
    vanishes at t = 0, which the data do not exclude: n is then not what the image shows.
    Updates ``again`` in place."""
    layout = solved.problem.layout
    numerically_held = "ior" in again.held and "ior" in again.partner
    if not ("ior" in again.free or numerically_held) or not {"ior", "transparency"} <= set(layout.names):
        return
    transparency = float(solved.x[layout.offsets[layout.names.index("transparency")]])
    uncertainty, _, _ = _laplace(solved.problem, solved.x, solved.rss, None, solved.information)
    deviation = float(uncertainty["transparency"])
    if transparency > 2 * deviation:
        return
    if "ior" in again.free:
        again.free.remove("ior")
    # held as the image not showing it (the scene's value), not at the fitted value
    again.partner.pop("ior", None)
    if "ior" in again.dead:
        again.dead.remove("ior")
    again.held["ior"] = (f"the fitted transparency, t = {transparency:.2g} ± {deviation:.2g}, is not distinguishable "
                         "from 0: the image need not show anything through the sphere, so n would rest on noise")


def _hold_jointly_dead_at_fit(again: Decision, before: Decision, fitted: dict[str, Any], solved: "_Solved",
                              material: Material, lights: Lights, sigma: float, values: dict[str, Any],
                              reasons: dict[str, str]) -> None:
    """Hold the parameters that the image ignores at the optimum at the fitted values
    instead of the scene's, when putting them back to the scene's values would change the
    image (by more than Δχ² = 1 at the reference noise): they are then invisible only
    jointly. A white plastic mirror is one: at C = 1 and m = 0 neither colour nor metalness
    moves the image (the tint is m·(C − 1)), but the scene's colour with its metalness
    would tint it. Updates ``values`` and ``reasons`` in place."""
    layout = solved.problem.layout
    dead = [n for n in again.held if n in again.dead and n not in before.held and n in layout.names]
    if not dead:
        return
    x = np.array(solved.x, dtype=float)
    for name in dead:
        offset, size = layout.offsets[layout.names.index(name)], layout.sizes[layout.names.index(name)]
        x[offset:offset + size] = np.atleast_1d(np.asarray(_value_of(name, material, lights), dtype=float))
    cost = float(np.asarray(_costs(solved.problem, jnp.asarray(x[None])))[0])
    if cost * float(solved.problem.residual_scale) ** 2 <= solved.rss + sigma**2:
        return
    for name in dead:
        values[name] = fitted[name]
        others = [n for n in dead if n != name]
        jointly = f" (together with {', '.join(others)})" if others else ""
        reasons[name] = (f"{again.held[name]} at the fitted point{jointly}; held at the value the fit reached, "
                         "since the scene's value would change the image")


def _decision_key(decision: Decision, material: Material, lights: Lights) -> tuple:
    """What makes two decisions the same fit: the free names and the held values."""
    values = tuple(sorted((name, tuple(np.round(np.atleast_1d(np.asarray(_value_of(name, material, lights),
                                                                           dtype=float)), 6)))
                          for name in decision.held))
    return tuple(decision.free), values


@dataclass
class _Solved:
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


#: Above twice this many usable pixels, the starts run on an evenly strided subsample of
#: about this size and only the best start is continued on every pixel (:func:`_solve`).
COARSE_PIXELS = 8192


def coarse_problem(problem: Problem, prepared_full: Prepared, index: np.ndarray) -> Problem | None:
    """``problem`` restricted to every k-th of its pixels (k = N // :data:`COARSE_PIXELS`),
    or None when it is small enough. The residual scale shrinks with the pixel count, so
    costs (χ² per value at the reference noise) stay comparable."""
    stride = index.size // COARSE_PIXELS
    if stride < 2:
        return None
    subset = np.arange(0, index.size, stride)
    return dataclasses.replace(
        problem, prepared=_take_pixels(prepared_full, jnp.asarray(index[subset])),
        target=problem.target[subset], residual_scale=problem.residual_scale * np.sqrt(subset.size / index.size))


def _solve(problem: Problem, guess: dict[str, Any], options: FitOptions, say, coarse: Problem | None = None,
           exact_first: bool = False) -> _Solved:
    """Every start (:attr:`FitOptions.start_steps` steps each), then the best one
    polished (:func:`_polish`) on every pixel, unless it converged away from the bounds
    on every pixel already.

    With ``coarse`` (:func:`coarse_problem`), the index scan and the starts run on that
    subsample: a 256² sphere has 51 000 pixels where every sixth (8 500) tells the starts
    apart as well, and each step there costs a sixth; the polish then finishes on the full
    image in a few steps, so the answer is the full image's optimum."""
    layout = problem.layout
    screen = coarse if coarse is not None else problem
    ior_candidates = None
    if "ior" in layout.names:
        say("scanning the index of refraction for starting points")
        ior_candidates = _scan_ior(screen, guess)
    thetas = _starts(layout, guess, options.starts, ior_candidates, exact_first and ior_candidates is None)
    say(f"fitting {', '.join(layout.names)} from {thetas.shape[0]} start(s) with {options.solver}"
        + (f" on {screen.target.shape[0]} of {problem.target.shape[0]} pixels" if coarse is not None else ""))
    # A single start too stops after start_steps and is finished by the polish: run on,
    # a start creeping towards a bound (the transforms flatten there) took a median of 63
    # steps on the trade-off set against 25 when the polish pins it (23 ms against 46 ms).
    values, costs, steps, results = (np.asarray(v) for v in _solve_all(
        screen, jnp.asarray(thetas), options.solver, options.rtol, options.atol, options.start_steps,
        jax.default_backend() != "cpu"))
    physical = np.asarray(_to_physical(layout, jnp.asarray(values)))
    finite = np.isfinite(costs)
    if not finite.any():
        raise StraussFitError("every start of the fit diverged to non-finite values")
    best = int(np.argmin(np.where(finite, costs, np.inf)))
    statuses = [_status(int(r)) for r in results]
    start_points = np.asarray(_to_physical(layout, jnp.asarray(thetas)))
    starts = [{"start": _jsonable(layout.split(start_points[i])), "end": _jsonable(layout.split(physical[i])),
               "cost": float(costs[i]), "steps": int(steps[i]), "status": statuses[i]} for i in range(len(costs))]
    # "equally good": within Δχ² = 1 of the best at the reference noise (costs are χ²/N)
    # (on a subsample the costs are the same χ² per value, so the full image's Δχ² = 1
    # is still 1 / N of them)
    agree = finite & (costs <= costs[best] + 1.0 / problem.target.size)
    spread = {label: float(np.ptp(physical[agree, k])) for k, label in enumerate(layout.labels())}
    near_lower, near_upper = _near_bounds(layout, physical[best])
    interior = not (near_lower | near_upper).any()
    if coarse is None and statuses[best] == "successful" and interior:
        # converged away from every bound: the active-set polish would only repeat it
        theta_best, cost_best, polish_steps, status, information = values[best], costs[best], 0, statuses[best], None
    else:
        say("polishing the best start (parameters at a bound held there)")
        theta_best, cost_best, polish_steps, status, problem, information = _polish(
            problem, values[best], options, near=coarse is not None and statuses[best] == "successful")
    x_best = np.asarray(problem.physical(jnp.asarray(theta_best)))
    rss = float(cost_best) * float(problem.residual_scale) ** 2
    return _Solved(problem, x_best, rss, status, int(steps[best]) + polish_steps, polish_steps, best, starts, spread,
                   information)


def _scaled(prepared: Prepared, lights: Lights) -> Prepared:
    """A unit-intensity :class:`Prepared` with the lights' intensities applied."""
    changes = {}
    if prepared.irradiance is not None:
        changes["irradiance"] = prepared.irradiance * _intensity_vector(lights)
    if lights.ambient is not None:
        changes["ambient"] = lights.ambient
    return dataclasses.replace(prepared, **changes)


def _intensity_vector(lights: Lights) -> Any:
    parts = []
    if lights.directional is not None:
        parts.append(lights.directional.intensity)
    if lights.point is not None:
        parts.append(lights.point.intensity)
    return jnp.concatenate(parts) if parts else None


def _all_intensities(lights: Lights) -> list[float]:
    values = []
    vector = _intensity_vector(lights)
    if vector is not None:
        values += [float(v) for v in np.asarray(vector)]
    if lights.ambient is not None:
        values.append(float(np.asarray(lights.ambient)))
    return values


def _value_of(name: str, material: Material, lights: Lights) -> Any:
    if name in MATERIAL_SIZES:
        return material.to_dict()[name]
    return dict(zip(light_parameter_names(lights), _all_intensities(lights)))[name]


def _jsonable(values: dict[str, Any]) -> dict[str, Any]:
    out = {}
    for k, v in values.items():
        arr = np.asarray(v)
        out[k] = arr.tolist() if arr.ndim else float(arr)
    return out


_RESULT_NAMES = ("successful", "max_steps_reached", "nonlinear_max_steps_reached", "nonlinear_divergence",
                 "nonfinite", "singular", "breakdown", "stagnation")


def _status(code: int) -> str:
    return _RESULT_NAMES[code]
