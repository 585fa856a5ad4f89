r"""A global search over smoothness and metalness, the colour solved in closed form.

Variable projection. Where the renderer traces no transmission (an opaque material, t
held at 0, or ``depth = 1``), the radiance of every pixel is *affine in each channel of
the colour*: the diffuse term is `d\,C_c C_{L,c}`, Strauss's specular tint
`1 + m(1 - F)(C_c - 1)` is affine in `C_c`, the ambient term is
`a\,r_d\,C_c`, and the background reflected by the convex sphere is seen once,
weighted by `r_j` and that same tint. So, for fixed s and m,

```text
I_c(p) = A_c(p; s, m)\,C_c + B_c(p; s, m),
```

with B the render at C = 0 and A the render at C = 1 minus B (two renders; checked to
1e-12 on scenes that reflect a studio and a checkerboard by ``tests/fit/test_search.py``).
The best `C_c \in [0, 1]` of a least-squares cost is then a one-dimensional convex
problem per channel, solved exactly: `C_c^* = \mathrm{clip}(\sum_p A (T - B) /
\sum_p A^2, 0, 1)` (`projected_costs`). Only (s, m) remain to search, and a grid
of them (`GRID_SMOOTHNESS` × `GRID_METALNESS`, dense towards s = 1 where
the highlight narrows) costs a few hundred renders of the coarse subsample in one
compiled call — the global search the issue asks for (the linear part convex, as in Yu,
Seo & Lee's branch-and-bound estimation of BRDFs). The best distinct local minima of the
grid become the starts of the usual Levenberg–Marquardt solves
(`strauss_fit.fitting.solvers`), which polish all parameters together.

Where the projection does not hold the grid is not used and the fit keeps its multi-start
(`strauss_fit.fitting.starts`): transmission traced (t free or held above 0, and then n
too: the transmitted light is tinted by C once per passage and the inner reflections by
`C_s`, a polynomial in C), a light intensity or the exposure free (the image is then
*bilinear* in them and C, not jointly linear), the colour held, or a loss other than plain
least squares (the robust losses reweight residuals nonlinearly). `grid_applies`
says which.

``FitOptions.search = "auto"`` (the default) uses the grid wherever it applies, as
measured against the multi-start: see `SEARCHES`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..engine import Kernel, Steps, run
from ..models.material import OPAQUE_NAMES
from ..precision import uses_float64
from ..rendering.strauss import shade_prepared
from .parameters import Layout, material_with
from .problem import Problem, scaled

#: The nonlinear parameters the grid spans (those of them that are free): an opaque
#: material's parameters but its colour, which is solved in closed form.
GRID_NAMES = tuple(name for name in OPAQUE_NAMES if name != "color")
#: Smoothness values of the grid: every 0.05 up to 0.9, then geometrically towards 1 (the
#: highlight's exponent is 3/(1 − s), so equal steps of log(1 − s) change its width by equal
#: factors), and the mirror, s = 1. Each costs four renders of the coarse subsample.
GRID_SMOOTHNESS = np.r_[np.linspace(0.0, 0.9, 19), 1 - np.geomspace(0.07, 1e-5, 15), 1.0]
#: Metalness values of the grid: nearly free (the cost is a quadratic form in m and C whose
#: coefficients the four renders of each s give), hence fine.
GRID_METALNESS = np.linspace(0.0, 1.0, 51)
#: Smoothness values rendered together inside the compiled call (a bound on its memory:
#: each holds four (N, 3) renders). 5 divides the grid's 35 values (no remainder, one loop
#: body) and was the fastest of 1-8 on a 256² sphere's coarse subsample (8 500 pixels:
#: 15.0 ms against 17.6 ms with 8, 28.6 with 1; 2026-12-04).
GRID_CHUNK = 5
#: A start from the grid is kept this far inside the bounds of s near 1 (the grid resolves
#: 1 − s down to 1e-5, and the usual margin of 0.02 would erase that), and
#: `START_MARGIN` elsewhere.
SMOOTH_EDGE = 1e-7


def grid_applies(problem: Problem) -> str | None:
    """None when the colour can be projected out of ``problem`` (see the module), else why
    not (a phrase)."""
    layout = problem.layout
    if "color" not in layout.names:
        return "the colour is held"
    if problem.plan.transmit:
        return "transmission is traced (the image is not affine in the colour)"
    if problem.loss != "linear":
        return f"the {problem.loss} loss is not least squares"
    others = [name for name in layout.names if name != "color" and name not in GRID_NAMES]
    if others:
        return f"{', '.join(others)} free"
    return None


def grid_axes(problem: Problem) -> tuple[np.ndarray, np.ndarray]:
    """The grid's smoothness and metalness values: `GRID_SMOOTHNESS` and
    `GRID_METALNESS` where free, else the held value alone (the problem's material's)."""
    names = problem.layout.names
    held = problem.material
    smoothness = GRID_SMOOTHNESS if "smoothness" in names else np.atleast_1d(np.asarray(held.smoothness, float))
    metalness = GRID_METALNESS if "metalness" in names else np.atleast_1d(np.asarray(held.metalness, float))
    return smoothness, metalness


def _entry(layout: Layout, name: str) -> int | None:
    return layout.offsets[layout.names.index(name)] if name in layout.names else None


def _projected_costs(problem: Problem, base: Array, smoothness: Array, metalness: Array, chunk: int):
    r"""The grid's costs (S, M) — normalised as the fit's, with the colour at its best in
    [0, 1] for each (s, m) — and those colours (S, M, 3).

    Per s, four renders at m ∈ {0, 1} and C ∈ {0, 1} (every channel) give the image's
    coefficients `I_c = \alpha_c + \beta_c C_c + \gamma_c m + \delta_c m C_c` (bilinear in
    m and C, see the module); with a held m, two renders at it and γ = δ = 0. For each m,
    `A = \beta + \delta m` and `D = T - \alpha - \gamma m`, and the cost per
    channel `\sum_p w (A C - D)^2` is a quadratic in C whose coefficients are
    quadratics in m, from eight weighted sums over the pixels; the best C is
    `\mathrm{clip}(\sum w A D / \sum w A^2, 0, 1)`. ``base`` (P,) holds the other
    values of the layout (its colour is kept where the image shows none of it)."""
    layout = problem.layout
    colour = slice(_entry(layout, "color"), _entry(layout, "color") + 3)
    s_entry, m_entry = _entry(layout, "smoothness"), _entry(layout, "metalness")
    target = problem.target
    weight = (jnp.ones(target.shape[0], target.dtype) if problem.valid is None else problem.valid)[:, None]

    # The corners (m, C) rendered per s, vmapped over the corners only, s shared: what
    # depends on s alone (the highlight's fall-off, r_d, r_j: most of a render) is computed
    # once per s, not per corner — `Problem.render_physical` takes s inside its vector,
    # which would batch it with the corners, so the render is spelt out here from the same
    # public pieces (the lights and the exposure are held: `grid_applies`).
    corners = ((0.0, 0.0), (0.0, 1.0)) + (((1.0, 0.0), (1.0, 1.0)) if m_entry is not None else ())
    held = layout.split(base)
    prepared = scaled(problem.prepared, problem.lights)

    def corner(s: Array, m: Array, c: Array) -> Array:
        values = dict(held, color=jnp.broadcast_to(c, (3,)))
        if s_entry is not None:
            values["smoothness"] = s
        if m_entry is not None:
            values["metalness"] = m
        radiance = shade_prepared(material_with(problem.material, values), prepared, problem.scene, problem.plan)
        return radiance if problem.exposure is None else radiance * problem.exposure

    def moments(s: Array) -> Array:
        m_corner, c_corner = (jnp.asarray(v, dtype=base.dtype) for v in zip(*corners))
        rendered = jax.vmap(corner, in_axes=(None, 0, 0))(s, m_corner, c_corner)
        alpha = rendered[0]
        beta = rendered[1] - alpha
        if m_entry is None:
            gamma = delta = jnp.zeros_like(alpha)
        else:
            gamma = rendered[2] - alpha
            delta = rendered[3] - alpha - beta - gamma
        rest = target - alpha

        def total(u: Array, v: Array) -> Array:
            return jnp.sum(weight * u * v, axis=0)  # (3,)

        return jnp.stack(
            [
                total(beta, beta),
                total(beta, delta),
                total(delta, delta),
                total(beta, rest),
                total(delta, rest) - total(beta, gamma),
                total(delta, gamma),
                total(rest, rest),
                total(gamma, rest),
                total(gamma, gamma),
            ]
        )  # (9, 3)

    sums = jax.lax.map(moments, smoothness, batch_size=chunk)[:, None]  # (S, 1, 9, 3)
    m = metalness[None, :, None]  # (1, M, 1)
    aa = sums[..., 0, :] + 2 * m * sums[..., 1, :] + m * m * sums[..., 2, :]  # Σ w A²
    ad = sums[..., 3, :] + m * sums[..., 4, :] - m * m * sums[..., 5, :]  # Σ w A D
    dd = sums[..., 6, :] - 2 * m * sums[..., 7, :] + m * m * sums[..., 8, :]  # Σ w D²
    # a channel the image does not show (no diffuse light, no tint: A = 0) keeps the base
    # colour; the guarded quotient keeps NaN out of both branches
    shown = aa > 1e-300 * jnp.maximum(dd, 1.0)
    best = jnp.where(shown, jnp.clip(ad / jnp.where(shown, aa, 1.0), 0.0, 1.0), base[colour])
    # the expanded square loses digits against Σ w D² (an exact fit: 0 from terms of order
    # Σ T²), so a tiny negative is rounding: the ranking of the grid does not depend on it
    cost = jnp.maximum(jnp.sum(dd - 2 * best * ad + best * best * aa, axis=-1), 0.0)
    return cost / problem.residual_scale**2, best


#: The projected cost and colour over a grid of (s, m) (`_projected_costs`); a
#: `Kernel`, so that a batch of fits evaluates its grids together.
projected_costs = Kernel(_projected_costs, "projected_costs")


@dataclass
class GridSearch:
    """What `grid_search_steps` found: the chosen starts (physical rows, best first),
    the grid's values of s and m, its costs (S, M) and colours (S, M, 3)."""

    starts: np.ndarray
    smoothness: np.ndarray
    metalness: np.ndarray
    costs: np.ndarray
    colors: np.ndarray


@uses_float64
def grid_search(problem: Problem, guess: dict[str, Any], count: int) -> GridSearch:
    """`grid_search_steps`, run directly."""
    return run(grid_search_steps(problem, guess, count))


def grid_search_steps(problem: Problem, guess: dict[str, Any], count: int) -> Steps:
    """The projected cost over the grid (one compiled call) and ``count`` starts
    (`grid_choice`). ``problem``
    must satisfy `grid_applies`; ``guess`` gives the colour where the image shows none."""
    layout = problem.layout
    smoothness, metalness = grid_axes(problem)
    base = layout.join(guess)
    values, colors = (
        np.asarray(v) for v in (yield projected_costs.call(problem, base, smoothness, metalness, GRID_CHUNK))
    )
    values = np.where(np.isfinite(values), values, np.inf)
    rows = []
    for flat in grid_choice(values, count):
        i, j = np.unravel_index(flat, values.shape)
        point = dict(guess, color=colors[i, j], smoothness=float(smoothness[i]), metalness=float(metalness[j]))
        rows.append(layout.join(point))
    return GridSearch(np.stack(rows), smoothness, metalness, values, colors)


#: A grid point that fills a start left over by the basins is at least this many grid
#: steps (in s or in m) from every start chosen before it.
FILL_SEPARATION = 3


def grid_choice(values: np.ndarray, count: int) -> list[int]:
    """Flat indices of ``count`` starts on the grid ``values`` (fewer only on a grid of fewer
    points): the lowest points of the best distinct basins (`basin_minima`), then,
    where the grid has fewer basins than that, its lowest points at least
    `FILL_SEPARATION` steps from every start before. Why always ``count``: the starts
    are solved in one compiled call whose shape is their number, so that the fits of a batch
    (`strauss_fit.fit_many`) share it; and a second start away from the first still
    guards against a basin the grid is too coarse to resolve."""
    count = max(1, min(int(count), values.size))
    chosen = basin_minima(values)[:count]
    where = np.indices(values.shape).reshape(values.ndim, -1)
    for separation in (FILL_SEPARATION, 1):  # the second pass only on a grid too small for the first
        for flat in np.argsort(values, axis=None, kind="stable"):
            if len(chosen) >= count:
                return chosen
            apart = [np.max(np.abs(where[:, flat] - where[:, k])) >= separation for k in chosen]
            if all(apart):
                chosen.append(int(flat))
    return chosen


def basin_minima(values: np.ndarray) -> list[int]:
    """Flat indices of the lowest point of each basin of the grid ``values``, best first.

    A basin is the set of points whose steepest descent on the grid (each point's lowest
    neighbour, diagonals included, or itself; ties to the lower index, so that a plateau
    drains to one point) ends at the same point: two points of one valley are one basin,
    however long and flat the valley, while minima separated by any ridge are distinct."""
    shape = values.shape
    size = values.size
    order = np.empty(size, dtype=np.int64)
    order[np.argsort(values, axis=None, kind="stable")] = np.arange(size)  # a strict total order
    rank = order.reshape(shape)
    padded = np.pad(rank, 1, constant_values=size)
    best_rank = rank.copy()
    for shift in np.ndindex(*(3,) * values.ndim):
        window = padded[tuple(slice(k, k + n) for k, n in zip(shift, shape))]
        best_rank = np.minimum(best_rank, window)
    by_rank = np.argsort(order)  # flat index of each rank
    successor = by_rank[best_rank.ravel()]
    while True:  # pointer jumping: every point to the end of its descent
        following = successor[successor]
        if np.array_equal(following, successor):
            break
        successor = following
    sinks = np.unique(successor)
    return [int(i) for i in sinks[np.argsort(order[sinks], kind="stable")]]
