"""Strauss → Phong: the steps that convert one Strauss material (see
`strauss_fit.convert.converter` for the method, `strauss_fit.convert.phong_fit`
for the least squares).

`phong_steps` is the whole conversion of one material, written as steps
(`strauss_fit.engine`) so that a chunk's kernel calls run together; it reads, in order:

1. the target, the Strauss rendering of the opaque material; a black one gives Phong
   black (`_black_result`);
2. every start solved to convergence and the best kept (`_fit`);
3. what the image constrains, decided at the optimum as a fit decides it, and the Laplace
   deviations of the rest (`_decide`);
4. the result (`_result`).

Each step takes the `Converter` whose shared state
(the scene, the settings, the Strauss problem that renders the targets) it works with.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import TYPE_CHECKING, Any, NamedTuple

import jax.numpy as jnp
import numpy as np

from ..engine import Steps
from ..errors import StraussFitError
from ..fitting.identifiability import numerical_decision, reference_noise_level
from ..fitting.problem import render_at
from ..fitting.starts import START_MARGIN
from ..io.material_tables import Entry
from ..models.material import Material
from ..models.phong import MAX_EXPONENT
from ..stats.laplace import jacobian_kernel
from ._batches import Direction
from ._guesses import phong_guess
from ._problems import StraussProblems
from ._shared import lobe_note, not_run, require_finite, residual_stats, scale_of
from .phong_fit import (
    PHONG_LAYOUT,
    exponent_from_unit,
    laplace_deviations_from,
    material_from_vector,
    solve_phong_starts,
    unit_from_exponent,
)

if TYPE_CHECKING:
    from .converter import Converter

#: A Strauss rendering whose largest value is at most this is black for Strauss → Phong:
#: below the first step of an 8-bit sRGB image (code 1 is 3.0e-4 linear). Strauss's
#: darkest material (C = 0, m = 1, s = 0, what Phong → Strauss gives for kd = ks = 0) is
#: not exactly black (its off-specular term reaches 7e-5); fitting it ran to the step limit.
BLACK_LEVEL = 1e-4


class Item(NamedTuple):
    """A material to convert: its place in the input, its entry, the closed-form guess
    (the vector of `strauss_fit.convert.phong_fit.PHONG_LAYOUT`,
    `strauss_fit.convert._guesses.phong_guess`), the ambient coefficient and the
    Strauss parameter vector of the opaque material (what renders the target)."""

    index: int
    entry: Entry
    guess: np.ndarray
    ka: float
    source: np.ndarray


class _Fit(NamedTuple):
    """The best of the starts: the problem solved, the physical optimum, RSS, the
    Jacobian there, which start, its steps, whether it converged and how many starts ran."""

    problem: Any
    x: np.ndarray
    rss: float
    jacobian: np.ndarray
    best: int
    steps: int
    converged: bool
    starts: int


def direction(conv: Converter, blinn: bool) -> Direction:
    """Strauss → Phong (Blinn–Phong with ``blinn``) for the batch driver
    (`strauss_fit.convert._batches.stream`)."""
    template = dataclasses.replace(conv.phong_template, blinn=blinn) if blinn else conv.phong_template
    return Direction(functools.partial(prepare, conv.problems, blinn), functools.partial(phong_steps, conv, template))


def prepare(problems: StraussProblems, blinn: bool, i: int, entry: Entry) -> Item:
    """The item of entry number ``i`` (raises for a material that cannot be built): the
    guess for the opaque material, its exponent ×4 for Blinn–Phong (whose cos^n(N·H) is
    close to cos^(n/4)(R·V))."""
    material = entry.build()
    opaque = Material(**{**material.to_dict(), "transparency": 0.0})
    guess, ka = phong_guess(opaque)
    if blinn:
        guess[6] = unit_from_exponent(4.0 * float(exponent_from_unit(guess[6])))
    return Item(i, entry, guess, ka, problems.vector(opaque))


def phong_steps(conv: Converter, template: Any, item: Item) -> Steps:
    """The Strauss → Phong conversion of one material, as steps: every start solved
    to convergence (`strauss_fit.convert.phong_fit.solve_starts`), the best
    kept, what the image constrains decided at it as a fit decides it. ``template``: the
    Phong problem (Blinn–Phong or not). Returns the result."""
    # rendered here, batched with the chunk's other renders (see _to_strauss.strauss_steps)
    target = np.asarray((yield render_at.call(conv.problems.full, item.source)))
    require_finite(target, "the Strauss rendering is not finite")
    if float(np.max(target)) <= BLACK_LEVEL:
        return (yield from _black_result(conv, template, item, target))
    fit = yield from _fit(conv, template, item, target)
    held, sd, corr, at_bound = _decide(conv, fit, target)
    status = "successful" if fit.converged else "max_steps_reached"
    notes = []
    if status != "successful":
        notes.append(f"the solver ended with status '{status}'")
    for name, info in held.items():
        notes.append(f"{name} held at {info['value']:.4g}: {info['reason']}")
    bound = [label for label in at_bound if label not in held]
    if bound:
        notes.append(
            "at a bound, where the data push against it (its Laplace deviation is no symmetric interval there): "
            + ", ".join(bound)
        )
    solver = {"status": status, "steps": fit.steps, "best_start": fit.best, "starts": fit.starts, "at_bound": bound}
    return (yield from _result(conv, template, item, fit.x, target, (sd, corr), solver, notes, held))


def _black_result(conv: Converter, template: Any, item: Item, target: np.ndarray) -> Steps:
    """The result of a material that renders black: nothing to fit, Phong black
    (kd = ks = 0; the exponent is the guess's, it shows nowhere)."""
    x = item.guess.copy()
    x[0:6] = 0.0  # Phong black: D = S = 0 (the exponent is the guess's, it shows nowhere)
    note = (
        f"the material renders black in the conversion scene (largest value "
        f"{float(np.max(target)):.2g}, below {BLACK_LEVEL:g}, an 8-bit image's first step): nothing "
        "to fit, Phong black (kd = ks = 0) is returned"
    )
    return (yield from _result(conv, template, item, x, target, (None, None), not_run(), [note], {}))


def _starts(guess: np.ndarray, count: int) -> np.ndarray:
    """The guess, then the exponent ×4 and ÷4, then the highlight halved and the
    exponent ×16 (first ``count`` of them, at least one), unconstrained."""
    step = math.log(4.0) / math.log(MAX_EXPONENT)
    rows = [guess]
    for du, spec_factor in ((step, 1.0), (-step, 1.0), (2 * step, 0.5), (-2 * step, 2.0), (3 * step, 1.0)):
        row = guess.copy()
        row[6] = float(np.clip(row[6] + du, 0.0, 1.0))
        row[3:6] = np.clip(row[3:6] * spec_factor, 0.0, 1.0)
        rows.append(row)
    rows = rows[: max(count, 1)]
    return PHONG_LAYOUT.to_unconstrained(np.stack(rows), margin=START_MARGIN)


def _fit(conv: Converter, template: Any, item: Item, target: np.ndarray) -> Steps:
    """Every start (`_starts`) solved to convergence, the best kept, and the
    Jacobian there. Returns the `_Fit`."""
    settings = conv.settings
    scale = scale_of(target)
    problem = dataclasses.replace(
        template, target=np.asarray(target), residual_scale=np.asarray(scale), ambient_ka=np.asarray(item.ka)
    )
    thetas = _starts(item.guess, settings.starts)
    values, costs_, steps_, ok = (
        np.asarray(v)
        for v in (
            yield solve_phong_starts.call(
                problem, thetas, settings.rtol, settings.atol, settings.max_steps, conv.batched
            )
        )
    )
    finite = np.isfinite(costs_)
    if not finite.any():
        raise StraussFitError("every start of the fit diverged to non-finite values")
    best = int(np.argmin(np.where(finite, costs_, np.inf)))
    x = np.asarray(PHONG_LAYOUT.to_physical_numpy(values[best]))
    require_finite(x, "the fit ended at non-finite parameters")
    rss = float(costs_[best]) * scale**2
    jacobian = np.asarray((yield jacobian_kernel.call(problem, x)))
    return _Fit(problem, x, rss, jacobian, best, int(steps_[best]), bool(ok[best]), int(len(costs_)))


def _decide(conv: Converter, fit: _Fit, target: np.ndarray) -> tuple[dict[str, Any], Any, Any, list[str]]:
    """What the image constrains at the optimum
    (`strauss_fit.fitting.identifiability.numerical_decision` at the target's reference
    noise, entries at a bound protected), the others held at the value the fit reached.
    Returns the held parameters (value and reason), the Laplace deviations and
    correlations of the free ones, and the labels of the entries at a bound."""
    x, jacobian = fit.x, fit.jacobian
    labels = PHONG_LAYOUT.labels()
    at_bound = [label for label, v in zip(labels, x) if v < 1e-6 or v > 1 - 1e-6]
    decision = numerical_decision(
        PHONG_LAYOUT, jacobian, x, reference_noise_level(target), conv.options.threshold, frozenset(at_bound)
    )
    held = {
        name: {"value": float(x[labels.index(name)]), "reason": f"{reason}; held at the value the fit reached"}
        for name, reason in decision.held.items()
    }
    free = np.array([label not in held for label in labels])
    sd, corr = laplace_deviations_from(jacobian, fit.rss, free)
    return held, sd, corr, at_bound


def _result(
    conv: Converter,
    template: Any,
    item: Item,
    x: np.ndarray,
    target: np.ndarray,
    laplace: tuple,
    solver: dict[str, Any],
    notes: list[str],
    held: dict[str, Any],
) -> Steps:
    """The result of a conversion to the Phong vector ``x``: the input, the guess, the
    Phong material, opacity and n carried over, the held parameters, the uncertainties
    (``laplace``: deviations and correlations, None when not fitted), the ``solver``
    record, the notes and the residual (of the model rendered here, one more step)."""
    entry, ka = item.entry, item.ka
    problem = dataclasses.replace(template, target=np.asarray(target), ambient_ka=np.asarray(ka))
    model = np.asarray((yield render_at.call(problem, x)))
    phong = _phong_dict(x, ka, template.blinn)
    uncertainty, correlation = _uncertainty(x, *laplace, held)
    t = float(entry.material.transparency)
    all_notes = list(entry.notes) + notes
    if t > 0:
        all_notes.append(
            f"opacity d = 1 - t = {1 - t:.4g} carried over, not fitted (the fit matches the opaque appearance)"
        )
    all_notes.append(f"ka = (1 - s^3)·max(C) = {ka:.4g} so that Phong's ambient term equals Strauss's")
    lobe = lobe_note(conv.scene.camera.width, phong["exponent"])
    if lobe:
        all_notes.append(lobe)
    return {
        "name": entry.name,
        "source": entry.source,
        "status": "ok",
        "input": {"strauss": entry.material.to_dict()},
        "guess": _phong_dict(item.guess, ka, template.blinn),
        "phong": phong,
        "opacity": float(1.0 - t),
        "ior": float(entry.material.ior),
        "held": held,
        "uncertainty": uncertainty,
        "correlation": correlation,
        "solver": solver,
        "notes": all_notes,
        # measured here, against this material's own target (its exposure scale)
        "residual": residual_stats(model, target),
    }


def _uncertainty(
    x: np.ndarray, sd: np.ndarray | None, corr: np.ndarray | None, held: dict[str, Any]
) -> tuple[dict[str, Any] | None, dict[str, Any] | None]:
    """The deviations ``sd`` of D, S and u as those of D, S and the exponent (None for a
    held entry: a held value has no interval) and the correlations ``corr`` with their
    labels; (None, None) when not fitted."""
    if sd is None:
        return None, None
    n = float(exponent_from_unit(x[6]))
    sd_or_none = [None if label in held else float(v) for label, v in zip(PHONG_LAYOUT.labels(), sd)]
    uncertainty = {
        "diffuse": sd_or_none[0:3],
        "specular": sd_or_none[3:6],
        "exponent": None if sd_or_none[6] is None else float(n * math.log(MAX_EXPONENT) * sd_or_none[6]),
    }
    correlation = {"labels": PHONG_LAYOUT.labels(), "matrix": np.round(corr, 6).tolist()}
    return uncertainty, correlation


def _phong_dict(x: np.ndarray, ka: float, blinn: bool) -> dict[str, Any]:
    """The Phong material of the vector ``x`` (with ``ka``) as a result's dict."""
    material = material_from_vector(jnp.asarray(x), ka, blinn)
    out = {
        name: (float(v) if np.ndim(v) == 0 else [float(c) for c in np.asarray(v)])
        for name, v in (
            ("ka", material.ka),
            ("kd", material.kd),
            ("ks", material.ks),
            ("exponent", material.exponent),
            ("diffuse_color", material.diffuse_color),
            ("specular_color", material.specular_color),
        )
    }
    out["exponent"] = float(min(out["exponent"], MAX_EXPONENT))
    out["blinn"] = bool(blinn)
    return out
