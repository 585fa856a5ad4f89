r"""Which values look the same? Perceptual equivalence ranges of a fit.

The statistical ± of a fit (`strauss_fit.stats.laplace`) answers "how well do the
data pin the best Strauss approximation"; it shrinks with every extra pixel and says
nothing about what a person sees. The *equivalence range* of a parameter answers the
artist's question instead: how far can its slider move, the other parameters re-adjusted,
before anyone can see a difference from the best fit?

For a free parameter p (each channel of the colour separately) with best value p̂, and
the best fit's image `\hat I` at the pixels the fit used,

```text
D(v) = \min_{\theta_{-p}} \overline{\Delta E_{2000}}\big(I(p = v, \theta_{-p}), \hat I\big),
```

the mean CIEDE2000 difference after re-fitting the others with p held at v; the range is
the set of v around p̂ where `D(v) \le \Delta E^*` (default 1, one just-noticeable
difference). Each side is found by doubling a step away from p̂ until D exceeds
`\Delta E^*` (or the bound is reached: then the range ends at the bound), then by
bisection. The inner minimisation is a least-squares fit to `\hat I` in the
perceptual (cube-root, see `strauss_fit.fitting.problem.loss_residual`) space, a close
and smooth stand-in for the CIEDE2000 it is judged by, warm-started at the previous point.

It says nothing about the target: a parameter with a wide range is one the image of this
scene cannot show, however precisely the data pin it statistically.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any

import numpy as np

from ..color import delta_e_2000
from ..engine import Steps, run
from ..errors import StraussFitError
from ..precision import uses_float64

#: The default threshold: one just-noticeable difference in mean CIEDE2000.
DEFAULT_DELTA_E = 1.0
#: Bisection steps per side (the range's ends are then known to 2⁻¹⁰ of the last step).
BISECTIONS = 10
#: Upper ends for parameters without one: the index of refraction, intensities, exposure
#: (as multiples of the fitted value).
IOR_MAX = 3.0
SCALE_MAX = 10.0


def _real(problem: Any, per_pixel: Any) -> np.ndarray:
    """``per_pixel`` without a padded problem's padding (`strauss_fit.fitting.problem.Problem.real`)."""
    real = getattr(problem, "real", None)
    return real(per_pixel) if real is not None else np.asarray(per_pixel)


def _perceptual_copy(problem: Any, image: np.ndarray) -> Any:
    from .problem import PERCEPTUAL_OFFSET

    level = max(float(np.percentile(_real(problem, image), 98)), 1e-12)
    offset = PERCEPTUAL_OFFSET * level
    return dataclasses.replace(
        problem,
        target=np.asarray(image),
        loss="perceptual",
        loss_offset=np.asarray(offset),
        loss_norm=np.asarray((level + offset) ** (-2.0 / 3.0) / 3.0),
        weights=None,
    )


def range_end_steps(
    distance: Callable[[float, Any], Steps],
    centre: float,
    bound: float,
    direction: float,
    step: float,
    delta_e: float,
    bisections: int,
    warm: Any,
) -> Steps:
    """Steps giving one end of an equivalence range: from ``centre`` towards ``bound``
    (``direction`` −1: downwards, +1: upwards), the step doubled from ``step`` until the
    distance exceeds ``delta_e`` (or ``bound`` is reached: the end is then the bound), then
    ``bisections`` halvings of the last step. The end is the farthest value found within
    ``delta_e``.

    ``distance(v, warm)`` gives, as steps, the distance at ``v`` and the inner fit's solution
    there, which warm-starts the next evaluation (``warm``: the first one's). The one search
    of both equivalence ranges, a single image's (here) and a capture's
    (`strauss_fit.fitting.capture_equivalence`, whose distance runs no `Call`)."""
    inside, outside = centre, None
    while True:
        v = float(max(centre - step, bound) if direction < 0 else min(centre + step, bound))
        d, solution = yield from distance(v, warm)
        if d > delta_e:
            outside = v
            break
        inside, warm = v, solution
        if v == bound:
            break
        step *= 2.0
    if outside is not None:
        for _ in range(bisections):
            middle = 0.5 * (inside + outside)
            d, solution = yield from distance(middle, warm)
            if d > delta_e:
                outside = middle
            else:
                inside, warm = middle, solution
    return inside


@uses_float64
def equivalence_ranges(problem: Any, x: np.ndarray, **settings: Any) -> dict[str, Any]:
    """The perceptual equivalence range of every free parameter of a fit
    (``problem``, ``x`` as in `strauss_fit.FitResult.problem` and ``.x``): a map
    from parameter name to ``[low, high]`` (colour: three pairs, R, G, B). See the module
    docstring; ``settings`` as for `equivalence_ranges_steps`."""
    return run(equivalence_ranges_steps(problem, x, **settings))


def equivalence_ranges_steps(
    problem: Any,
    x: np.ndarray,
    *,
    delta_e: float = DEFAULT_DELTA_E,
    rtol: float = 1e-6,
    atol: float = 1e-8,
    max_steps: int = 100,
) -> Steps:
    """`equivalence_ranges` as steps: ``delta_e`` the threshold (mean CIEDE2000), the
    inner fits' tolerances and step limit."""
    from .problem import physical_values, render_at
    from .solvers import solve_starts

    if not np.isfinite(delta_e) or delta_e <= 0:
        raise StraussFitError(f"the equivalence threshold must be a positive CIEDE2000, got {delta_e}")
    layout = problem.layout
    x = np.asarray(x, dtype=np.float64)
    rendered = np.asarray((yield render_at.call(problem, x)))
    base = _perceptual_copy(problem, rendered)
    best = _real(problem, rendered)
    pinned0 = np.asarray(problem.pinned)
    values0 = np.where(pinned0, np.asarray(problem.pinned_values), x)
    lower, upper = layout.lower_bounds(), layout.upper_bounds()
    labels = layout.labels()

    def distance(k: int, v: float, warm: np.ndarray) -> Steps:
        mask = pinned0.copy()
        mask[k] = True
        values = values0.copy()
        values[k] = v
        trial = dataclasses.replace(base, pinned=mask, pinned_values=values)
        if mask.all():
            theta = warm
        else:
            thetas, _, _, _ = yield solve_starts.call(trial, warm[None], "lm", rtol, atol, max_steps, False)
            theta = np.asarray(thetas[0])
        image = _real(problem, (yield render_at.call(problem, physical_values(trial, theta))))
        return float(np.mean(delta_e_2000(image, best))), theta

    start_theta = layout.to_unconstrained(values0)
    ranges: dict[str, list[float]] = {}
    for k, label in enumerate(labels):
        name = label[: -len("_r")] if label.startswith("color_") else label
        top = upper[k]
        if not np.isfinite(top):
            top = IOR_MAX if name == "ior" else max(SCALE_MAX * values0[k], values0[k] + 1.0)
        centre = values0[k]
        step = 0.02 * max(abs(centre), 1.0) if name in ("ior", "exposure") or "intensity" in name else 0.02
        ends = []
        for direction, bound in ((-1.0, lower[k]), (1.0, top)):
            end = yield from range_end_steps(
                functools.partial(distance, k), centre, bound, direction, step, delta_e, BISECTIONS, start_theta
            )
            ends.append(end)
        ranges[label] = [float(min(ends)), float(max(ends))]
    out: dict[str, Any] = {}
    for name, size, offset in zip(layout.names, layout.sizes, layout.offsets):
        pairs = [ranges[labels[offset + i]] for i in range(size)]
        out[name] = pairs if size > 1 else pairs[0]
    return out
