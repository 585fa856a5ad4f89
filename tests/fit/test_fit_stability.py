"""Fits started at the extremes (issue 8, part 3; see ``tests/models/test_shade_stability.py``):
fits of extreme materials converge without NaN, and the solver started exactly at the
bounds stays finite."""

from __future__ import annotations

import functools
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import strauss_fit as sf
from strauss_fit.fitting.api import fit
from strauss_fit.fitting.problem import to_physical
from strauss_fit.fitting.solvers import solve_starts
from strauss_fit.fitting.starts import START_MARGIN
from support import assert_all_finite, key_and_fill_scene, legacy_options, noisy_target

# --- 4. fits started at the extremes ---------------------------------------------------

# A grey backdrop at depth 2, so that a mirror (s = 1) still shows something; one free set
# for every fit, so that the solver compiles once.
FIT_OPTIONS = legacy_options(free=("color", "smoothness", "metalness"))
FIT_TRUTHS = [(0.0, 0.0), (0.0, 1.0), (1.0, 0.0), (1.0, 1.0), (1 - 1e-6, 0.0), (0.5, 0.5)]


def _fit_scene(s: float, m: float):
    return key_and_fill_scene(
        24,
        source="stability-fit",
        no_material=False,
        material={"color": [0.5, 0.5, 0.5], "smoothness": s, "metalness": m},
        background={"color": [0.4, 0.45, 0.5]},
        depth=2,
    )


def _target(scene, s, m, noise=0.005, seed=0):
    return noisy_target(scene, sf.Material(color=(0.5, 0.7, 0.2), smoothness=s, metalness=m), noise, seed)


@functools.cache
def _fits():
    results = {}
    for s, m in FIT_TRUTHS:
        # the scene's material (the held values and the guess's fallback) at the opposite corner
        scene = _fit_scene(1.0 - round(s), 1.0 - round(m))
        results[(s, m)] = fit(scene, _target(scene, s, m), FIT_OPTIONS)
    return results


@pytest.mark.parametrize("s,m", FIT_TRUTHS)
def test_fits_of_extreme_materials_converge_without_nan(s, m):
    result = _fits()[(s, m)]
    json.dumps(result.to_json(), allow_nan=False)  # raises on NaN or infinity anywhere
    assert result.solver["status"] != "nonfinite"
    assert_all_finite(
        (result.material.color, result.material.smoothness, result.material.metalness, result.fitted_image, result.x),
        "fit result",
    )
    for name in ("smoothness", "metalness"):
        assert 0.0 <= float(getattr(result.material, name)) <= 1.0
    assert result.residual["rms"] < 0.02  # noise 0.005: the fit explains the image


def test_solver_started_exactly_at_the_bounds_stays_finite(x64):
    # Every corner of (s, m) with the colour at its bounds, both exactly at the bounds
    # (where the sin transform's slope vanishes) and START_MARGIN inside them (what fit()
    # generates). Same shapes and settings as fit()'s own starts: no recompilation.
    result = _fits()[(0.5, 0.5)]
    problem = result.problem
    size = problem.layout.size
    problem = problem.pin(np.zeros(size, bool), np.zeros(size))
    corners = [
        problem.layout.join({"color": c, "smoothness": s, "metalness": m})
        for c, s, m in (
            ((0.0, 0.0, 0.0), 0.0, 0.0),
            ((1.0, 1.0, 1.0), 1.0, 1.0),
            ((0.0, 1.0, 0.0), 0.0, 1.0),
            ((1.0, 0.0, 1.0), 1.0, 0.0),
        )
    ]
    cost = jax.jit(jax.vmap(lambda theta: jnp.sum(problem.residual(theta) ** 2)))
    # both ways of running the starts: one after the other (CPU) and vectorised (GPU)
    for margin, batched in ((0.0, False), (START_MARGIN, False), (0.0, True)):
        thetas = jnp.asarray(problem.layout.to_unconstrained(np.stack(corners), margin=margin))
        assert thetas.shape == (FIT_OPTIONS.starts, size)
        values, costs, steps, codes = solve_starts(
            problem, thetas, FIT_OPTIONS.solver, FIT_OPTIONS.rtol, FIT_OPTIONS.atol, FIT_OPTIONS.start_steps, batched
        )
        physical = np.asarray(to_physical(problem.layout, values))
        assert_all_finite((values, costs, physical), f"solver from the bounds (margin {margin})")
        assert np.all((physical >= 0) & (physical <= 1))
        # Levenberg–Marquardt only accepts steps that lower the cost
        assert np.all(np.asarray(costs) <= np.asarray(cost(thetas)) * (1 + 1e-12))
