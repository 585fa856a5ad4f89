"""Phong → Strauss: the steps that convert one Phong material (see
`strauss_fit.convert.converter` for the method).

`strauss_steps` is the whole conversion of one material, written as steps
(`strauss_fit.engine`) so that a chunk's kernel calls run together; it reads, in order:

1. the target, the Phong rendering (`strauss_fit.convert._shared.phong_pixels`);
   a black one returns the closed-form guess (`_black_result`);
2. the fit of C, s and m from every start (`solve`);
3. the canonical branch: for a tinted highlight the best metal, for a white one the best
   dielectric, taken unless it looks less close (`_canonical_branch`);
4. what the image constrains at the optimum, decided as a fit decides it, a metalness
   the image does not determine held at the source's canonical value (`_hold`);
5. the Laplace uncertainties of what stays free (`_uncertainty`) and the result
   (`_result`).

Each step takes the `Converter` whose shared state
(the scene, the settings, the Strauss problems) it works with.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from ..color import delta_e_2000
from ..engine import Steps
from ..errors import StraussFitError
from ..fitting.diagnosis import WEAK_FRACTION
from ..fitting.identifiability import (
    Decision,
    deviation_scale,
    held_at_optimum,
    numerical_decision,
    reference_noise_level,
)
from ..fitting.options import VISIBLE_DELTA_E
from ..fitting.parameters import jsonable, material_with
from ..fitting.problem import physical_values, render_at
from ..fitting.solvers import STRICT_REJECT_RATIO, polish_steps, solve_starts
from ..fitting.starts import START_MARGIN, starts
from ..io.material_tables import Entry
from ..models.material import Material
from ..models.phong import PhongMaterial
from ..stats.laplace import covariance, deviations, jacobian_kernel, problem_laplace_steps
from ..stats.laplace import information as information_of
from ._batches import Direction
from ._guesses import metallic_tint, strauss_guess, triple
from ._problems import STRAUSS_FREE
from ._shared import lobe_note, not_run, phong_pixels, require_finite, residual_stats, scale_of

if TYPE_CHECKING:
    from .converter import Converter

#: Two conversions whose mean CIEDE2000 to the target differ by less than this (a hundredth
#: of a just-noticeable difference) look the same: the one on the canonical branch is taken
#: (a metal for a tinted Phong highlight, a dielectric for a white one).
SAME_LOOK_DE = 0.01


@dataclass
class _Solution:
    """A Phong → Strauss fit: the problem (nothing pinned), the problem with the polish's
    pins, the physical optimum, RSS, steps, status, JᵀJ there (None: to be computed) and
    the rendered model at the pixels used."""

    problem: Any
    pinned: Any
    x: np.ndarray
    rss: float
    steps: int
    status: str
    information: np.ndarray | None
    model: np.ndarray


class Item(NamedTuple):
    """A material to convert: its place in the input, its entry, the closed-form guess
    (`strauss_fit.convert._guesses.strauss_guess`), the guess's notes and the
    Phong material."""

    index: int
    entry: Entry
    guess: dict[str, Any]
    guess_notes: list[str]
    phong: PhongMaterial


def direction(conv: Converter) -> Direction:
    """Phong → Strauss for the batch driver (`strauss_fit.convert._batches.stream`)."""
    return Direction(prepare, functools.partial(strauss_steps, conv))


def prepare(i: int, entry: Entry) -> Item:
    """The item of entry number ``i`` (raises for a material that cannot be built)."""
    material = entry.build()
    guess, notes = strauss_guess(material)
    notes = [f"closed-form guess: {note}" for note in notes]
    return Item(i, entry, guess, notes, material)


def strauss_steps(conv: Converter, item: Item) -> Steps:
    """The Phong → Strauss conversion of one material (an item of `prepare`), as
    steps: the fit of C, s, m; for a tinted highlight the best metal too; then what the
    image constrains, decided as `strauss_fit.fit` decides it, with a metalness the
    image does not determine held at the source's canonical value. Returns the result."""
    _, entry, guess, guess_notes, phong = item
    # rendered here, not when the item is prepared: the renders of a chunk then run as
    # one compiled call, beside other materials' Python, instead of one by one before it
    target = np.asarray((yield phong_pixels.call(conv.scene, phong, conv.index)))
    require_finite(target, "the Phong rendering is not finite")
    if float(np.max(target)) <= 0.0:
        return _black_result(conv, entry, guess, guess_notes, target)
    scale = scale_of(target)
    problem = conv.problems.problem(conv.problems.full, target, scale)
    thetas = starts(problem.layout, guess, conv.settings.starts)
    first, best, ends = yield from solve(conv, problem, thetas, target, scale)
    chosen, best, notes, off_branch_note = yield from _canonical_branch(
        conv, phong, guess, problem, thetas, target, scale, first, best, ends
    )
    current, fitted, held, jacobian = yield from _hold(conv, phong, guess, chosen, target, scale)
    laplace = yield from _uncertainty(current, held, jacobian)
    if off_branch_note is not None and "metalness" not in held:
        notes.append(off_branch_note)
    solver = {
        "status": current.status,
        "steps": int(current.steps),
        "best_start": best,
        "starts": int(len(thetas)),
        "at_bound": laplace[2],
    }
    return _result(conv, item, target, current, fitted, held, notes, laplace, solver)


# --- the fit -----------------------------------------------------------------------------


def solve(
    conv: Converter, problem: Any, thetas: np.ndarray, target: np.ndarray, scale: float, ends: tuple | None = None
) -> Steps:
    """Every start on the coarse pixels (`Settings.start_steps` steps), then the
    best one polished on every pixel (`strauss_fit.fitting.solvers.polish_steps`:
    entries at a bound pinned there), and the model rendered there. ``ends``: the
    starts' ends (θ, costs, steps), when they were solved before. Returns the
    `_Solution`, the best start and the starts' ends."""
    settings = conv.settings
    if ends is None:
        screen = conv.problems.screen(problem, target, scale)
        ends = tuple(
            np.asarray(v)
            for v in (
                yield solve_starts.call(
                    screen,
                    np.asarray(thetas),
                    "lm",
                    settings.rtol,
                    settings.atol,
                    settings.start_steps,
                    conv.batched,
                    STRICT_REJECT_RATIO,
                )
            )
        )[:3]
    values, costs_, steps_ = ends
    finite = np.isfinite(costs_)
    if not finite.any():
        raise StraussFitError("every start of the fit diverged to non-finite values")
    best = int(np.argmin(np.where(finite, costs_, np.inf)))
    theta, cost, polish_count, status, pinned, information = yield from polish_steps(
        problem, values[best], conv.options, reject_ratio=STRICT_REJECT_RATIO
    )
    x = physical_values(pinned, theta)
    require_finite(x, "the fit ended at non-finite parameters")
    rss = float(cost) * float(np.asarray(problem.residual_scale)) ** 2
    model = np.asarray((yield render_at.call(pinned, x)))
    steps = int(int(steps_[best]) + polish_count)
    return _Solution(problem, pinned, x, rss, steps, status, information, model), best, ends


def _refit(
    conv: Converter,
    free: tuple[str, ...],
    values: dict[str, Any],
    fitted: dict[str, Any],
    target: np.ndarray,
    scale: float,
) -> Steps:
    """The fit again with only ``free`` fitted and the other parameters held at
    ``values`` (else their ``fitted`` value), polished from the fitted values."""
    problems = conv.problems
    held = {name: values.get(name, fitted[name]) for name in STRAUSS_FREE if name not in free}
    problem = problems.problem(problems.template(free), target, scale, material_with(problems.base, held))
    start = problem.layout.to_unconstrained(problem.layout.join({**fitted, **held}))
    theta, cost, steps_, status, pinned, information = yield from polish_steps(
        problem, start, conv.options, reject_ratio=STRICT_REJECT_RATIO
    )
    x = physical_values(pinned, theta)
    require_finite(x, "the refit with the held parameters ended at non-finite parameters")
    model = np.asarray((yield render_at.call(pinned, x)))
    rss = float(cost) * scale**2
    return _Solution(problem, pinned, x, rss, int(steps_), status, information, model)


# --- the canonical branch ----------------------------------------------------------------


def _canonical_branch(
    conv: Converter,
    phong: PhongMaterial,
    guess: dict[str, Any],
    problem: Any,
    thetas: np.ndarray,
    target: np.ndarray,
    scale: float,
    first: _Solution,
    best: int,
    ends: tuple,
) -> Steps:
    """The fit on the canonical branch: a tinted highlight is what a metal shows, a white
    one a dielectric's. Least squares in linear RGB can land on the other: Phong gold (its
    narrow lobe and diffuse Kd fit a smooth plastic with a white highlight, ΔE 5, better
    in RMS than the metal, ΔE 1.6, whose diffuse term (1 - ms)(1 - s^3)C ties it to a
    wider lobe); a grey Phong glass renders alike as C = 0.23, m = 0.03 and as C = 0.98,
    m = 0.80 (the highlight dimmed by m(1 - C) either way), and the presets ended in
    either. When the ``first`` fit is off the branch, fit again from the canonical branch
    and take it unless it looks less close to the target.

    Returns the fit taken, its best start, its notes and the note to add should the
    metalness stay free when the first fit stands (None when there is none)."""
    metal_index = _metal_index(problem.layout)
    tinted = metallic_tint(phong)
    if tinted == (first.x[metal_index] >= 0.5):
        return first, best, [], None
    other, other_best = yield from _fit_on_branch(
        conv, tinted, phong, guess, problem, thetas, target, scale, first, best, ends
    )
    taken, note = _choose_branch(tinted, first, other, target, metal_index)
    if taken:
        return other, other_best, [note], None
    return first, best, [], note


def _metal_index(layout: Any) -> int:
    """Where the metalness sits in a problem's parameter vector."""
    return layout.offsets[layout.names.index("metalness")]


def _fit_on_branch(
    conv: Converter,
    tinted: bool,
    phong: PhongMaterial,
    guess: dict[str, Any],
    problem: Any,
    thetas: np.ndarray,
    target: np.ndarray,
    scale: float,
    first: _Solution,
    best: int,
    ends: tuple,
) -> Steps:
    """The fit from the canonical branch's start (for a ``tinted`` highlight a metal of its
    tint, else the guess as a dielectric), reusing the ``first`` fit's work where its start
    was the same. Returns the fit and its best start."""
    layout = problem.layout
    if tinted:
        specular = triple(phong.ks) * np.asarray(phong.specular_color, dtype=np.float64)
        other_start = {**guess, "color": (specular / specular.max()).tolist(), "metalness": 1.0}
    else:
        other_start = {**guess, "metalness": 0.0}
    other_theta = layout.to_unconstrained(layout.join(other_start), margin=START_MARGIN)[None]
    if not np.array_equal(other_theta[0], thetas[0]):
        other, other_best, _ = yield from solve(conv, problem, other_theta, target, scale)
        return other, other_best
    if best == 0:  # the canonical start is the guess, and the first fit came from it
        return first, best
    # the canonical start is the guess: its end on the coarse pixels is known
    other, other_best, _ = yield from solve(conv, problem, other_theta, target, scale, tuple(v[:1] for v in ends))
    return other, other_best


def _choose_branch(
    tinted: bool, first: _Solution, other: _Solution, target: np.ndarray, metal_index: int
) -> tuple[bool, str]:
    """Whether the fit on the canonical branch (``other``) is taken over the ``first``:
    when it ends on the branch and looks as close to the target (mean CIEDE2000 within
    `SAME_LOOK_DE`) or closer. Returns that and the note that says why."""
    looks = float(np.mean(delta_e_2000(first.model, target)))
    other_looks = float(np.mean(delta_e_2000(other.model, target)))
    rms, other_rms = math.sqrt(first.rss / target.size), math.sqrt(other.rss / target.size)
    m, other_m = first.x[metal_index], other.x[metal_index]
    kind = "a metal" if tinted else "a dielectric"
    highlight = "tinted, as a metal's" if tinted else "white, as a dielectric's"
    on_branch = tinted == (other_m >= 0.5)
    if on_branch and other_looks <= looks + SAME_LOOK_DE:
        return True, (
            f"the highlight is {highlight}: the best fit from {kind} (m = {other_m:.3g}, mean "
            f"CIEDE2000 {other_looks:.3g}, linear RMS {other_rms:.3g}) is taken over the least-squares "
            f"optimum found first (m = {m:.3g}, CIEDE2000 {looks:.3g}, RMS {rms:.3g}): it looks "
            + ("closer" if other_looks < looks - SAME_LOOK_DE else "the same")
        )
    why = (
        f"it ends at m = {other_m:.3g}"
        if not on_branch
        else f"it looks less close: mean CIEDE2000 {other_looks:.3g} against {looks:.3g}, "
        f"linear RMS {other_rms:.3g} against {rms:.3g}"
    )
    reason = (
        "Strauss ties a metal's diffuse term to its smoothness, (1 - ms)(1 - s^3)C, so a metal cannot "
        "have both this highlight's width and this diffuse term"
        if tinted
        else "a dielectric's highlight, r_s = s^3 at normal incidence, cannot match this one's strength "
        "at this width without a metal's tint"
    )
    # said only if the metalness stays free (strauss_steps): when the image does not
    # determine it, it is held at the canonical value, and that note says why
    return False, (
        f"the highlight is {highlight}, but the best Strauss match is not {kind}: the best fit started "
        f"from {kind} is no better ({why}); {reason}"
    )


# --- what the image constrains -----------------------------------------------------------


def _hold(
    conv: Converter, phong: PhongMaterial, guess: dict[str, Any], current: _Solution, target: np.ndarray, scale: float
) -> Steps:
    """What the conversion image constrains at the fit ``current`` (`_decide`); the
    parameters it does not are held (`_held_values`) and the others refitted with
    them (`_refit_held`), or, when held at the fitted values, the optimum stands and
    the ± are conditional on them. Returns the fit, its parameter values, the held
    parameters (value and reason) and the Jacobian at the first fit."""
    fitted = jsonable(current.problem.layout.split(current.x))
    held: dict[str, dict[str, Any]] = {}
    decision, jacobian = yield from _decide(conv, current, reference_noise_level(target))
    if not decision.held:
        return current, fitted, held, jacobian
    tinted = metallic_tint(phong)
    canonical = float(guess["metalness"]) if tinted else 0.0
    before = Decision(free=list(current.problem.layout.names))
    values, reasons, hold_metalness = _held_values(decision, before, fitted, tinted, canonical)
    refit = None
    if _changed(values, fitted) and decision.free:
        refit = yield from _refit_held(
            conv, decision, values, reasons, fitted, current, target, scale, canonical if hold_metalness else None
        )
    held.update({name: {"value": values[name], "reason": reasons[name]} for name in decision.held})
    if refit is not None:
        fitted = {**fitted, **values, **jsonable(refit.problem.layout.split(refit.x))}
        refit.steps += current.steps
        return refit, fitted, held, jacobian
    # held at the fitted values: the optimum stands, the ± are conditional on them
    mask = np.array([owner in held for owner in _owners(current.problem.layout)])
    current.pinned = current.pinned.pin(mask | np.asarray(current.pinned.pinned), current.x)
    current.information = None
    return current, fitted, held, jacobian


def _held_values(
    decision: Decision, before: Decision, fitted: dict[str, Any], tinted: bool, canonical: float
) -> tuple[dict[str, Any], dict[str, str], bool]:
    """Values and reasons for the parameters ``decision`` holds at the optimum and
    ``before`` freed (`strauss_fit.fitting.identifiability.held_at_optimum`, else the
    fitted value), with
    a metalness the image does not determine held at the ``canonical`` value (the guess's
    for a ``tinted`` highlight, else 0) — unless it is a mirror's, held at 1. Returns the
    values, the reasons and whether the metalness is held at the canonical value."""
    values, reasons = held_at_optimum(decision, before, fitted)
    mirror = "metalness" in values and float(values["metalness"]) == 1.0 and "mirror" in reasons["metalness"]
    for name in decision.held:
        values.setdefault(name, fitted[name])  # the image ignores it: any value; keep the fit's
        reasons.setdefault(name, f"{decision.held[name]}; held at the value the fit reached")
    hold_metalness = "metalness" in decision.held and not mirror
    if hold_metalness:
        values["metalness"] = canonical
        reasons["metalness"] = f"the conversion image does not determine it: {decision.held['metalness']}; held at " + (
            f"{canonical:.3g}, the closed-form guess from the highlight's tint"
            if tinted
            else "0: the Phong source has no metallic (tinted) highlight"
        )
    return values, reasons, hold_metalness


def _refit_held(
    conv: Converter,
    decision: Decision,
    values: dict[str, Any],
    reasons: dict[str, str],
    fitted: dict[str, Any],
    current: _Solution,
    target: np.ndarray,
    scale: float,
    canonical: float | None,
) -> Steps:
    """The refit of the parameters ``decision`` frees with the held ones at ``values``
    (`_refit`). A metalness held at the ``canonical`` value (None: not held there)
    that would change what the image shows (mean CIEDE2000 above
    `strauss_fit.fitting.options.VISIBLE_DELTA_E` from ``current``'s model) is held at
    the fitted value instead (``values`` and ``reasons`` are updated), and the fit redone
    if anything is still held elsewhere than fitted. Returns the refit, or None when the
    fitted values stand."""
    free = tuple(decision.free)
    refit = yield from _refit(conv, free, values, fitted, target, scale)
    apart = float(np.mean(delta_e_2000(refit.model, current.model)))
    if canonical is None or apart <= VISIBLE_DELTA_E:
        return refit
    # holding it there would change what the image shows: keep the fit's value
    values["metalness"] = fitted["metalness"]
    reasons["metalness"] = (
        f"{decision.held['metalness']}; held at the value the fit reached, since holding it at "
        f"{canonical:.3g} would change the image visibly (mean CIEDE2000 {apart:.2g} from the fit)"
    )
    if not _changed(values, fitted):
        return None
    return (yield from _refit(conv, free, values, fitted, target, scale))


def _decide(conv: Converter, current: _Solution, sigma: float) -> Steps:
    """Which parameters the conversion image constrains at the solution ``current``:
    `strauss_fit.fitting.identifiability.numerical_decision` at the reference noise
    ``sigma`` with the Jacobian there, as a fit decides at its optimum. An entry pinned
    at a bound is protected from being held, as in a fit, where the data push against
    it — not where the cost is nearly flat there (the fit's ``flat-at-bound`` warning:
    free, its deviation would exceed `strauss_fit.fitting.diagnosis.WEAK_FRACTION` of
    its scale): then the bound, not the image, sets it. Returns the decision and the
    Jacobian."""
    layout = current.problem.layout
    jacobian = np.asarray((yield jacobian_kernel.call(current.problem, current.x)))
    pinned = np.asarray(current.pinned.pinned)
    at_bound = frozenset(
        name for name, size, offset in zip(layout.names, layout.sizes, layout.offsets) if size == 1 and pinned[offset]
    )
    scale = np.array([float(deviation_scale(owner, value)) for owner, value in zip(_owners(layout), current.x)])
    loose = deviations(covariance(information_of(jacobian), sigma**2)) > WEAK_FRACTION * scale
    flat = {owner for owner, is_loose in zip(_owners(layout), loose) if is_loose}
    decision = numerical_decision(layout, jacobian, current.x, sigma, conv.options.threshold, at_bound - flat)
    return decision, jacobian


def _changed(values: dict[str, Any], fitted: dict[str, Any]) -> bool:
    """Whether any of ``values`` differs from the fitted value."""
    return any(
        not np.allclose(np.asarray(value, dtype=float), np.asarray(fitted[name], dtype=float))
        for name, value in values.items()
    )


def _owners(layout: Any) -> list[str]:
    """The parameter name of every entry of ``layout`` (``color`` three times)."""
    return [name for name, size in zip(layout.names, layout.sizes) for _ in range(size)]


# --- uncertainties and the result --------------------------------------------------------


def _uncertainty(current: _Solution, held: dict[str, Any], jacobian: np.ndarray) -> Steps:
    """The Laplace deviations and correlations of the free parameters at the fit
    ``current`` (None for a held one: a held value has no interval), from its JᵀJ, or from
    the first fit's ``jacobian`` when the optimum stood. Returns them and the labels of
    the free entries pinned at a bound."""
    layout = current.pinned.layout
    info = jacobian.T @ jacobian if current.information is None else current.information
    uncertainty, correlation, _ = yield from problem_laplace_steps(current.pinned, current.x, current.rss, None, info)
    uncertainty = _held_uncertainty(layout, uncertainty, held)
    for name in held:
        uncertainty.setdefault(name, [None] * 3 if name == "color" else None)
    at_bound = [
        label
        for label, p, owner in zip(layout.labels(), np.asarray(current.pinned.pinned), _owners(layout))
        if p and owner not in held
    ]
    return uncertainty, correlation, at_bound


def _held_uncertainty(layout: Any, uncertainty: dict[str, Any], held: dict[str, Any]) -> dict[str, Any]:
    """``uncertainty`` with None for the held parameters (a held value has no interval)."""
    out = dict(uncertainty)
    for name in held:
        if name in out:
            out[name] = [None] * len(out[name]) if isinstance(out[name], list) else None
    return out


def _strauss_values(entry: Entry, fitted: dict[str, Any]) -> dict[str, Any]:
    """The converted material: the fitted C, s, m, with t = 1 − opacity and n carried over."""
    return {
        "color": [float(c) for c in np.asarray(fitted["color"])],
        "smoothness": float(fitted["smoothness"]),
        "metalness": float(fitted["metalness"]),
        "transparency": float(np.clip(1.0 - entry.opacity, 0, 1)),
        "ior": float(max(entry.ior, 1.0)),
    }


def _common_notes(conv: Converter, entry: Entry, values: dict[str, Any]) -> list[str]:
    """Notes on what does not carry over as a fit: a Blinn–Phong lobe, an opacity, the
    ambient term, a highlight narrower than a pixel."""
    notes = []
    phong = entry.material
    if phong.blinn:
        notes.append("Blinn-Phong source: the smoothness guess used n/4 (cos^n(N·H) ≈ cos^(n/4)(R·V))")
    if entry.opacity < 1:
        notes.append(
            f"transparency t = 1 - d = {1 - entry.opacity:.4g} carried over, not fitted "
            "(the fit matches the opaque appearance)"
        )
    ka = triple(phong.ka) * np.asarray(phong.diffuse_color, dtype=np.float64)
    r_d = (1 - values["smoothness"] ** 3) * np.asarray(values["color"])
    if float(np.max(ka)) > 0 and float(np.max(np.abs(ka - r_d))) > 0.02:
        notes.append(
            f"ka is not a Strauss parameter: Phong's ambient term ka·Cd = {np.round(ka, 3).tolist()} "
            f"becomes Strauss's ambient reflectance r_d·C = {np.round(r_d, 3).tolist()}"
        )
    lobe = lobe_note(conv.scene.camera.width, float(phong.exponent) / (4.0 if phong.blinn else 1.0))
    if lobe:
        notes.append(lobe)
    return notes


def _value_text(value: Any) -> str:
    """A held value for a note: a number, or a colour as a triple."""
    if isinstance(value, (list, tuple)):
        return "(" + ", ".join(f"{float(v):.4g}" for v in value) + ")"
    return f"{float(value):.4g}"


def _result(
    conv: Converter,
    item: Item,
    target: np.ndarray,
    current: _Solution,
    fitted: dict[str, Any],
    held: dict[str, dict[str, Any]],
    notes: list[str],
    laplace: tuple,
    solver: dict[str, Any],
) -> dict[str, Any]:
    """The result of a conversion: the input, the guess, the converted material, the held
    parameters, the uncertainties (``laplace``: deviations, correlations, entries at a
    bound), the ``solver`` record, the notes (the entry's, the guess's, what does not
    carry over, the fit's ``notes`` and the solver's) and the residual."""
    _, entry, guess, guess_notes, _ = item
    uncertainty, correlation, at_bound = laplace
    values = _strauss_values(entry, fitted)
    notes = list(entry.notes) + guess_notes + _common_notes(conv, entry, values) + notes
    if current.status != "successful":
        notes.append(f"the solver ended with status '{current.status}'")
    for name, info in held.items():
        notes.append(f"{name} held at {_value_text(info['value'])}: {info['reason']}")
    if at_bound:
        notes.append(
            "at a bound, where the data push against it (its Laplace deviation, 0 there, is no symmetric "
            f"interval): {', '.join(at_bound)}"
        )
    return {
        "name": entry.name,
        "source": entry.source,
        "status": "ok",
        "input": {"phong": entry.material.to_dict(), "opacity": entry.opacity, "ior": entry.ior},
        "guess": guess,
        "strauss": values,
        "held": held,
        "uncertainty": uncertainty,
        "correlation": correlation,
        "solver": solver,
        "notes": notes,
        # measured here, against this material's own target (its exposure scale)
        "residual": residual_stats(current.model, target),
    }


def _black_result(
    conv: Converter, entry: Entry, guess: dict, guess_notes: list[str], target: np.ndarray
) -> dict[str, Any]:
    """The result of a Phong material that renders black: nothing to fit, the closed-form
    guess is returned (with its residual against the black target)."""
    fitted = _strauss_values(entry, guess)
    model = conv.strauss_target(Material(**{**fitted, "transparency": 0.0}))
    return {
        "name": entry.name,
        "source": entry.source,
        "status": "ok",
        "input": {"phong": entry.material.to_dict(), "opacity": entry.opacity, "ior": entry.ior},
        "guess": guess,
        "strauss": fitted,
        "held": {},
        "uncertainty": None,
        "correlation": None,
        "solver": not_run(),
        "notes": list(entry.notes)
        + guess_notes
        + ["the material renders black in the conversion scene: nothing to fit, the closed-form guess is returned"],
        # measured here, against this material's own target (its exposure scale)
        "residual": residual_stats(model, target),
    }
