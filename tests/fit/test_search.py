"""The global search of a fit's starts: the colour in closed form over a grid of (s, m)."""

import tomllib

import numpy as np
import pytest

import strauss_fit as sf
from strauss_fit import FitOptions, parse_scene
from strauss_fit.engine import run
from strauss_fit.errors import StraussFitError
from strauss_fit.fitting.api import reference_noise
from strauss_fit.fitting.problem import build_problem, costs, render_at
from strauss_fit.fitting.search import (
    GRID_CHUNK,
    GRID_METALNESS,
    GRID_SMOOTHNESS,
    basin_minima,
    grid_applies,
    grid_choice,
    grid_search,
    projected_costs,
)
from strauss_fit.fitting.solvers import solve
from strauss_fit.fitting.starts import start_points_steps, starts, uses_grid
from strauss_fit.rendering.strauss import plan_render
from support import SCENES, noisy_target

pytestmark = pytest.mark.usefixtures("x64")

FREE = ["color", "smoothness", "metalness"]
ROOT = SCENES.parents[1]


def scene_at(name: str, size: int, background: dict | None = None) -> sf.Scene:
    data = tomllib.loads((SCENES / name).read_text())
    data["camera"].update(width=size, height=size)
    if background is not None:
        data["background"] = background
    data.pop("material", None)
    return parse_scene(data, base_dir=SCENES, source=name)


def room(size: int = 32) -> sf.Scene:
    """The opaque scene of benchmarks/recovery.py: two_lights before a grey backdrop."""
    return scene_at("two_lights.toml", size, background={"color": [0.3, 0.3, 0.3]})


def opaque_problem(scene: sf.Scene, target: sf.Target, names=FREE, loss: str = "linear", noise: float = 1.0):
    material = sf.Material()
    plan = plan_render(scene, material, transparent=False)
    options = FitOptions(edge_pixels="include")
    problem, _, _ = build_problem(scene, target, names, material, plan, options, noise, loss=loss, pad=True)
    return problem


def test_an_opaque_image_is_affine_in_each_colour_channel_and_bilinear_with_metalness():
    """The projection's premise, on a scene whose background the sphere reflects (a studio)
    under a coloured directional, a point and an ambient light: for fixed s, every pixel is
    α + βC + γm + δmC per channel (to 1e-12 of the radiance), at s from 0 to the mirror."""
    data = tomllib.loads((SCENES / "metal_environment.toml").read_text())
    data["camera"].update(width=32, height=32)
    data["light"][0]["color"] = [1.0, 0.8, 0.6]
    data["light"].append({"kind": "ambient", "intensity": 0.1})
    scene = parse_scene(data, base_dir=SCENES, source="studio")
    problem = opaque_problem(scene, noisy_target(scene, sf.Material()))
    assert problem.plan.reflect and float(np.max(np.asarray(problem.prepared.reflected_radiance))) > 0.1
    rng = np.random.default_rng(1)
    for s in (0.0, 0.37, 0.93, 1 - 1e-5, 1.0):

        def image(color, m, s=s):
            return np.asarray(render_at(problem, np.r_[color, s, m]))

        alpha = image(np.zeros(3), 0.0)
        beta = image(np.ones(3), 0.0) - alpha
        gamma = image(np.zeros(3), 1.0) - alpha
        delta = image(np.ones(3), 1.0) - alpha - beta - gamma
        for _ in range(4):
            color, m = rng.uniform(0, 1, 3), rng.uniform(0, 1)
            rendered = image(color, m)
            assert np.abs(rendered).max() > 0.05
            affine = alpha + beta * color + gamma * m + delta * m * color
            np.testing.assert_allclose(affine, rendered, rtol=0, atol=1e-12 * np.abs(rendered).max())


def test_the_closed_form_colour_is_the_brute_force_minimum():
    """Per (s, m), the projected colour minimises the fit's own cost over [0, 1] per channel
    (a scan of 401 values with full renders), the projected cost is that cost, and a
    channel brighter than any colour reaches lands on its bound (C = 1)."""
    scene = room()
    truth = sf.Material(color=(0.7, 0.35, 0.15), smoothness=0.6, metalness=0.4)
    target = noisy_target(scene, truth, noise=0.01, seed=3)
    target = sf.Target(target.pixels * np.array([1.0, 1.0, 6.0]), target.usable, "bright blue", "linear", 0, 0)
    problem = opaque_problem(scene, target, noise=0.01)
    # the grid a fit searches (one compilation with the recovery test's), checked at
    # s = 0.2, 0.6, 0.9895 and m = 0, 0.4, 1
    base = problem.layout.join(truth.to_dict())
    every = (np.asarray(v) for v in projected_costs(problem, base, GRID_SMOOTHNESS, GRID_METALNESS, GRID_CHUNK))
    rows_s, rows_m = [4, 12, 22], [0, 20, 50]
    values, colors = (v[np.ix_(rows_s, rows_m)] for v in every)
    smoothness, metalness = GRID_SMOOTHNESS[rows_s], GRID_METALNESS[rows_m]
    assert smoothness == pytest.approx([0.2, 0.6, 0.9895], abs=1e-4) and metalness == pytest.approx([0, 0.4, 1])
    assert np.any(colors[..., 2] == 1.0)  # the brightened channel is clipped somewhere
    # every (s, m), every channel scanned with the others at their best, and the closed
    # form itself: one call
    scan = np.linspace(0.0, 1.0, 401)
    rows = []
    for i, s in enumerate(smoothness):
        for j, m in enumerate(metalness):
            best = np.r_[colors[i, j], s, m]
            rows.append(best[None])
            for c in range(3):
                along = np.tile(best, (scan.size, 1))
                along[:, c] = scan
                rows.append(along)
    exact_and_scans = np.asarray(costs(problem, np.concatenate(rows))).reshape(len(smoothness), len(metalness), -1)
    for i in range(len(smoothness)):
        for j in range(len(metalness)):
            exact, scans = exact_and_scans[i, j, 0], exact_and_scans[i, j, 1:].reshape(3, scan.size)
            assert values[i, j] == pytest.approx(exact, rel=1e-9)
            assert exact <= scans.min() * (1 + 1e-12)
            np.testing.assert_array_less(np.abs(scan[np.argmin(scans, axis=1)] - colors[i, j]), 0.5 / 400 + 1e-12)


def test_basins_drain_plateaus_and_fill_the_starts_apart():
    values = np.full((6, 7), 5.0)
    values[1, 1] = 1.0  # a basin
    values[4, 5] = 2.0  # another, behind the plateau between them
    values[4, 4] = 2.0  # a tie next to it: the same basin
    assert basin_minima(values) == [1 * 7 + 1, 4 * 7 + 4]
    assert grid_choice(values, 1) == [8]
    # a third start: the lowest point at least three steps from both
    third = grid_choice(values, 3)[2]
    row, column = divmod(third, 7)
    assert max(abs(row - 1), abs(column - 1)) >= 3 and max(abs(row - 4), abs(column - 4)) >= 3
    assert grid_choice(np.array([[3.0]]), 4) == [0]


def test_the_grid_applies_only_where_the_colour_projects_out():
    opaque = room(24)
    target = noisy_target(opaque, sf.Material())
    assert grid_applies(opaque_problem(opaque, target)) is None
    assert "loss" in grid_applies(opaque_problem(opaque, target, loss="huber"))
    assert "held" in grid_applies(opaque_problem(opaque, target, names=["smoothness", "metalness"]))
    glass = sf.Material(transparency=0.5)
    problem, _, _ = build_problem(
        opaque, target, FREE + ["transparency"], glass, plan_render(opaque, glass), FitOptions(edge_pixels="include")
    )
    assert "transmission" in grid_applies(problem)
    # where it does not apply, and with search="starts", the starts are the multi-start's
    guess = sf.Material(color=(0.5, 0.4, 0.3), smoothness=0.2, metalness=0.1).to_dict()
    cases = ((problem, FitOptions(search="grid")), (opaque_problem(opaque, target), FitOptions(search="starts")))
    for problem_, options in cases:
        thetas, sources = run(start_points_steps(problem_, guess, options))
        np.testing.assert_array_equal(thetas, starts(problem_.layout, guess, options.starts))
        assert sources == ["guess"] + ["fixed"] * (options.starts - 1)
    # "auto", the default, is the grid wherever it applies (as measured: options.SEARCHES)
    assert uses_grid(opaque_problem(opaque, target), FitOptions())
    assert not uses_grid(opaque_problem(opaque, target, loss="huber"), FitOptions())
    assert not uses_grid(problem, FitOptions())
    with pytest.raises(StraussFitError, match="search"):
        FitOptions(search="everywhere").validate()


def quiet(message: str) -> None:
    pass


def test_the_readme_example_never_lands_in_its_s0_minimum_with_the_grid():
    """The README's example (strauss-noisy-0000 under two_lights) has a local minimum at
    s = 0 (RSS 2.155 against 1.99886 at s = 0.289): the multi-start's first start, the
    closed-form guess (s = 0 here), falls into it, so that one start alone ends there (the
    default's second start, s = 0.3 of START_GRID, finds the optimum). Every basin the grid
    finds lies away from s = 0, and one grid start alone reaches the optimum."""
    scene = sf.load_scene(SCENES / "two_lights.toml")
    target = sf.load_target(ROOT / "data_synth" / "bundled" / "strauss-noisy-0000.exr")
    scene = sf.match_scene(scene, target)[0]
    material = scene.material
    noise = reference_noise(target, FitOptions())
    plan = plan_render(scene, material, transparent=False)
    problem, _, _ = build_problem(scene, target, FREE, material, plan, FitOptions(), noise, pad=True)
    # the closed-form guess of a fit of this target (initial_guess): a metal, s = 0
    guess = {**material.to_dict(), "color": [0.45, 0.73, 0.49], "smoothness": 0.0, "metalness": 1.0}
    found = grid_search(problem, guess, 4)
    s_entry = problem.layout.offsets[problem.layout.names.index("smoothness")]
    assert np.all(found.starts[: len(basin_minima(found.costs))][:, s_entry] > 0.15)
    assert found.starts[0, s_entry] == pytest.approx(0.3, abs=0.051)

    def final(search):
        solved = solve(problem, guess, FitOptions(starts=1, search=search), quiet)
        return solved.rss, float(problem.layout.split(solved.x)["smoothness"])

    rss_grid, s_grid = final("grid")
    rss_starts, s_starts = final("starts")
    assert s_grid == pytest.approx(0.289, abs=0.003) and rss_grid == pytest.approx(1.99886, rel=1e-5)
    assert s_starts < 0.01 and rss_starts > rss_grid * 1.05  # what one multi-start start does


@pytest.mark.parametrize("starts", [1, None])
def test_the_readme_fit_ends_at_its_optimum_whatever_the_starts(starts):
    """The README's command, as the library runs it (``sf.fit`` with the default search,
    "auto", and the preset's starts or one): the starts come from the grid, and the fit ends
    at s = 0.289, RSS 1.99886, never in the local minimum at s = 0 (RSS 2.155)."""
    scene = sf.load_scene(SCENES / "two_lights.toml")
    target = sf.load_target(ROOT / "data_synth" / "bundled" / "strauss-noisy-0000.exr")
    options = FitOptions() if starts is None else FitOptions(starts=starts)
    result = sf.fit(scene, target, options)
    assert result.settings["search"] == "auto"
    assert {start["source"] for start in result.starts} == {"grid"}
    assert len(result.starts) == (starts or FitOptions().starts)
    assert result.material.smoothness == pytest.approx(0.289, abs=0.003)
    assert result.to_json()["residual"]["sum_of_squares"] == pytest.approx(1.99886, rel=1e-5)


def test_a_recovery_case_is_recovered_from_the_grid():
    """A case of benchmarks/recovery.py (the grey backdrop reflected), noise-free, 32²:
    one start from the grid, whatever the guess, recovers it to 0.005."""
    scene = room()
    truth = sf.Material(color=(0.2, 0.5, 0.9), smoothness=0.7, metalness=0.5)
    target = noisy_target(scene, truth)
    problem = opaque_problem(scene, target, noise=reference_noise(target, FitOptions()))
    far = {**sf.Material().to_dict(), "color": [0.9, 0.9, 0.9], "smoothness": 0.1, "metalness": 0.9}
    solved = solve(problem, far, FitOptions(starts=1, search="grid"), quiet)
    assert solved.starts[0]["source"] == "grid"
    np.testing.assert_allclose(solved.x, np.r_[truth.color, 0.7, 0.5], atol=0.005)
