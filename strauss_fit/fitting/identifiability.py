r"""Deciding which parameters a scene and image can constrain, and saying why not.

Two kinds of reasons, checked in this order:

1. *Structural*: the scene cannot show the parameter at all. The index of refraction needs
   a transparent material, a global model (depth > 1) and a background that varies with
   direction (a constant colour looks the same through any lens). Transparency needs the
   same: over black, t only dims the surface, which the colour's brightness (and
   smoothness) can mimic; over a constant colour, light through the sphere is
   indistinguishable from that colour reflected (a clear glass ball and a mirror look
   alike over a uniform backdrop).
2. *Numerical*: at a probe point (the first guess, kept away from the bounds, or the
   optimum of a fit, exactly), the Fisher information of the image,
   `\mathcal{I} = J^\top J/\sigma^2` with J the Jacobian of the rendered pixels
   with respect to the physical parameters and σ a reference noise level, predicts each
   parameter's standard deviation `\sqrt{((\mathcal{I} + \epsilon)^{-1})_{ii}}`,
   with a ridge ε of 1e-12 of the mean information (in units of each parameter's scale)
   so that an exact degeneracy reads as an enormous deviation, not as none. While the worst
   parameter's predicted deviation exceeds ``threshold`` times its scale (1 for values in
   [0, 1], 0.5 for n, the current value for light intensities), one of those over the
   threshold is held fixed — n first, then t, m, light intensities, s, C — and the analysis
   repeats. The reason names the parameter it trades off with (the largest correlation) or
   says that the image barely changes with it.

`decide_free` applies both at a probe point. A fit decides first at its guess and
then again at each optimum (`strauss_fit.fitting.api.fit`); the rules that turn the
decision at an optimum into held values — a mirror's metalness held at 1
(`held_at_optimum`), n held without a transparency distinguishable from 0
(`hold_ior_without_significant_transparency`), parameters invisible only jointly held
at the fit (`hold_jointly_dead_at_fit`) — and when a refit stands
(`chi2_95`) are here too. These functions are internal API of the fit.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from ..engine import Steps, run
from ..io.targets import Target
from ..models.material import FRACTION_NAMES, Material
from ..numerics import high_percentile
from ..rendering.strauss import plan_render
from ..scene.lights import Lights
from ..scene.loading import Scene
from ..stats import laplace
from .options import DEFAULT_THRESHOLD
from .parameters import Layout, value_of
from .problem import build_problem_steps, costs

if TYPE_CHECKING:
    from .options import FitOptions
    from .solvers import Solved

#: Reference noise: this fraction of the target's 98th-percentile value.
DEFAULT_REFERENCE_NOISE = 0.01


def reference_noise_level(values: np.ndarray) -> float:
    """The reference noise of an image's values: `DEFAULT_REFERENCE_NOISE` times
    their 98th percentile (at least 1e-6; 1 for no values)."""
    level = high_percentile(values, 98) if values.size else 1.0
    return DEFAULT_REFERENCE_NOISE * max(level, 1e-6)


@dataclass
class Decision:
    """Free parameter names (in order) and, for each held parameter, why."""

    free: list[str]
    held: dict[str, str] = field(default_factory=dict)
    predicted_sd: dict[str, float] = field(default_factory=dict)
    #: For a parameter held by the numerical analysis: the parameter it trades off with,
    #: or None when the image does not depend on it (or only barely).
    partner: dict[str, str | None] = field(default_factory=dict)
    #: Held parameters the image does not depend on at all (a zero Jacobian column).
    dead: list[str] = field(default_factory=list)


def structural_reasons(
    candidates: list[str], *, depth: int, background_kind: str, background_black: bool, transparency_may_vary: bool
) -> dict[str, str]:
    """Parameters the scene cannot show at all, with the reason."""
    reasons: dict[str, str] = {}
    if "transparency" in candidates:
        if depth <= 1:
            reasons["transparency"] = (
                "the scene renders the local model only (depth 1), where t merely dims "
                "the surface and trades off with the brightness of the colour"
            )
        elif background_black:
            reasons["transparency"] = (
                "nothing is seen through the sphere (black background): t only dims the "
                "surface and trades off with the brightness of the colour"
            )
        elif background_kind == "color":
            reasons["transparency"] = (
                "the background is a constant colour: light through the sphere looks like "
                "light reflected from it, so t trades off with smoothness and colour"
            )
    if "ior" in candidates:
        if depth <= 1:
            reasons["ior"] = "the scene renders the local model only (depth 1): no refraction is traced"
        elif not transparency_may_vary and "transparency" not in candidates:
            reasons["ior"] = "the material is opaque (transparency 0): no light passes through the sphere"
        elif background_kind == "color":
            reasons["ior"] = (
                "the background is a constant colour, which looks the same through any lens: "
                "refraction has no effect on the image"
            )
        elif "transparency" in reasons:
            reasons["ior"] = "nothing is seen through the sphere, so refraction has no effect on the image"
    return reasons


def deviation_scale(name: str, value: np.ndarray | float) -> np.ndarray:
    """The scale a deviation of parameter ``name`` at ``value`` is judged against: 0.5 for
    n, the value itself (at least 1e-3) for a light intensity or the exposure, 1 for values
    in [0, 1] (also used by `strauss_fit.inference.summaries`)."""
    value = np.asarray(value, dtype=float)
    if name == "ior":
        return np.full(value.shape, 0.5)
    if "intensity" in name or name == "exposure":
        return np.maximum(np.abs(value), 1e-3)
    return np.ones(value.shape)


def _HOLD_ORDER(name: str) -> int:
    # the exposure is held first of all: it is the user's extra unknown, and it trades off
    # with the colour's brightness (and with the lights) whenever the image cannot tell them apart
    order = ("exposure", "ior", "transparency", "metalness", "intensity", "smoothness", "color")
    return next((i for i, key in enumerate(order) if key in name), len(order))


def numerical_decision(
    layout: Layout,
    jacobian: np.ndarray,
    probe: np.ndarray,
    sigma: float,
    threshold: float = DEFAULT_THRESHOLD,
    at_bound: frozenset[str] = frozenset(),
) -> Decision:
    """Hold parameters whose predicted deviation at noise ``sigma`` is too large.

    ``jacobian`` (N, P) is taken at the physical point ``probe`` (P,) for ``layout``.
    ``at_bound``: parameters a fit pinned at a bound because the data pushes against it.
    There the first derivative may vanish (at s = 0 every term in s is of second order)
    while the data still decides the value, one-sidedly, so they are held only if the
    image does not depend on them at all.
    """
    columns = {n: np.arange(o, o + k) for n, k, o in zip(layout.names, layout.sizes, layout.offsets)}
    scales = {n: deviation_scale(n, probe[columns[n]]) for n in layout.names}
    names = list(layout.names)
    held: dict[str, str] = {}
    partners: dict[str, str | None] = {}
    dead: list[str] = []
    predicted: dict[str, float] = {}
    while names:
        index = np.concatenate([columns[n] for n in names])
        owner = np.concatenate([[n] * columns[n].size for n in names])
        j = jacobian[:, index]
        scale = np.concatenate([scales[n] for n in names])
        # In units of each parameter's scale, with a ridge 1e-12 of the mean information:
        # an exact degeneracy (two columns that move the image the same way, as m and C
        # do for a mirror) then shows as a huge deviation along it, where a
        # pseudo-inverse would drop that direction and report a small one.
        fisher = laplace.information(j * scale) / sigma**2
        ridge = 1e-12 * max(float(np.trace(fisher)) / len(scale), 1e-300)
        covariance = laplace.covariance(fisher, ridge=ridge) * np.outer(scale, scale)
        sd = laplace.deviations(covariance)
        insensitive = np.linalg.norm(j, axis=0) == 0
        relative = np.where(insensitive, np.inf, sd / scale)
        predicted = {n: float(sd[owner == n].max()) for n in names}
        if relative.max() <= threshold:
            break
        # Of the parameters the image cannot pin down, hold the one a scene least often
        # needs (n, then t, m, light intensities, s, C): when t and m trade off in an
        # opaque-looking image, holding t at its usual 0 is the better bet than holding m.
        weak = np.flatnonzero((relative > threshold) & (insensitive | ~np.isin(owner, list(at_bound))))
        if weak.size == 0:
            break
        worst = int(min(weak, key=lambda k: (_HOLD_ORDER(str(owner[k])), -relative[k])))
        name = str(owner[worst])
        partners[name] = None
        if insensitive[worst]:
            dead.append(name)
            reason = "the image does not change with it at all"
        else:
            corr = laplace.correlation(covariance, floor=1e-300)[worst]
            others = np.flatnonzero(owner != name)
            partner = others[np.argmax(np.abs(corr[others]))] if others.size else None
            if partner is not None and abs(corr[partner]) >= 0.9:
                partners[name] = str(owner[partner])
                reason = (
                    f"it trades off with {owner[partner]} (correlation {corr[partner]:+.2f}); "
                    f"the image would pin it only to ±{sd[worst]:.2g}"
                )
            else:
                reason = f"the image barely changes with it (it would be pinned only to ±{sd[worst]:.2g})"
        held[name] = reason
        names.remove(name)
    return Decision(free=names, held=held, predicted_sd={n: predicted[n] for n in names}, partner=partners, dead=dead)


def decide_free(*args: Any, **kwargs: Any) -> Decision:
    """`decide_free_steps`, run directly."""
    return run(decide_free_steps(*args, **kwargs))


def decide_free_steps(
    scene: Scene,
    target: Target,
    options: FitOptions,
    material: Material,
    guess: dict[str, Any],
    candidates: list[str],
    fixed: dict[str, Any],
    sigma: float,
    margin: float = 0.15,
    at_bound: frozenset[str] = frozenset(),
    cache: dict | None = None,
) -> Steps:
    """Which of ``candidates`` to fit (see the module docstring), probing at ``guess``
    with unit-interval values kept ``margin`` inside their bounds. At a first guess a
    margin keeps a rough estimate off the bounds, where some sensitivities vanish (m has
    no effect at s = 0); at an optimum the fit calls it with margin 0 on purpose: if the
    fit lands on s = 0, m really is invisible."""
    if options.free is not None:
        return Decision(
            free=[n for n in candidates if n in options.free and n not in fixed],
            held={n: "held by the user (--free)" for n in candidates if n not in options.free and n not in fixed},
        )
    names = [n for n in candidates if n not in fixed]
    background = scene.background
    black = background.kind == "color" and not np.any(np.asarray(background.color))
    transparency_may_vary = "transparency" in names or float(np.asarray(material.transparency)) > 0
    held = structural_reasons(
        names,
        depth=scene.depth,
        background_kind=background.kind,
        background_black=black,
        transparency_may_vary=transparency_may_vary,
    )
    names = [n for n in names if n not in held]
    if not names:
        return Decision(free=[], held=held)
    plan = plan_render(scene, material, transparent="transparency" in names or transparency_may_vary)
    probe_values = dict(guess)
    for key in FRACTION_NAMES:
        probe_values[key] = float(np.clip(probe_values[key], margin, 1 - margin))
    probe_values["color"] = np.clip(np.asarray(probe_values["color"], dtype=float), margin, 1 - margin)
    problem, _, _ = yield from build_problem_steps(scene, target, names, material, plan, options, cache=cache, pad=True)
    probe = problem.layout.join(probe_values)
    jacobian = np.asarray((yield laplace.jacobian_kernel.call(problem, probe)))
    decision = numerical_decision(problem.layout, jacobian, probe, sigma, options.threshold, at_bound)
    decision.held = {**held, **decision.held}
    return decision


# --- deciding again at an optimum -------------------------------------------------------

#: How many times the free set is decided and fitted at most: at the first guess, then at
#: each optimum while the answer is new.
MAX_DECISIONS = 3
#: A fitted smoothness at least this is a mirror (see `held_at_optimum`): above it the
#: diffuse term (1 − s³) and the highlight (exponent 3/(1 − s) ≥ 300) are nearly invisible,
#: and the rule applies only where the analysis found metalness trading off with colour.
MIRROR_SMOOTHNESS = 0.99
#: 95 % points of χ² with 1 to 10 degrees of freedom.
_CHI2_95 = (3.841, 5.991, 7.815, 9.488, 11.070, 12.592, 14.067, 15.507, 16.919, 18.307)


def chi2_95(dof: int) -> float:
    """The 95 % point of χ² with ``dof`` (≥ 1) degrees of freedom (Wilson–Hilferty above 10).

    A refit under a new decision stands unless it costs more than this (times σ²) above
    the best fit before, with as many degrees of freedom as values it newly holds
    (`newly_held`)."""
    dof = max(int(dof), 1)
    if dof <= len(_CHI2_95):
        return _CHI2_95[dof - 1]
    return dof * (1 - 2 / (9 * dof) + 1.6449 * np.sqrt(2 / (9 * dof))) ** 3


def newly_held(before: Layout, decision: Decision) -> int:
    """How many scalar values ``before`` fitted that ``decision`` holds."""
    return sum(size for name, size in zip(before.names, before.sizes) if name not in decision.free)


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
    _mirror_holds_metalness(again, before, fitted)
    for name in again.held:
        if name in before.held:
            reasons[name] = before.held[name]  # held before, at the value it still has
            continue
        if name in again.dead or name not in again.partner:
            continue
        if (
            name == "metalness"
            and again.partner[name] == "color"
            and "color" in again.free
            and float(fitted["smoothness"]) >= MIRROR_SMOOTHNESS
        ):
            metalness = float(fitted["metalness"])
            tint = metalness * (np.asarray(fitted["color"], dtype=float) - 1.0)
            values["metalness"] = 1.0
            values["color"] = np.clip(1.0 + tint, 0.0, 1.0).tolist()
            reasons["metalness"] = (
                f"the fit found a mirror (s = {float(fitted['smoothness']):.4g}), which shows "
                "only the backdrop tinted by "
                "C_s = 1 + m(1 − F)(C − 1): metalness and colour enter only as the tint "
                "m·(C − 1). Held at 1, so that the colour reported is the mirror's tint "
                f"({again.held[name]})"
            )
        else:
            values[name] = fitted[name]
            reasons[name] = f"{again.held[name]}; held at the value the fit reached"
    return values, reasons


def _mirror_holds_metalness(again: Decision, before: Decision, fitted: dict[str, Any]) -> None:
    """The mirror's canonical choice, whichever of the pair the analysis held: when the fit
    pinned metalness on its upper bound, the analysis (which does not hold a pinned parameter that
    the data push against) holds the colour instead; for a mirror the degeneracy is the same
    m·(C − 1), so hold metalness and free the colour, as `held_at_optimum` expects.
    Updates ``again`` in place."""
    if not (
        again.partner.get("color") == "metalness"
        and "metalness" in again.free
        and "color" in before.free
        and "metalness" in before.free
        and float(fitted["smoothness"]) >= MIRROR_SMOOTHNESS
        # pinned at 1: a metal mirror; at 0 the colour is invisible (a plastic mirror),
        # and holding it, as the analysis did, is the answer
        and float(fitted["metalness"]) >= 0.5
    ):
        return
    reason = again.held.pop("color").replace("trades off with metalness", "trades off with color")
    again.partner.pop("color")
    order = [name for name in before.free if name in again.free or name == "color"]
    again.free[:] = [name for name in order if name != "metalness"]
    again.held["metalness"] = reason
    again.partner["metalness"] = "color"


def hold_ior_without_significant_transparency(again: Decision, solved: Solved) -> None:
    """`hold_ior_without_significant_transparency_steps`, run directly."""
    run(hold_ior_without_significant_transparency_steps(again, solved))


def hold_ior_without_significant_transparency_steps(again: Decision, solved: Solved) -> Steps:
    """Hold n at the scene's value — whether the analysis found it free or held it as
    barely visible — when the fitted transparency is within two Laplace deviations of 0.
    Why: the local analysis sees n's effect at the fitted t, however small — and with
    t = 0.003 ± 0.002 noise alone can buy a χ² gain through n (an opaque sphere
    before a checkerboard, fitted n = 1.02 ± 0.002 against a true 1.7) — but that effect
    vanishes at t = 0, which the data do not exclude: n is then not what the image shows.
    Updates ``again`` in place."""
    layout = solved.problem.layout
    numerically_held = "ior" in again.held and "ior" in again.partner
    if not ("ior" in again.free or numerically_held) or not ("ior" in layout.names and "transparency" in layout.names):
        return
    transparency = float(solved.x[layout.offsets[layout.names.index("transparency")]])
    uncertainty, _, _ = yield from laplace.problem_laplace_steps(
        solved.problem, solved.x, solved.rss, None, solved.information
    )
    deviation = float(uncertainty["transparency"])
    if transparency > 2 * deviation:
        return
    if "ior" in again.free:
        again.free.remove("ior")
    # held as the image not showing it (the scene's value), not at the fitted value
    again.partner.pop("ior", None)
    if "ior" in again.dead:
        again.dead.remove("ior")
    again.held["ior"] = (
        f"the fitted transparency, t = {transparency:.2g} ± {deviation:.2g}, is not distinguishable "
        "from 0: the image need not show anything through the sphere, so n would rest on noise"
    )


def hold_jointly_dead_at_fit(*args: Any, **kwargs: Any) -> None:
    """`hold_jointly_dead_at_fit_steps`, run directly."""
    run(hold_jointly_dead_at_fit_steps(*args, **kwargs))


def hold_jointly_dead_at_fit_steps(
    again: Decision,
    before: Decision,
    fitted: dict[str, Any],
    solved: Solved,
    material: Material,
    lights: Lights,
    sigma: float,
    values: dict[str, Any],
    reasons: dict[str, str],
    exposure: float = 1.0,
) -> Steps:
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
        x[offset : offset + size] = np.atleast_1d(np.asarray(value_of(name, material, lights, exposure), dtype=float))
    cost = float(np.asarray((yield costs.call(solved.problem, x[None])))[0])
    if cost * float(solved.problem.residual_scale) ** 2 <= solved.rss + sigma**2:
        return
    for name in dead:
        values[name] = fitted[name]
        others = [n for n in dead if n != name]
        jointly = f" (together with {', '.join(others)})" if others else ""
        reasons[name] = (
            f"{again.held[name]} at the fitted point{jointly}; held at the value the fit reached, "
            "since the scene's value would change the image"
        )


def decision_key(decision: Decision, material: Material, lights: Lights, exposure: float = 1.0) -> tuple:
    """What makes two decisions the same fit: the free names and the held values."""
    values = tuple(
        sorted(
            (
                name,
                tuple(np.round(np.atleast_1d(np.asarray(value_of(name, material, lights, exposure), dtype=float)), 6)),
            )
            for name in decision.held
        )
    )
    return tuple(decision.free), values
