"""Where a fit's solves start: the closed-form guess, a fixed grid, and a scan over n.

The guess (`strauss_fit.fitting.guess`) comes first, then points of `START_GRID`
(colour always from the guess), each kept `START_MARGIN` inside the bounds, where the
transforms of `strauss_fit.fitting.parameters` are flat. When the index of refraction is
fitted, a patterned background seen through the sphere makes the cost oscillate in n, so
the best local minima of a scan over `IOR_SCAN` (`scan_ior`) each get their
own copy of the starts.

Where the colour can be projected out (an opaque material fitted by least squares), the
starts come instead from a global search over smoothness and metalness
(`strauss_fit.fitting.search`), per ``FitOptions.search`` (`start_points_steps`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from ..engine import Steps, run
from ..models.material import FRACTION_NAMES
from .options import FitOptions
from .parameters import Layout
from .problem import Problem, costs
from .search import SMOOTH_EDGE, grid_applies, grid_search_steps

#: Fixed starting points tried besides the guess: values of the fractions s, m, t
#: (`FRACTION_NAMES`, in that order).
START_GRID = ((0.3, 0.1, 0.2), (0.8, 0.1, 0.6), (0.6, 0.9, 0.4), (0.2, 0.6, 0.8), (0.9, 0.5, 0.1), (0.5, 0.3, 0.5))
#: Unit-interval starts are kept this far inside the bounds (the transform is flat there).
START_MARGIN = 0.02
#: Indices of refraction scanned for starting points when n is fitted.
IOR_SCAN = np.linspace(1.0, 3.0, 81)


def starts(
    layout: Layout,
    guess: dict[str, Any],
    count: int,
    ior_candidates: list[float] | None = None,
    exact_first: bool = False,
) -> np.ndarray:
    """The unconstrained starting points (rows): the guess first, then points of
    `START_GRID` (colour always from the guess), ``count`` in all. With
    ``ior_candidates`` (from `scan_ior`), each candidate index gets its own copy of
    those starts. Starts are kept `START_MARGIN` inside the bounds, except the first
    with ``exact_first``: a refit starts from the optimum before it, where the held values
    were taken, and must be able to stay there (a mirror at s = 0.99995 is not one at
    s = 0.98)."""
    rows = []
    for ior in ior_candidates or [guess.get("ior")]:
        base = dict(guess, ior=ior)
        rows.append(layout.join(base))
        for point in START_GRID[: max(count - 1, 0)]:
            rows.append(layout.join(dict(base, **dict(zip(FRACTION_NAMES, point)))))
    thetas = layout.to_unconstrained(np.stack(rows), margin=START_MARGIN)
    if exact_first:
        thetas[0] = layout.to_unconstrained(rows[0])
    return thetas


def scan_ior(problem: Problem, guess: dict[str, Any], keep: int = 3) -> list[float]:
    """The ``keep`` best local minima of the cost over `IOR_SCAN`, the other
    parameters at the guess (`scan_ior_steps`, run directly)."""
    return run(scan_ior_steps(problem, guess, keep))


def scan_ior_steps(problem: Problem, guess: dict[str, Any], keep: int = 3) -> Steps:
    """`scan_ior` as steps. Why scan: a patterned background seen through the sphere
    makes the cost oscillate in n, so a local solver must start near the right basin."""
    layout = problem.layout
    # n only shows through transmitted light: scan it at several transparencies (when t is
    # fitted) and keep, per n, the best of them.
    t_values = (0.25, 0.5, 0.75, 1.0) if "transparency" in layout.names else (guess["transparency"],)
    xs = np.stack([layout.join(dict(guess, ior=float(n), transparency=t)) for n in IOR_SCAN for t in t_values])
    values = np.asarray((yield costs.call(problem, xs))).reshape(IOR_SCAN.size, len(t_values))
    values = np.min(np.where(np.isfinite(values), values, np.inf), axis=1)
    interior = np.r_[True, values[1:] <= values[:-1]] & np.r_[values[:-1] <= values[1:], True]
    minima = sorted(np.flatnonzero(interior), key=lambda i: values[i])[:keep]
    return [float(IOR_SCAN[i]) for i in minima]


def uses_grid(problem: Problem, options: FitOptions) -> bool:
    """Whether ``problem``'s starts come from the grid search: ``options.search`` is
    ``"grid"`` or ``"auto"`` (`SEARCHES`) and the colour
    can be projected out (`strauss_fit.fitting.search.grid_applies`)."""
    return options.search in ("auto", "grid") and grid_applies(problem) is None


def start_points_steps(
    problem: Problem,
    guess: dict[str, Any],
    options: FitOptions,
    ior_candidates: list[float] | None = None,
    exact_first: bool = False,
    say: Callable[[str], None] | None = None,
) -> Steps:
    """The unconstrained starts of a fit on ``problem`` (the coarse one, where there is one)
    and where each came from (``"guess"``, ``"fixed"`` or ``"grid"``): the grid search's
    best distinct minima (`strauss_fit.fitting.search.grid_search_steps`, up to
    ``options.starts``) where `uses_grid`, else `starts`. With ``exact_first``
    the guess, exactly, comes first in either case (a refit from the optimum before it).
    ``say``, if given, is told when the grid is searched."""
    layout = problem.layout
    if not uses_grid(problem, options):
        thetas = starts(layout, guess, options.starts, ior_candidates, exact_first and ior_candidates is None)
        per_copy = ["guess"] + ["fixed"] * (thetas.shape[0] // max(len(ior_candidates or [None]), 1) - 1)
        return thetas, per_copy * len(ior_candidates or [None])
    wanted = options.starts - 1 if exact_first else options.starts
    rows, sources = [], []
    if exact_first:
        rows.append(layout.to_unconstrained(layout.join(guess)))
        sources.append("guess")
    if wanted > 0:
        if say is not None:
            say("searching smoothness and metalness on a grid, the colour in closed form")
        found = yield from grid_search_steps(problem, guess, wanted)
        rows.extend(grid_thetas(layout, found.starts))
        sources.extend(["grid"] * found.starts.shape[0])
    return np.stack(rows), sources


def grid_thetas(layout: Layout, points: np.ndarray) -> np.ndarray:
    """θ of the grid's physical ``points`` (rows): kept `START_MARGIN` inside the
    bounds, where the transforms are flat, except the upper bound of s, kept only
    `SMOOTH_EDGE` below 1 — the grid resolves 1 − s down to
    1e-5 (a highlight a few pixels wide), and a margin of 0.02 would put every start near a
    mirror at s = 0.98. Near 1 the transform's flatness is no obstacle: the image's
    sensitivity to s grows as 1/(1 − s)² there, faster than the slope of the transform
    shrinks."""
    lower = np.full(layout.size, START_MARGIN)
    upper = np.full(layout.size, 1.0 - START_MARGIN)
    if "smoothness" in layout.names:
        upper[layout.offsets[layout.names.index("smoothness")]] = 1.0 - SMOOTH_EDGE
    return layout.to_unconstrained(np.clip(points, lower, upper))
