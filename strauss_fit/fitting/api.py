r"""Least-squares recovery of the Strauss parameters from a reference image: `fit`.

The fit minimises `\tfrac12\sum_p \lVert I_\text{model}(p;\theta) - I_\text{target}(p)\rVert^2`
over the usable sphere pixels p (linear RGB), in float64, with θ the unconstrained
parameters of `strauss_fit.fitting.parameters`. Solvers: Levenberg–Marquardt (default),
Gauss–Newton, or the quasi-Newton minimiser BFGS, all from optimistix
(`strauss_fit.fitting.solvers`).

The pieces, in the order a fit uses them: the problem (`strauss_fit.fitting.problem`:
the material-independent part of the rendering is prepared once), the closed-form guess
(`strauss_fit.fitting.guess`), which parameters the image constrains
(`strauss_fit.fitting.identifiability`), the starts and the scan over n
(`strauss_fit.fitting.starts`), the solves and the bound-aware polish
(`strauss_fit.fitting.solvers`), the verdict on whether the model reproduces the target
(`strauss_fit.fitting.diagnosis`, against the target's noise from
`strauss_fit.stats.noise`), the uncertainties (`strauss_fit.stats.laplace`:
the noise sandwich when the noise is known, else the Laplace approximation) and the result
(`strauss_fit.fitting.result`).

Only what the scene constrains is fitted; held parameters keep the scene file's
``[material]`` values and the result says why. The decision is taken at the first guess
and again at each optimum, and the fit repeated while the answer is new (at most
`MAX_DECISIONS` times).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..color import delta_e_2000
from ..engine import Steps, run
from ..errors import StraussFitError
from ..io.targets import Target, reduce_target
from ..models.material import PARAMETER_NAMES, Material
from ..precision import uses_float64
from ..rendering.strauss import Prepared, RenderPlan, plan_render
from ..runtime import keep_freed_memory, release_compiled_code_if_needed
from ..scene.loading import Scene
from ..stats import laplace
from ..stats.laplace import padded_noise, problem_laplace_steps, sandwich_from_parts, sandwich_parts_kernel
from ..stats.noise import NoiseModel, describe_noise
from .diagnosis import (
    REACH_MARGIN,
    Diagnosis,
    diagnose,
    reachable_floor_call,
    reachable_maximum_steps,
    uncertainty_warnings,
)
from .equivalence import equivalence_ranges_steps
from .guess import initial_guess
from .identifiability import (
    MAX_DECISIONS,
    Decision,
    chi2_95,
    decide_free_steps,
    decision_key,
    held_at_optimum,
    hold_ior_without_significant_transparency_steps,
    hold_jointly_dead_at_fit_steps,
    newly_held,
    reference_noise_level,
)
from .options import MISMATCH_LOSS, VISIBLE_DELTA_E, FitOptions
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
from .problem import (
    EXPOSURE,
    ROBUST_LOSSES,
    Problem,
    build_problem_steps,
    coarse_problem_steps,
    resolve_edge_pixels_steps,
    shade_full,
)
from .result import FitResult, finite_or_none
from .solvers import SOLVERS, Solved, solve_steps


def candidate_names(scene: Scene, options: FitOptions) -> list[str]:
    """The parameters a fit may free: the material's, the light intensities with
    ``fit_lights`` and the global exposure with ``fit_exposure``."""
    names = list(PARAMETER_NAMES)
    if options.fit_lights:
        names += light_parameter_names(scene.lights)
    if options.fit_exposure:
        names.append(EXPOSURE)
    return names


def parse_fixed(options: FitOptions, allowed: list[str]) -> dict[str, Any]:
    """``options.fixed`` as a dict, checking the names (the exposure may always be fixed)."""
    fixed = {}
    for name, value in options.fixed:
        if name not in allowed and name != EXPOSURE:
            raise StraussFitError(f"cannot fix unknown parameter {name!r}; known: {', '.join(allowed)}")
        if name == EXPOSURE and not (np.isfinite(float(value)) and float(value) > 0):
            raise StraussFitError(f"the exposure must be a positive number, got {value}")
        fixed[name] = value
    return fixed


def reference_noise(target: Target, options: FitOptions) -> float:
    """The noise level the identifiability analysis and the cost's scale use: the given
    one, else `reference_noise_level` of the
    target's usable pixels."""
    if options.reference_noise is not None:
        return options.reference_noise
    # every pixel usable (a render, a photograph without a mask): no copy of the selection
    values = target.pixels if target.usable.all() else target.pixels[target.usable]
    return reference_noise_level(values)


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
    exposure: float


@uses_float64
def fit(
    scene: Scene,
    target: Target,
    options: FitOptions = FitOptions(),
    *,
    progress: Callable[[str], None] | None = None,
) -> FitResult:
    """Fit the material (and optionally light intensities and the exposure) of ``scene``
    to ``target``.

    ``scene`` must already match the target's size
    (`strauss_fit.io.targets.match_scene`). ``options`` defaults to the ``balanced``
    preset (`FitOptions.preset`). ``progress``, if given, is called with short
    status strings. Runs in float64 whatever ``jax_enable_x64`` says
    (`strauss_fit.precision`). Many targets: `strauss_fit.fit_many`, which runs
    the same steps (`fit_steps`) batched.

    Examples:
        A render of a known material, fitted back (noise-free, so recovered exactly):

        >>> import numpy as np
        >>> import strauss_fit as sf
        >>> scene = sf.load_scene("data_synth/scenes/key_and_fill.toml")
        >>> image, mask = sf.render(scene, sf.Material(color=(0.8, 0.2, 0.1), smoothness=0.6, metalness=0.3))
        >>> target = sf.Target(np.asarray(image), np.asarray(mask), "example", "linear", 0, 0)
        >>> result = sf.fit(scene, target, sf.FitOptions(free=("color", "smoothness", "metalness")))
        >>> round(float(result.material.smoothness), 3), round(float(result.material.metalness), 3)
        (0.6, 0.3)
    """
    keep_freed_memory()
    release_compiled_code_if_needed()
    return run(fit_steps(scene, target, options, progress=progress))


def fit_steps(
    scene: Scene,
    target: Target,
    options: FitOptions = FitOptions(),
    *,
    progress: Callable[[str], None] | None = None,
    cache: dict | None = None,
) -> Steps:
    """`fit` as steps (`strauss_fit.engine`): the one definition of a fit,
    run directly by `fit` and batched by `strauss_fit.fit_many`. ``cache``
    (a dict) may be shared by the fits of one scene, which then prepare it once."""
    say = progress or (lambda message: None)
    started = time.perf_counter()
    setup = _set_up(scene, target, options, say)
    # one prepared scene per render plan, for every problem of this fit
    prepared_cache: dict = {} if cache is None else cache
    first = yield from _first_guess_steps(setup, options, prepared_cache, say)
    options, target = first.options, setup.target
    loss = "linear" if options.loss == "auto" else options.loss
    # the robust losses scale residuals by each value's noise: at the target's level, the
    # only one there is before a fit (a whole image's worth: only for a loss that reads it)
    noise_sigma = _image_noise(first.noise, target) if loss in ROBUST_LOSSES else None
    sigma_ref = reference_noise(target, options)
    context = _Context(
        target, options, setup.candidates, setup.fixed, sigma_ref, prepared_cache, loss, noise_sigma, say
    )
    say("deciding which parameters the image constrains")
    decision = yield from decide_free_steps(
        setup.scene,
        target,
        options,
        setup.material,
        first.guess,
        setup.candidates,
        setup.fixed,
        sigma_ref,
        cache=prepared_cache,
    )
    solve_started = time.perf_counter()
    kept, fits_done = yield from _rounds_steps(
        context, decision, first.guess, setup.material, setup.scene, setup.exposure
    )
    kept, outcome = yield from _verdict_steps(context, kept, first.noise)
    solve_time = time.perf_counter() - solve_started
    result = yield from _result(
        kept, outcome, setup.fixed, target, options, first.noise, sigma_ref, fits_done, started, solve_time
    )
    result.notes.extend(note for note in (setup.reduction, first.edge_note, first.noise.sidecar_problem) if note)
    return result


@dataclass
class _SetUp:
    """A fit's inputs checked and made ready: the scene with the user's fixed values in it."""

    scene: Scene
    #: the target as fitted (`reduce_target`: its size may be reduced)
    target: Target
    #: the scene's material with the fixed material values
    material: Material
    #: the parameters the fit may free (`candidate_names`)
    candidates: list[str]
    #: the user's fixed values (`parse_fixed`)
    fixed: dict[str, Any]
    exposure: float
    #: what the reduction of the target did, if anything (a note for the result)
    reduction: str | None


def _set_up(scene: Scene, target: Target, options: FitOptions, say: Callable[[str], None]) -> _SetUp:
    """The options checked, the target reduced and the fixed values put into the scene,
    before any work: a bad option is a one-line error, not a failure halfway."""
    options.validate()
    scene, target, reduction = reduce_target(scene, target)
    if reduction:
        say(reduction)
    if options.solver not in SOLVERS:
        raise StraussFitError(f"unknown solver {options.solver!r}; expected one of {', '.join(SOLVERS)}")
    if options.starts < 1:
        raise StraussFitError(f"the number of starts must be at least 1, got {options.starts}")
    candidates = candidate_names(scene, options)
    fixed = parse_fixed(options, candidates)
    exposure = float(fixed.get(EXPOSURE, 1.0))
    base_values = {**scene.material.to_dict(), **{k: v for k, v in fixed.items() if k in MATERIAL_SIZES}}
    # float64 at once: every problem of the fit casts its material to it (Material.astype), a no-op then
    material = Material.from_dict(base_values, dtype=jnp.float64)
    light_values = {k: jnp.asarray(float(v)) for k, v in fixed.items() if k not in MATERIAL_SIZES and k != EXPOSURE}
    scene = eqx.tree_at(lambda s: s.lights, scene, lights_with(scene.lights, light_values))
    scene = eqx.tree_at(lambda s: s.material, scene, material)

    if options.free is not None:
        unknown = [n for n in options.free if n not in candidates]
        if unknown:
            raise StraussFitError(
                f"cannot free unknown parameter(s) {', '.join(unknown)}; known: {', '.join(candidates)}"
            )
        both = [n for n in options.free if n in fixed]
        if both:
            raise StraussFitError(f"{', '.join(both)} both freed and fixed: free a parameter or fix it, not both")
    return _SetUp(scene, target, material, candidates, fixed, exposure, reduction)


@dataclass
class _FirstGuess:
    """What a fit knows before it decides what to free."""

    #: the options with the edge pixels resolved (what the result records)
    options: FitOptions
    #: why the edge pixels were included or left out, if that was decided (a note)
    edge_note: str | None
    #: a value for every candidate parameter (`initial_guess`)
    guess: dict[str, Any]
    #: the target's noise at the pixels used (`describe_noise`)
    noise: NoiseModel


def _first_guess_steps(setup: _SetUp, options: FitOptions, prepared_cache: dict, say: Callable[[str], None]) -> Steps:
    """Steps giving the `_FirstGuess`: the edge pixels resolved, the pixels to fit
    chosen, the closed-form guess from them, and the target's noise there."""
    scene, target, material, exposure = setup.scene, setup.target, setup.material, setup.exposure
    probe_plan = plan_render(scene, material, transparent=False)
    edge_pixels, edge_note = yield from resolve_edge_pixels_steps(
        scene, target, probe_plan, options, prepared_cache, exposure
    )
    options = dataclasses.replace(options, edge_pixels=edge_pixels)  # what the result records
    guess_problem, _prepared_full, index = yield from build_problem_steps(
        scene, target, ["color"], material, probe_plan, options, cache=prepared_cache, exposure=exposure, pad=True
    )
    if edge_note:
        say(edge_note)  # after the check that there are pixels to fit
    say("computing the first guess")
    guess = _initial_guess(guess_problem, index, scene, material, exposure)
    used_mask = np.zeros(target.pixels.shape[:2], dtype=bool)
    used_mask.reshape(-1)[index] = True
    noise = describe_noise(target.pixels, used_mask, encoding=target.encoding, path=target.path, given=options.noise)
    return _FirstGuess(options, edge_note, guess, noise)


def _initial_guess(
    guess_problem: Problem, index: np.ndarray, scene: Scene, material: Material, exposure: float
) -> dict[str, Any]:
    """The closed-form first guess (`initial_guess`) of every
    candidate parameter from the pixels of ``guess_problem``, the exposure included."""
    direct = guess_problem.prepared.direct
    real = guess_problem.real  # host arrays, NumPy only: nothing here compiles per pixel count
    guess = initial_guess(
        real(guess_problem.target) / exposure,
        np.ones(index.size, dtype=bool),
        None if direct is None else real(direct.cos_alpha),
        None if direct is None else real(direct.cos_beta),
        None
        if direct is None
        else real(guess_problem.prepared.irradiance) * np.asarray(intensity_vector(scene.lights)),
        float(np.asarray(scene.lights.ambient)) if scene.lights.ambient is not None else 0.0,
        {
            **material.to_dict(),
            **{n: float(v) for n, v in zip(light_parameter_names(scene.lights), all_intensities(scene.lights))},
        },
    )
    guess[EXPOSURE] = exposure
    return guess


@dataclass
class _Context:
    """What stays the same through every round of one fit."""

    target: Target
    options: FitOptions
    candidates: list[str]
    fixed: dict[str, Any]
    #: the reference noise level (`reference_noise`)
    sigma_ref: float
    prepared_cache: dict
    loss: str
    #: every value's noise σ for a robust loss, else None (`_image_noise`)
    noise_sigma: np.ndarray | None
    say: Callable[[str], None]


def _rounds_steps(
    context: _Context, decision: Decision, guess: dict[str, Any], material: Material, scene: Scene, exposure: float
) -> Steps:
    """Steps giving the `Round` that stands and the number of fits run: the fit
    under ``decision``, then, while the decision taken again at its optimum is new, the
    fit under that one (at most `MAX_DECISIONS`)."""
    options, sigma_ref, say = context.options, context.sigma_ref, context.say
    kept: Round | None = None  # the fit that stands
    tried = [decision_key(decision, material, scene.lights, exposure)]
    best_rss = np.inf
    for attempt in range(MAX_DECISIONS):
        if not decision.free and kept is not None:
            break  # nothing left to refit: the fit before stands
        if not decision.free:
            raise StraussFitError(
                "no parameter is left to fit: the scene constrains none of the candidates "
                f"({'; '.join(f'{k}: {v}' for k, v in decision.held.items())})"
            )
        current = yield from _round_steps(context, decision, guess, material, scene, exposure, attempt > 0)
        fits_done = attempt + 1
        # Holding a parameter never lowers the cost; a refit under a new decision stands
        # unless it costs significantly more at the reference noise than the best fit before:
        # Δχ² above the 95 % point of χ² with as many degrees of freedom as it holds values
        # that fit had free (3.84 for one). A stricter Δχ² = 1 rejected holds the analysis
        # had good reason for (a mirror's m at 1, at Δχ² = 1.4) and left C and m "free" at ±2.
        if (
            kept is not None
            and current.solved.rss > best_rss + chi2_95(newly_held(kept.problem.layout, decision)) * sigma_ref**2
        ):
            say("the refit was worse: keeping the fit before it")
            break
        kept = current
        best_rss = min(current.solved.rss, best_rss)
        if options.free is not None or attempt == MAX_DECISIONS - 1:
            break
        again, fitted, held_values = yield from _decide_at_optimum_steps(context, kept, guess)
        next_material, next_scene, next_exposure = _with_held(material, scene, exposure, held_values)
        # a decision is new if it frees other parameters or holds one at another value
        # (a mirror's metalness held at 1 rather than at the scene's 0, say)
        key = decision_key(again, next_material, next_scene.lights, next_exposure)
        if key in tried:
            break
        tried.append(key)
        say(f"at the optimum the image constrains {', '.join(again.free) or 'nothing'}: fitting again from there")
        decision, guess, material, scene = again, {**fitted, **held_values}, next_material, next_scene
        exposure = next_exposure
    return kept, fits_done


def _round_steps(
    context: _Context,
    decision: Decision,
    guess: dict[str, Any],
    material: Material,
    scene: Scene,
    exposure: float,
    exact_first: bool,
) -> Steps:
    """Steps giving the `Round` of one decision: its problem built and solved from
    ``guess`` (``exact_first``: a refit, which starts with the exact solve)."""
    transparent = "transparency" in decision.free or float(np.asarray(material.transparency)) > 0
    plan = plan_render(scene, material, transparent=transparent)
    problem, prepared_full, index = yield from build_problem_steps(
        scene,
        context.target,
        decision.free,
        material,
        plan,
        context.options,
        context.sigma_ref,
        cache=context.prepared_cache,
        loss=context.loss,
        noise_sigma=context.noise_sigma,
        exposure=exposure,
        pad=True,
    )
    coarse = yield from coarse_problem_steps(problem, prepared_full, index)
    solved = yield from solve_steps(problem, guess, context.options, context.say, coarse, exact_first=exact_first)
    return Round(decision, problem, prepared_full, index, solved, plan, material, scene, exposure)


def _decide_at_optimum_steps(context: _Context, kept: Round, guess: dict[str, Any]) -> Steps:
    """Steps giving the decision taken again at ``kept``'s optimum, the values there
    (``fitted``) and the values it holds at (``held_values``).

    The decision was taken at the first guess, which may be far from the truth (a metal
    mistaken for plastic, say): it is taken again at the optimum, probing exactly where the
    fit landed, bounds included (a mirror, s = 1, or an opaque glass, t = 0, must be seen as
    such, not as the generic material a first guess is)."""
    decision, problem, solved = kept.decision, kept.problem, kept.solved
    material, scene, exposure = kept.material, kept.scene, kept.exposure
    fitted = {
        **guess,
        **{name: value_of(name, material, scene.lights, exposure) for name in decision.held},
        **jsonable(problem.layout.split(solved.x)),
    }
    pinned = np.asarray(solved.problem.pinned)
    at_bound = frozenset(
        name
        for name, size, offset in zip(problem.layout.names, problem.layout.sizes, problem.layout.offsets)
        if size == 1 and pinned[offset]
    )
    again = yield from decide_free_steps(
        scene,
        context.target,
        context.options,
        material,
        fitted,
        context.candidates,
        context.fixed,
        context.sigma_ref,
        margin=0.0,
        at_bound=at_bound,
        cache=context.prepared_cache,
    )
    yield from hold_ior_without_significant_transparency_steps(again, solved)
    held_values, reasons_at_optimum = held_at_optimum(again, decision, fitted)
    yield from hold_jointly_dead_at_fit_steps(
        again,
        decision,
        fitted,
        solved,
        material,
        scene.lights,
        context.sigma_ref,
        held_values,
        reasons_at_optimum,
        exposure,
    )
    again.held.update(reasons_at_optimum)
    return again, fitted, held_values


def _with_held(
    material: Material, scene: Scene, exposure: float, held_values: dict[str, Any]
) -> tuple[Material, Scene, float]:
    """The material, scene (its lights) and exposure with ``held_values`` put in: where
    the next round starts from."""
    next_material = material_with(material, {k: v for k, v in held_values.items() if k in MATERIAL_SIZES})
    next_scene = eqx.tree_at(
        lambda s: s.lights,
        scene,
        lights_with(
            scene.lights,
            {k: jnp.asarray(float(v)) for k, v in held_values.items() if k not in MATERIAL_SIZES and k != EXPOSURE},
        ),
    )
    next_exposure = float(held_values.get(EXPOSURE, exposure))
    return next_material, next_scene, next_exposure


def _verdict_steps(context: _Context, kept: Round, noise: NoiseModel) -> Steps:
    """Steps giving the round that stands and its `_Outcome`: the verdict on
    ``kept``, and with the ``auto`` loss, when the model visibly cannot reproduce the
    target, the fit again under `MISMATCH_LOSS` instead."""
    target, options, loss, say = context.target, context.options, context.loss, context.say
    outcome = yield from _conclude(kept, target, options, noise, loss, say)
    visible = float(np.mean(outcome.delta_e)) >= VISIBLE_DELTA_E
    if options.loss == "auto" and outcome.diagnosis.verdict == "mismatch" and visible and MISMATCH_LOSS != loss:
        say(f"the model cannot reproduce the target: fitting again with the {MISMATCH_LOSS} loss")
        robust_sigma = _image_noise(noise, target) if MISMATCH_LOSS in ROBUST_LOSSES else None
        refit = yield from _refit_with_loss(kept, target, options, MISMATCH_LOSS, robust_sigma, context.sigma_ref, say)
        # the same pixels under the same lights: what Strauss materials reach there is known
        outcome = yield from _conclude(refit, target, options, noise, MISMATCH_LOSS, say, outcome.reachable)
        kept = refit
    return kept, outcome


def _refit_with_loss(
    kept: Round,
    target: Target,
    options: FitOptions,
    loss: str,
    noise_sigma: np.ndarray | None,
    sigma_ref: float,
    say: Callable[[str], None],
) -> Steps:
    """The kept round's fit again under another loss, from its optimum (same free and
    held parameters)."""
    problem, prepared_full, index = yield from build_problem_steps(
        kept.scene,
        target,
        kept.decision.free,
        kept.material,
        kept.plan,
        options,
        sigma_ref,
        loss=loss,
        noise_sigma=noise_sigma,
        exposure=kept.exposure,
        pad=True,
    )
    layout = problem.layout
    start = {
        **kept.material.to_dict(),
        **{n: float(v) for n, v in zip(light_parameter_names(kept.scene.lights), all_intensities(kept.scene.lights))},
        EXPOSURE: kept.exposure,
        **jsonable(layout.split(kept.solved.x)),
    }
    coarse = yield from coarse_problem_steps(problem, prepared_full, index)
    solved = yield from solve_steps(problem, start, options, say, coarse, exact_first=True)
    return Round(
        kept.decision, problem, prepared_full, index, solved, kept.plan, kept.material, kept.scene, kept.exposure
    )


@dataclass
class _Outcome:
    """The fitted images of a round and what they say about the fit."""

    model: np.ndarray
    full: np.ndarray
    delta_e: np.ndarray
    diagnosis: Diagnosis
    #: (N, 3) each used value's noise σ at the fitted radiance ``model``; None when unknown.
    sigma: np.ndarray | None
    #: What Strauss materials reach at the used pixels, as far as the verdict needed it.
    reachable: _Reachable | None = None
    #: The noise sandwich's parts at the fit (`sandwich_parts_kernel`, maybe still being
    #: computed); None when the noise is unknown.
    sandwich: Any = None
    #: The fitted material and lights (the round's with the fitted values), as rendered.
    material: Material | None = None
    lights: Any = None


@dataclass(frozen=True)
class _Reachable:
    """(N, 3) at the used pixels: a white matte plastic's values (`reachable_floor_call`)
    and, where the verdict needed it, the brightest values any material reaches
    (`reachable_maximum_steps`; None when not computed). They depend on the pixels, the
    lights and the exposure, not on the fit: a refit of the same round reuses them."""

    white_floor: np.ndarray
    maximum: np.ndarray | None


def _image_noise(noise: NoiseModel, target: Target) -> np.ndarray | None:
    """Every value's noise σ at the target's own level (H, W, 3), None when unknown."""
    return noise.sigma_at(target.pixels) if noise.known else None


def _conclude(
    kept: Round,
    target: Target,
    options: FitOptions,
    noise: NoiseModel,
    loss: str,
    say: Callable[[str], None],
    reachable: _Reachable | None = None,
) -> Steps:
    """The fitted image of ``kept`` and the verdict on it (`diagnose`); ``reachable``:
    what an earlier conclusion on the same pixels and lights found (`_Reachable`). The
    noise sandwich's kernel is dispatched here too, when the noise is known (its parts in
    `_Outcome.sandwich`, read by `_uncertainty_steps`), so that it runs while the
    verdict's Python does."""
    solved, scene, plan = kept.solved, kept.scene, kept.plan
    problem, layout = solved.problem, solved.problem.layout
    fitted_values = layout.split(solved.x)
    fitted_material = material_with(kept.material, fitted_values)
    fitted_lights = lights_with(scene.lights, fitted_values)
    exposure = float(fitted_values[EXPOSURE]) if EXPOSURE in layout.names else kept.exposure
    full_fit = np.asarray((yield shade_full.call(fitted_material, kept.prepared_full, fitted_lights, scene, plan)))
    full_fit = full_fit.reshape(-1, 3)
    if exposure != 1.0:
        full_fit = full_fit * exposure
    model = full_fit[kept.index]  # the fitted radiance at the pixels used
    sigma = noise.sigma_at(model) if noise.known else None  # once, for the verdict and the ±
    free_lights = EXPOSURE in layout.names or any(n not in MATERIAL_SIZES for n in layout.names)
    # What a white matte plastic reflects (the verdict's floor of what Strauss materials
    # reach), then the noise sandwich's parts (read by `_uncertainty_steps` only): both
    # dispatched now, in the order they are read, so that their compiled work runs while
    # the Python below (ΔE2000, the verdict) does. A round refitted with another loss
    # discards the sandwich (its work, against the 10-20 ms the overlap saves at 256²).
    floor = None
    if not free_lights and (reachable is None or reachable.white_floor.shape != model.shape):
        floor = yield reachable_floor_call(problem)
    sandwich = None
    if sigma is not None:
        sandwich = yield sandwich_parts_kernel.call(
            problem, np.asarray(solved.x, dtype=np.float64), padded_noise(problem, sigma)
        )
    delta_e = delta_e_2000(model, problem.real(problem.target))
    hit = np.asarray(kept.prepared_full.hit).reshape(-1, 1)
    full = np.where(hit, full_fit, np.asarray(kept.prepared_full.miss_radiance).reshape(-1, 3) * exposure)
    say("comparing the fit with the target's noise")
    pinned = np.asarray(problem.pinned)
    reach = None
    if not free_lights:
        if floor is not None:
            reachable = _Reachable(problem.real(np.asarray(floor)), None)
        if _may_be_out_of_reach(problem.real(problem.target), np.maximum(model, reachable.white_floor), sigma):
            if reachable.maximum is None:
                maximum = problem.real((yield from reachable_maximum_steps(problem)))
                reachable = _Reachable(reachable.white_floor, maximum)
            reach = reachable.maximum
    diagnosis = diagnose(
        problem,
        model,
        noise,
        parameters=int((~pinned).sum()),
        delta_e_mean=float(np.mean(delta_e)),
        at_bound=[label for label, p in zip(layout.labels(), pinned) if p],
        reach=reach,
        image=target.pixels,  # an unknown noise is bounded from the whole image
        index=kept.index,
        sigma=sigma,
    )
    return _Outcome(
        model,
        full.reshape(target.pixels.shape),
        delta_e,
        diagnosis,
        sigma,
        reachable,
        sandwich,
        fitted_material,
        fitted_lights,
    )


def _may_be_out_of_reach(target: np.ndarray, floor: np.ndarray, sigma: np.ndarray | None) -> bool:
    """Whether the out-of-reach check needs the reachable maximum (88 renders of the used
    pixels: a fifth of a warm fit): only where the target exceeds, by the check's margin
    (`diagnose`'s: 2 % and 3 σ of the noise at the fitted
    model, ``sigma``, when it is known, 2 % alone otherwise), a ``floor`` of values that Strauss
    materials reach: the fit itself and a white matte plastic. A pixel within the margin of
    a reachable value is not out of reach (were the envelope's sampling of s ever below the
    floor, flagging such a pixel would be a false alarm)."""
    margin = 3.0 * np.nan_to_num(sigma) if sigma is not None else 0.0
    return bool(np.any(target > floor * REACH_MARGIN + margin))


def _result(
    kept: Round,
    outcome: _Outcome,
    fixed: dict[str, Any],
    target: Target,
    options: FitOptions,
    noise: NoiseModel,
    sigma_ref: float,
    fits_done: int,
    started: float,
    solve_time: float,
) -> Steps:
    """Steps giving the `FitResult` of the round that stands: its uncertainties
    (`_uncertainty_steps`), notes, equivalence ranges and warnings, and what the fit
    records of its residual, solver and settings."""
    solved = kept.solved
    problem, x_best = solved.problem, solved.x
    layout, pinned = problem.layout, np.asarray(solved.problem.pinned)
    residual = outcome.model - problem.real(problem.target)
    rss = float(np.sum(residual**2))
    uncertainty = yield from _uncertainty_steps(solved, outcome, noise, rss)
    fitted_values = layout.split(x_best)
    # as `_conclude` rendered them (the same round and values: ``kept`` is the outcome's)
    fitted_material, fitted_lights = outcome.material, outcome.lights
    exposure = float(fitted_values[EXPOSURE]) if EXPOSURE in layout.names else kept.exposure
    notes = _notes(solved, fitted_values)
    equivalence = None
    if options.equivalence and layout.size:
        equivalence = yield from equivalence_ranges_steps(problem, x_best, delta_e=options.equivalence_de)
    free_covariance = yield from _free_covariance_steps(solved, outcome, noise, uncertainty.parts, rss, residual.size)
    warnings = outcome.diagnosis.warnings + uncertainty_warnings(
        layout,
        np.zeros((layout.size, layout.size)) if uncertainty.covariance is None else uncertainty.covariance,
        np.asarray(x_best),
        pinned,
        free_covariance,
        equivalence,
    )
    result = FitResult(
        material=fitted_material,
        free=list(layout.names),
        held=_held(kept, fixed),
        lights={n: float(v) for n, v in zip(light_parameter_names(fitted_lights), all_intensities(fitted_lights))},
        uncertainty=uncertainty.deviations,
        correlation=uncertainty.correlation,
        residual=_residual_record(residual, rss, outcome, noise),
        solver=_solver_record(solved, options, fits_done),
        starts=[finite_or_none(record) for record in solved.starts],
        start_spread=solved.spread,
        wall_time_s=time.perf_counter() - started,
        compile_and_solve={"solve_s": solve_time},
        pixels_used=int(kept.index.size),
        notes=notes,
        settings=_settings_record(kept, target, options, noise, sigma_ref),
        fitted_image=outcome.full,
        mask=np.asarray(kept.prepared_full.hit),
        problem=problem,
        x=x_best,
        warnings=warnings,
        exposure=exposure,
        equivalence=equivalence,
        uncertainty_method=uncertainty.method,
        uncertainty_laplace=uncertainty.laplace_deviations,
        used_index=kept.index,
        standardized_residual=outcome.diagnosis.standardized,
        target_image=target.pixels,
    )
    # a figure that came out NaN or infinite is a computation that broke down: a one-line
    # error naming it (to_json checks every number), never a NaN passed on or written
    result.to_json()
    return result


def _held(kept: Round, fixed: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Every held parameter's value and why it is held: the decision's reasons, and the
    values the user fixed."""
    held = {
        name: {"value": value_of(name, kept.material, kept.scene.lights, kept.exposure), "reason": reason}
        for name, reason in kept.decision.held.items()
    }
    for name, value in fixed.items():
        held[name] = {"value": value, "reason": "fixed by the user (--fix)"}
    return held


@dataclass
class _Uncertainty:
    """The fitted values' deviations, as the result reports them."""

    #: the reported ± by parameter name (the noise sandwich's when the noise is known, else Laplace's)
    deviations: dict[str, Any]
    correlation: dict[str, Any]
    covariance: np.ndarray | None
    #: what the ± is (the result's ``uncertainty_method``)
    method: dict[str, Any]
    laplace_deviations: dict[str, Any]
    #: the noise sandwich's parts (`sandwich_parts_kernel`),
    #: None when the noise is unknown
    parts: Any


def _uncertainty_steps(solved: Solved, outcome: _Outcome, noise: NoiseModel, rss: float) -> Steps:
    """Steps giving the `_Uncertainty` of the fit: the noise sandwich when the noise
    is known, else the Laplace approximation (which is computed either way)."""
    problem, x_best = solved.problem, solved.x
    # JᵀJ of the physical residuals: the polish's (least squares), else one kernel's (with
    # the noise sandwich's parts when the noise is known: one call for both)
    information = solved.information if problem.loss == "linear" else None
    parts = None
    if noise.known:
        parts = outcome.sandwich  # dispatched by `_conclude`
        information = np.asarray(parts["information"]) if information is None else information
    laplace_sd, laplace_corr, laplace_cov = yield from problem_laplace_steps(problem, x_best, rss, None, information)
    if not noise.known:
        method = {
            "name": "laplace",
            "noise_source": "residual",
            "conditional_on_model": True,
            "meaning": "σ² (JᵀJ)⁻¹ with σ² = RSS/(N − P): valid only if the model reproduces the target",
        }
        return _Uncertainty(laplace_sd, laplace_corr, laplace_cov, method, laplace_sd, parts)
    uncertainty, correlation, covariance, extra = sandwich_from_parts(problem, parts)
    method = {
        "name": "noise sandwich",
        "noise_source": noise.source,
        "conditional_on_model": False,
        "meaning": _sandwich_meaning(outcome.diagnosis.verdict, problem.loss),
        **extra,
    }
    return _Uncertainty(uncertainty, correlation, covariance, method, laplace_sd, parts)


def _sandwich_meaning(verdict: str, loss: str) -> str:
    """What the noise sandwich's ± means, for the fit's ``verdict`` and ``loss``."""
    return (
        "how far the fitted values would move with fresh noise: the spread around the best Strauss "
        "approximation of this image"
        + (", not around the true material (the model cannot reproduce the target)" if verdict == "mismatch" else "")
        + (
            f"; for the {loss} loss that approximation is the value its fit converges to at this "
            "noise level (the minimiser of the expected loss), not its fit of the noise-free image"
            if loss in ("huber", "cauchy")  # the robust losses (docs/uncertainty.md)
            else ""
        )
    )


def _notes(solved: Solved, fitted_values: dict[str, Any]) -> list[str]:
    """The result's notes on the solve: equally good starts that disagree, a solver that
    did not succeed, values on their bounds."""
    layout, status = solved.problem.layout, solved.status
    notes = [
        f"equally good fits (within Δχ² = 1 of the best) disagree on {label} by {value:.2g}: "
        "the image may not pin it down"
        for label, value in solved.spread.items()
        if value > 0.05
    ]
    if status != "successful":
        notes.append(f"the solver ended with status '{status}'")
    for name in layout.names:
        lo, hi = (
            layout.lower_bounds()[layout.offsets[layout.names.index(name)]],
            layout.upper_bounds()[layout.offsets[layout.names.index(name)]],
        )
        value = np.atleast_1d(np.asarray(fitted_values[name]))
        if np.any(np.isclose(value, lo, atol=1e-6)) or np.any(np.isclose(value, hi, atol=1e-6)):
            notes.append(f"{name} sits on its bound; its deviation is not a symmetric interval there")
    return notes


def _free_covariance_steps(
    solved: Solved, outcome: _Outcome, noise: NoiseModel, parts: Any, rss: float, values: int
) -> Steps:
    """Steps giving the covariance the fit would have with its pinned entries free (what
    their deviations would be; for the warnings), None when nothing is pinned. ``values``:
    the number of residual values."""
    problem, x_best = solved.problem, solved.x
    layout, pinned = problem.layout, np.asarray(solved.problem.pinned)
    if not pinned.any():
        return None
    variance = float(np.mean(outcome.sigma**2)) if noise.known else rss / max(values - layout.size, 1)
    if parts is None:
        jacobian = np.asarray((yield laplace.jacobian_kernel.call(problem, np.asarray(x_best))))
        free_information = laplace.information(jacobian)
    else:
        free_information = np.asarray(parts["information"])
    return laplace.covariance(free_information, variance)


def _residual_record(residual: np.ndarray, rss: float, outcome: _Outcome, noise: NoiseModel) -> dict[str, Any]:
    """The result's ``residual``: its size, the noise and the verdict."""
    diagnosis = outcome.diagnosis
    # at the fitted radiance, from its σ already computed
    noise_typical = noise.typical(outcome.model, sigma=outcome.sigma) if noise.known else None
    return {
        "rms": float(np.sqrt(np.mean(residual**2))),
        "max_abs": float(np.max(np.abs(residual))),
        "delta_e2000_mean": float(np.mean(outcome.delta_e)),
        "delta_e2000_p95": float(np.percentile(outcome.delta_e, 95)),
        "sum_of_squares": rss,
        "noise": None if noise_typical is None else noise_typical.tolist(),
        "noise_source": noise.source,
        "chi2_per_dof": diagnosis.chi2_per_dof,
        "chi2_expected_sd": diagnosis.expected_sd,
        "verdict": diagnosis.verdict,
        "per_channel": diagnosis.per_channel,
        "regions": diagnosis.regions,
        **diagnosis.bound_keys(),
    }


def _solver_record(solved: Solved, options: FitOptions, fits_done: int) -> dict[str, Any]:
    """The result's ``solver``: how the solve went."""
    layout, pinned = solved.problem.layout, np.asarray(solved.problem.pinned)
    return {
        "name": options.solver,
        "steps": solved.steps,
        "status": solved.status,
        "best_start": solved.best,
        "polish_steps": solved.polish_steps,
        "attempts": fits_done,
        "at_bound": [label for label, p in zip(layout.labels(), pinned) if p],
        "loss": solved.problem.loss,
    }


def _settings_record(
    kept: Round, target: Target, options: FitOptions, noise: NoiseModel, sigma_ref: float
) -> dict[str, Any]:
    """The result's ``settings``: the options and what the fit decided about its input."""
    return {
        **options.as_dict(),
        "reference_noise_used": sigma_ref,
        "target_encoding": target.encoding,
        "clipped_pixels_excluded": target.clipped_count,
        "mask_excluded": target.masked_out_count,
        "depth": kept.scene.depth,
        "traced": {"reflection": kept.plan.reflect, "transmission": kept.plan.transmit},
        "noise_model": noise.to_dict(),
    }
