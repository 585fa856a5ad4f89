r"""Least-squares recovery of the Strauss parameters from a reference image: :func:`fit`.

The fit minimises :math:`\tfrac12\sum_p \lVert I_\text{model}(p;\theta) - I_\text{target}(p)\rVert^2`
over the usable sphere pixels p (linear RGB), in float64, with θ the unconstrained
parameters of :mod:`strauss_fit.fit.parameters`. Solvers: Levenberg–Marquardt (default),
Gauss–Newton, or the quasi-Newton minimiser BFGS, all from optimistix
(:mod:`strauss_fit.fit.solvers`).

The pieces, in the order a fit uses them: the problem (:mod:`strauss_fit.fit.problem`:
the material-independent part of the rendering is prepared once), the closed-form guess
(:mod:`strauss_fit.fit.guess`), which parameters the image constrains
(:mod:`strauss_fit.fit.identifiability`), the starts and the scan over n
(:mod:`strauss_fit.fit.starts`), the solves and the bound-aware polish
(:mod:`strauss_fit.fit.solvers`), the Laplace uncertainties
(:mod:`strauss_fit.inference.laplace`) and the result (:mod:`strauss_fit.fit.result`).

Only what the scene constrains is fitted; held parameters keep the scene file's
``[material]`` values and the result says why. The decision is taken at the first guess
and again at each optimum, and the fit repeated while the answer is new (at most
:data:`~strauss_fit.fit.identifiability.MAX_DECISIONS` times).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..color import delta_e_2000
from ..errors import StraussFitError
from ..inference.laplace import problem_laplace
from ..io.targets import Target
from ..models.material import PARAMETER_NAMES, Material
from ..precision import uses_float64
from ..render.strauss import Prepared, RenderPlan, plan_render
from ..scene.loading import Scene
from .guess import initial_guess
from .identifiability import (
    MAX_DECISIONS,
    Decision,
    chi2_95,
    decide_free,
    decision_key,
    held_at_optimum,
    hold_ior_without_significant_transparency,
    hold_jointly_dead_at_fit,
    newly_held,
    reference_noise_level,
)
from .options import FitOptions
from .parameters import (
    MATERIAL_SIZES,
    all_intensities,
    intensity_vector,
    jsonable,
    light_parameter_names,
    lights_with,
    material_with,
    value_of,
)
from .problem import Problem, build_problem, coarse_problem, shade_full
from .result import FitResult
from .solvers import SOLVERS, Solved, solve


def candidate_names(scene: Scene, options: FitOptions) -> list[str]:
    """The parameters a fit may free: the material's, and the light intensities with
    ``fit_lights``."""
    names = list(PARAMETER_NAMES)
    if options.fit_lights:
        names += light_parameter_names(scene.lights)
    return names


def parse_fixed(options: FitOptions, allowed: list[str]) -> dict[str, Any]:
    """``options.fixed`` as a dict, checking the names."""
    fixed = {}
    for name, value in options.fixed:
        if name not in allowed:
            raise StraussFitError(f"cannot fix unknown parameter {name!r}; known: {', '.join(allowed)}")
        fixed[name] = value
    return fixed


def reference_noise(target: Target, options: FitOptions) -> float:
    """The noise level the identifiability analysis and the cost's scale use: the given
    one, else :func:`~strauss_fit.fit.identifiability.reference_noise_level` of the
    target's usable pixels."""
    if options.reference_noise is not None:
        return options.reference_noise
    return reference_noise_level(target.pixels[target.usable])


@dataclass
class Round:
    """One decision of the free parameters and the fit under it."""

    decision: Decision
    problem: Problem
    prepared_full: Prepared
    index: np.ndarray
    solved: Solved
    plan: RenderPlan
    material: Material
    scene: Scene


@uses_float64
def fit(
    scene: Scene,
    target: Target,
    options: FitOptions = FitOptions(),
    *,
    progress: Callable[[str], None] | None = None,
) -> FitResult:
    """Fit the material (and optionally light intensities) of ``scene`` to ``target``.

    ``scene`` must already match the target's size
    (:func:`strauss_fit.io.targets.match_scene`). ``options`` defaults to the ``balanced``
    preset (:meth:`FitOptions.preset`). ``progress``, if given, is called with short
    status strings. Runs in float64 whatever ``jax_enable_x64`` says
    (:mod:`strauss_fit.precision`).
    """
    say = progress or (lambda message: None)
    started = time.perf_counter()
    if options.solver not in SOLVERS:
        raise StraussFitError(f"unknown solver {options.solver!r}; expected one of {', '.join(SOLVERS)}")
    if options.starts < 1:
        raise StraussFitError(f"the number of starts must be at least 1, got {options.starts}")
    candidates = candidate_names(scene, options)
    fixed = parse_fixed(options, candidates)
    base_values = {**scene.material.to_dict(), **{k: v for k, v in fixed.items() if k in MATERIAL_SIZES}}
    material = Material.from_dict(base_values)
    lights = lights_with(scene.lights, {k: jnp.asarray(float(v)) for k, v in fixed.items() if k not in MATERIAL_SIZES})
    scene = eqx.tree_at(lambda s: s.lights, scene, lights)
    scene = eqx.tree_at(lambda s: s.material, scene, material)

    if options.free is not None:
        unknown = [n for n in options.free if n not in candidates]
        if unknown:
            raise StraussFitError(
                f"cannot free unknown parameter(s) {', '.join(unknown)}; known: {', '.join(candidates)}"
            )
    probe_plan = plan_render(scene, material, transparent=False)
    prepared_cache: dict = {}  # one prepared scene per render plan, for every problem of this fit
    guess_problem, prepared_full, index = build_problem(
        scene, target, ["color"], material, probe_plan, options, cache=prepared_cache
    )
    say("computing the first guess")
    direct = guess_problem.prepared.direct
    guess = initial_guess(
        np.asarray(guess_problem.target),
        np.ones(index.size, dtype=bool),
        None if direct is None else np.asarray(direct.cos_alpha),
        None if direct is None else np.asarray(direct.cos_beta),
        None if direct is None else np.asarray(guess_problem.prepared.irradiance) * intensity_vector(scene.lights),
        float(np.asarray(scene.lights.ambient)) if scene.lights.ambient is not None else 0.0,
        {
            **material.to_dict(),
            **{n: float(v) for n, v in zip(light_parameter_names(scene.lights), all_intensities(scene.lights))},
        },
    )

    sigma_ref = reference_noise(target, options)
    say("deciding which parameters the image constrains")
    decision = decide_free(scene, target, options, material, guess, candidates, fixed, sigma_ref, cache=prepared_cache)
    solve_started = time.perf_counter()
    kept: Round | None = None  # the fit that stands
    tried = [decision_key(decision, material, scene.lights)]
    best_rss = np.inf
    for attempt in range(MAX_DECISIONS):
        if not decision.free and kept is not None:
            break  # nothing left to refit: the fit before stands
        if not decision.free:
            raise StraussFitError(
                "no parameter is left to fit: the scene constrains none of the candidates "
                f"({'; '.join(f'{k}: {v}' for k, v in decision.held.items())})"
            )
        transparent = "transparency" in decision.free or float(np.asarray(material.transparency)) > 0
        plan = plan_render(scene, material, transparent=transparent)
        problem, prepared_full, index = build_problem(
            scene, target, decision.free, material, plan, options, sigma_ref, cache=prepared_cache
        )
        solved = solve(
            problem, guess, options, say, coarse_problem(problem, prepared_full, index), exact_first=attempt > 0
        )
        fits_done = attempt + 1
        # Holding a parameter never lowers the cost; a refit under a new decision stands
        # unless it costs significantly more at the reference noise than the best fit before:
        # Δχ² above the 95 % point of χ² with as many degrees of freedom as it holds values
        # that fit had free (3.84 for one). A stricter Δχ² = 1 rejected holds the analysis
        # had good reason for (a mirror's m at 1, at Δχ² = 1.4) and left C and m "free" at ±2.
        if (
            kept is not None
            and solved.rss > best_rss + chi2_95(newly_held(kept.problem.layout, decision)) * sigma_ref**2
        ):
            say("the refit was worse: keeping the fit before it")
            break
        kept = Round(decision, problem, prepared_full, index, solved, plan, material, scene)
        best_rss = min(solved.rss, best_rss)
        if options.free is not None or attempt == MAX_DECISIONS - 1:
            break
        # The decision was taken at the first guess, which may be far from the truth (a
        # metal mistaken for plastic, say): take it again at the optimum, probing exactly
        # where the fit landed, bounds included (a mirror, s = 1, or an opaque glass, t = 0,
        # must be seen as such, not as the generic material a first guess is), and refit
        # from there if the answer is new.
        fitted = {
            **guess,
            **{name: value_of(name, material, scene.lights) for name in decision.held},
            **jsonable(problem.layout.split(solved.x)),
        }
        pinned = np.asarray(solved.problem.pinned)
        at_bound = frozenset(
            name
            for name, size, offset in zip(problem.layout.names, problem.layout.sizes, problem.layout.offsets)
            if size == 1 and pinned[offset]
        )
        again = decide_free(
            scene,
            target,
            options,
            material,
            fitted,
            candidates,
            fixed,
            sigma_ref,
            margin=0.0,
            at_bound=at_bound,
            cache=prepared_cache,
        )
        hold_ior_without_significant_transparency(again, solved)
        held_values, reasons_at_optimum = held_at_optimum(again, decision, fitted)
        hold_jointly_dead_at_fit(
            again, decision, fitted, solved, material, scene.lights, sigma_ref, held_values, reasons_at_optimum
        )
        again.held.update(reasons_at_optimum)
        next_material = material_with(material, {k: v for k, v in held_values.items() if k in MATERIAL_SIZES})
        next_scene = eqx.tree_at(
            lambda s: s.lights,
            scene,
            lights_with(
                scene.lights, {k: jnp.asarray(float(v)) for k, v in held_values.items() if k not in MATERIAL_SIZES}
            ),
        )
        # a decision is new if it frees other parameters or holds one at another value
        # (a mirror's metalness held at 1 rather than at the scene's 0, say)
        key = decision_key(again, next_material, next_scene.lights)
        if key in tried:
            break
        tried.append(key)
        say(f"at the optimum the image constrains {', '.join(again.free) or 'nothing'}: fitting again from there")
        decision, guess, material, scene = again, {**fitted, **held_values}, next_material, next_scene
    decision, prepared_full, index, solved = kept.decision, kept.prepared_full, kept.index, kept.solved
    plan, material, scene = kept.plan, kept.material, kept.scene
    solve_time = time.perf_counter() - solve_started
    held = {
        name: {"value": value_of(name, material, scene.lights), "reason": reason}
        for name, reason in decision.held.items()
    }
    for name, value in fixed.items():
        held[name] = {"value": value, "reason": "fixed by the user (--fix)"}
    problem, x_best, rss = solved.problem, solved.x, solved.rss
    layout, pinned, status = problem.layout, np.asarray(solved.problem.pinned), solved.status
    starts, spread = solved.starts, solved.spread
    notes = [
        f"equally good fits (within Δχ² = 1 of the best) disagree on {label} by {value:.2g}: "
        "the image may not pin it down"
        for label, value in spread.items()
        if value > 0.05
    ]
    uncertainty, correlation, _ = problem_laplace(problem, x_best, rss, None, solved.information)
    fitted_values = layout.split(x_best)
    fitted_material = material_with(material, fitted_values)
    fitted_lights = lights_with(scene.lights, fitted_values)
    full_fit = np.asarray(shade_full(fitted_material, prepared_full, fitted_lights, scene, plan)).reshape(-1, 3)
    model = full_fit[index]  # the fitted radiance at the pixels used
    residual = model - np.asarray(problem.target)
    delta_e = delta_e_2000(model, np.asarray(problem.target))
    full = np.where(
        np.asarray(prepared_full.hit).reshape(-1, 1), full_fit, np.asarray(prepared_full.miss_radiance).reshape(-1, 3)
    )

    if status != "successful":
        notes.append(f"the solver ended with status '{status}'")
    for name in layout.names:
        lo, hi = (
            layout.lower_bounds()[layout.offsets[layout.names.index(name)]],
            layout.upper_bounds()[layout.offsets[layout.names.index(name)]],
        )
        value = np.atleast_1d(np.asarray(fitted_values[name]))
        if np.any(np.isclose(value, lo, atol=1e-6)) or np.any(np.isclose(value, hi, atol=1e-6)):
            notes.append(f"{name} sits on its bound; its Laplace deviation is not a symmetric interval there")
    return FitResult(
        material=fitted_material,
        free=list(layout.names),
        held=held,
        lights={n: float(v) for n, v in zip(light_parameter_names(fitted_lights), all_intensities(fitted_lights))},
        uncertainty=uncertainty,
        correlation=correlation,
        residual={
            "rms": float(np.sqrt(np.mean(residual**2))),
            "max_abs": float(np.max(np.abs(residual))),
            "delta_e2000_mean": float(np.mean(delta_e)),
            "delta_e2000_p95": float(np.percentile(delta_e, 95)),
            "sum_of_squares": rss,
        },
        solver={
            "name": options.solver,
            "steps": solved.steps,
            "status": status,
            "best_start": solved.best,
            "polish_steps": solved.polish_steps,
            "attempts": fits_done,
            "at_bound": [label for label, p in zip(layout.labels(), pinned) if p],
        },
        starts=starts,
        start_spread=spread,
        wall_time_s=time.perf_counter() - started,
        compile_and_solve={"solve_s": solve_time},
        pixels_used=int(index.size),
        notes=notes,
        settings={
            **options.as_dict(),
            "reference_noise_used": sigma_ref,
            "target_encoding": target.encoding,
            "clipped_pixels_excluded": target.clipped_count,
            "mask_excluded": target.masked_out_count,
            "depth": scene.depth,
            "traced": {"reflection": plan.reflect, "transmission": plan.transmit},
        },
        fitted_image=full.reshape(target.pixels.shape),
        mask=np.asarray(prepared_full.hit),
        problem=problem,
        x=x_best,
    )
