"""The compiled work of one fit (issue 27): the noise sandwich's terms from the model's first
and second derivatives equal the generic derivatives of the whole residual, the sandwich
and the Laplace information come from one kernel, and a second fit of a target traces and
compiles nothing."""

from __future__ import annotations

import tomllib

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import strauss_fit as sf
import support
from strauss_fit.fitting.parameters import light_parameter_names
from strauss_fit.fitting.problem import build_problem
from strauss_fit.rendering.strauss import plan_render
from strauss_fit.stats import laplace
from support import SCENES

pytestmark = pytest.mark.usefixtures("x64")

FREE = ["color", "smoothness", "metalness"]
TRUTH = dict(color=(0.6, 0.4, 0.3), smoothness=0.6, metalness=0.3)
SIGMA = 0.004


@pytest.fixture(scope="module")
def scene_and_target():
    scene = support.key_and_fill_scene(24, material=TRUTH)
    image, _ = sf.render(scene, sf.Material(**TRUTH))
    image = np.asarray(image) + np.random.default_rng(5).normal(0.0, SIGMA, np.shape(image))
    return scene, sf.Target(image, np.ones(image.shape[:2], bool), "kernels.exr", "linear", 0, 0)


def _problem(scene, target, loss: str, pad: bool):
    material = sf.Material(**TRUTH)
    plan = plan_render(scene, material, transparent=False)
    sigma = np.full(target.pixels.shape, SIGMA) * np.linspace(0.8, 1.2, target.pixels.size).reshape(target.pixels.shape)
    problem = build_problem(
        scene, target, FREE, material, plan, sf.FitOptions(), SIGMA, loss=loss, noise_sigma=sigma, pad=pad
    )[0]
    # metalness pinned at its value: a pinned entry's rows and columns must come out the same too
    return problem.pin(np.array([False, False, False, False, True]), np.array([0.0, 0.0, 0.0, 0.0, 0.35]))


def _generic_terms(problem, x):
    """J, H, D, g and ∂J/∂y by differentiating the whole residual (what the structured
    kernel replaced): the definition the fast path must reproduce."""
    residual = problem.objective_residual

    def with_target(target):
        return type(problem).objective_residual(eqx.tree_at(lambda p: p.target, problem, target), x)

    def jacobian_of_target(target):
        return jax.jacfwd(type(problem).objective_residual, argnums=1)(
            eqx.tree_at(lambda p: p.target, problem, target), x
        )

    ones = jnp.ones_like(problem.target)
    values, slope = jax.jvp(with_target, (problem.target,), (ones,))
    _, jacobian_slope = jax.jvp(jacobian_of_target, (problem.target,), (ones,))
    hessian = jax.hessian(lambda z: 0.5 * jnp.sum(residual(z) ** 2))(x)
    return jax.jacfwd(residual)(x), hessian, slope, values, jacobian_slope


@pytest.mark.parametrize("loss", ["linear", "huber", "cauchy", "perceptual"])
@pytest.mark.parametrize("pad", [False, True])
def test_the_sandwich_terms_equal_the_whole_residuals_derivatives(scene_and_target, loss, pad):
    """J, H (with the misfit's curvature), D, g and ∂J/∂y from the render's derivatives and
    each value's own loss derivatives equal jax.jacfwd / jax.hessian of the whole residual,
    away from the optimum (where g∇²g matters) and with an entry pinned."""
    scene, target = scene_and_target
    problem = _problem(scene, target, loss, pad)
    x = jnp.asarray([0.75, 0.3, 0.2, 0.45, 0.35])
    fast = jax.jit(laplace._objective_terms)(problem, x)
    generic = jax.jit(_generic_terms)(problem, x)
    for name, a, b in zip(("J", "H", "D", "g", "dJ/dy"), fast, generic):
        a, b = np.asarray(a), np.asarray(b)
        assert a.shape == b.shape, name
        np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-12 * max(float(np.max(np.abs(b))), 1e-300), err_msg=name)
    hessian, gauss_newton = np.asarray(generic[1]), np.asarray(generic[0]).T @ np.asarray(generic[0])
    # the misfit's curvature is really there, so the second derivatives were tested
    assert np.max(np.abs(hessian - gauss_newton)) > 1e-3 * np.max(np.abs(hessian))


def test_the_sandwich_parts_kernel_gives_the_sandwich_and_the_laplace_information(scene_and_target):
    """One kernel call gives the sandwich (as computed from the full terms on the host) and
    JᵀJ of the physical residuals (as the Jacobian kernel's), the padding weighted 0."""
    scene, target = scene_and_target
    problem = _problem(scene, target, "linear", True)
    x = np.array([0.62, 0.41, 0.29, 0.58, 0.35])
    noise = np.full(problem.value_count(), SIGMA) * np.linspace(0.9, 1.1, problem.value_count())
    parts = laplace.sandwich_parts_kernel(problem, x, laplace.padded_noise(problem, noise))
    j, h, slope, cross = laplace.objective_terms(problem, x)
    scale = float(np.max(np.abs(slope)))
    padded = laplace.padded_noise(problem, noise)
    meat = (cross / scale**2).T @ ((cross / scale**2) * padded[:, None] ** 2)
    np.testing.assert_allclose(np.asarray(parts["meat"]), meat, rtol=1e-10)
    np.testing.assert_allclose(np.asarray(parts["bread"]), h / scale**2, rtol=1e-10)
    physical = np.asarray(laplace.jacobian(problem, jnp.asarray(x)))
    np.testing.assert_allclose(np.asarray(parts["information"]), physical.T @ physical, rtol=1e-10)
    sd, _, cov, extra = laplace.sandwich_from_parts(problem, parts)
    assert cov[4, 4] == 0 and sd["metalness"] == 0  # pinned: no deviation
    assert len(extra["curvature_eigenvalues"]) == 4


def test_a_second_fit_of_a_target_traces_and_compiles_nothing(scene_and_target):
    """Warm, a fit is only the compiled calls: no jaxpr traced, no program compiled."""
    scene, target = scene_and_target
    options = sf.FitOptions(free=tuple(FREE), starts=2)
    first = sf.fit(scene, target, options)
    events: list[str] = []

    def on_duration(event: str, duration: float, **_: object) -> None:
        if event.startswith("/jax/core/compile/"):
            events.append(event)

    jax.monitoring.register_event_duration_secs_listener(on_duration)
    try:
        again = sf.fit(scene, target, options)
    finally:
        jax.monitoring.unregister_event_duration_listener(on_duration)
    assert events == []
    assert again.uncertainty == first.uncertainty and again.residual["verdict"] == first.residual["verdict"]


@pytest.mark.parametrize(
    "scene_file, extra, transparent",
    [
        ("metal_environment.toml", "exposure", False),  # a reflected studio, depth 2
        ("checker.toml", None, False),
        ("key_and_fill.toml", "light", False),
        ("glass_checkerboard.toml", None, True),
    ],
)
def test_the_second_derivatives_skipped_are_zero(scene_file, extra, transparent):
    """The pairs `zero_pairs` leaves out of the sandwich's Hessian are 0 at every pixel (the
    image affine in each channel of C and in m, with a reflected background, a free exposure
    or a free light intensity), and the Hessian with them left out equals jax.hessian; with
    transmission none is left out."""
    data = tomllib.loads((SCENES / scene_file).read_text())
    data["camera"].update(width=20, height=20)
    scene = sf.parse_scene(data, source=scene_file, base_dir=SCENES)
    material = sf.Material(
        color=(0.6, 0.4, 0.3), smoothness=0.55, metalness=0.35, transparency=0.5 if transparent else 0.0
    )
    image, _ = sf.render(scene, material)
    target = sf.Target(np.asarray(image), np.ones(np.shape(image)[:2], bool), "pairs.exr", "linear", 0, 0)
    names = ["color", "smoothness", "metalness"] + (["transparency", "ior"] if transparent else [])
    if extra == "exposure":
        names.append("exposure")
    elif extra == "light":
        names.append(light_parameter_names(scene.lights)[0])
    plan = plan_render(scene, material, transparent=transparent)
    problem = build_problem(scene, target, names, material, plan, sf.FitOptions(), 0.01)[0]
    skipped = laplace.zero_pairs(problem)
    if transparent:
        assert plan.transmit and skipped == set()
        return
    assert {(0, 0), (0, 2), (1, 2), (4, 4)} <= skipped and len(skipped) == 7
    # the colour's pairs with s, m (and the exposure or light) in one pass per other entry
    passes = laplace._hessian_passes(problem, problem.layout.size)
    assert ((0, 1, 2), 3, ((0, 3), (1, 3), (2, 3))) in passes
    # (C, s), (C, m), (s, s), (s, m); with a sixth entry e also (C, e), (s, e), (m, e), (e, e)
    assert len(passes) == {5: 4, 6: 8}[problem.layout.size]
    x = jnp.asarray(np.r_[0.6, 0.4, 0.3, 0.55, 0.35, [0.8] * (problem.layout.size - 5)])
    weights = jnp.asarray(np.random.default_rng(3).normal(size=np.asarray(problem.target).size))
    full = np.asarray(jax.hessian(lambda z: jnp.sum(weights * problem.render_physical(z).ravel()))(x))
    largest = np.max(np.abs(full))
    for a, b in skipped:
        assert abs(full[a, b]) <= 1e-12 * largest, (a, b)
    fast = np.asarray(jax.jit(laplace._weighted_model_hessian)(problem, x, weights))
    np.testing.assert_allclose(fast, full, rtol=1e-9, atol=1e-12 * largest)
    # the colour alone: every pair vanishes, and the Hessian is 3 x 3 zeros
    colour_only = build_problem(scene, target, ["color"], material, plan, sf.FitOptions(), 0.01)[0]
    zero = np.asarray(jax.jit(laplace._weighted_model_hessian)(colour_only, x[:3], weights))
    np.testing.assert_array_equal(zero, np.zeros((3, 3)))
