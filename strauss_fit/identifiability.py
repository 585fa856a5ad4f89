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
   :math:`\mathcal{I} = J^\top J/\sigma^2` with J the Jacobian of the rendered pixels
   with respect to the physical parameters and σ a reference noise level, predicts each
   parameter's standard deviation :math:`\sqrt{((\mathcal{I} + \epsilon)^{-1})_{ii}}`,
   with a ridge ε of 1e-12 of the mean information (in units of each parameter's scale)
   so that an exact degeneracy reads as an enormous deviation, not as none. While the worst
   parameter's predicted deviation exceeds ``threshold`` times its scale (1 for values in
   [0, 1], 0.5 for n, the current value for light intensities), one of those over the
   threshold is held fixed — n first, then t, m, light intensities, s, C — and the analysis
   repeats. The reason names the parameter it trades off with (the largest correlation) or
   says that the image barely changes with it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .parameters import Layout

#: A parameter is fitted when its predicted standard deviation at the reference noise is
#: at most this fraction of its scale.
DEFAULT_THRESHOLD = 0.05
#: Reference noise: this fraction of the target's 98th-percentile value.
DEFAULT_REFERENCE_NOISE = 0.01


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


def structural_reasons(candidates: list[str], *, depth: int, background_kind: str, background_black: bool,
                       transparency_may_vary: bool) -> dict[str, str]:
    """Parameters the scene cannot show at all, with the reason."""
    reasons: dict[str, str] = {}
    if "transparency" in candidates:
        if depth <= 1:
            reasons["transparency"] = ("the scene renders the local model only (depth 1), where t merely dims "
                                       "the surface and trades off with the brightness of the colour")
        elif background_black:
            reasons["transparency"] = ("nothing is seen through the sphere (black background): t only dims the "
                                       "surface and trades off with the brightness of the colour")
        elif background_kind == "color":
            reasons["transparency"] = ("the background is a constant colour: light through the sphere looks like "
                                       "light reflected from it, so t trades off with smoothness and colour")
    if "ior" in candidates:
        if depth <= 1:
            reasons["ior"] = "the scene renders the local model only (depth 1): no refraction is traced"
        elif not transparency_may_vary and "transparency" not in candidates:
            reasons["ior"] = "the material is opaque (transparency 0): no light passes through the sphere"
        elif background_kind == "color":
            reasons["ior"] = ("the background is a constant colour, which looks the same through any lens: "
                              "refraction has no effect on the image")
        elif "transparency" in reasons:
            reasons["ior"] = "nothing is seen through the sphere, so refraction has no effect on the image"
    return reasons


def _scale(name: str, value: np.ndarray) -> np.ndarray:
    if name == "ior":
        return np.full(value.shape, 0.5)
    if "intensity" in name:
        return np.maximum(np.abs(value), 1e-3)
    return np.ones(value.shape)


def _HOLD_ORDER(name: str) -> int:
    order = ("ior", "transparency", "metalness", "intensity", "smoothness", "color")
    return next((i for i, key in enumerate(order) if key in name), len(order))


def numerical_decision(layout: Layout, jacobian: np.ndarray, probe: np.ndarray, sigma: float,
                       threshold: float = DEFAULT_THRESHOLD, at_bound: frozenset[str] = frozenset()) -> Decision:
    """Hold parameters whose predicted deviation at noise ``sigma`` is too large.

    ``jacobian`` (N, P) is taken at the physical point ``probe`` (P,) for ``layout``.
    ``at_bound``: parameters a fit pinned at a bound because the data pushes against it.
    There the first derivative may vanish (at s = 0 every term in s is of second order)
    while the data still decides the value, one-sidedly, so they are held only if the
    image does not depend on them at all.
    """
    columns = {n: np.arange(o, o + k) for n, k, o in zip(layout.names, layout.sizes, layout.offsets)}
    scales = {n: _scale(n, probe[columns[n]]) for n in layout.names}
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
        fisher = (j * scale).T @ (j * scale) / sigma**2
        ridge = 1e-12 * max(float(np.trace(fisher)) / len(scale), 1e-300)
        covariance = np.linalg.inv(fisher + ridge * np.eye(len(scale))) * np.outer(scale, scale)
        sd = np.sqrt(np.maximum(np.diag(covariance), 0.0))
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
            corr = covariance[worst] / np.maximum(sd[worst] * sd, 1e-300)
            others = np.flatnonzero(owner != name)
            partner = others[np.argmax(np.abs(corr[others]))] if others.size else None
            if partner is not None and abs(corr[partner]) >= 0.9:
                partners[name] = str(owner[partner])
                reason = (f"it trades off with {owner[partner]} (correlation {corr[partner]:+.2f}); "
                          f"the image would pin it only to ±{sd[worst]:.2g}")
            else:
                reason = f"the image barely changes with it (it would be pinned only to ±{sd[worst]:.2g})"
        held[name] = reason
        names.remove(name)
    return Decision(free=names, held=held, predicted_sd={n: predicted[n] for n in names}, partner=partners,
                    dead=dead)
