"""The closed-form derivatives of the lights' part of the local model
(:func:`strauss_fit.rendering.strauss.direct_radiance`, a ``jax.custom_jvp``) against JAX's own
differentiation of the same function (:func:`strauss_fit.rendering.strauss._direct_radiance`,
the plain code): first derivatives in every input a fit moves (C, s, m, t, the
irradiance), second derivatives (the Laplace curvature uses ``jax.hessian``), reverse mode,
finiteness at the extremes of the stability grid, the fallback for tangents of the
geometry, and a fit's Jacobian against finite differences."""

from __future__ import annotations

import importlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import strauss_fit as sf
from strauss_fit.models.strauss import angular_terms
from support import GRAZING, GRID, assert_all_finite, direction_at, key_and_fill_scene, noisy_target

pytestmark = pytest.mark.usefixtures("x64")

render_module = importlib.import_module("strauss_fit.rendering.strauss")
direct_radiance = render_module.direct_radiance
plain_direct_radiance = render_module._direct_radiance

#: Light directions (degrees from the normal, azimuth): head-on, oblique, grazing, behind.
LIGHTS = ((0.0, 0.0), (40.0, 30.0), (75.0, 200.0), (GRAZING, 90.0), (120.0, 10.0))
#: View directions at the pixels (degrees from the normal, azimuth), including the mirror
#: direction of the second light (cos β = 1) and grazing view.
VIEWS = ((0.0, 0.0), (40.0, 210.0), (20.0, 45.0), (60.0, 300.0), (GRAZING, 0.0), (89.0, 180.0))
LIGHT_COLORS = np.array([[1.0, 1.0, 1.0], [1.0, 0.8, 0.6], [0.3, 0.5, 1.0], [1.0, 1.0, 1.0], [0.2, 0.2, 0.2]])


def _geometry():
    """Angular terms of every light at every view, fields (pixels, lights)."""
    to_light = np.stack([direction_at(*a) for a in LIGHTS])
    to_eye = np.stack([direction_at(*v) for v in VIEWS])
    normal = np.array([0.0, 0.0, 1.0])
    terms = angular_terms(normal[None, None, :], to_light[None, :, :], to_eye[:, None, :])
    irradiance = np.linspace(0.5, 2.0, len(VIEWS) * len(LIGHTS)).reshape(len(VIEWS), len(LIGHTS))
    return terms, irradiance


def _inputs(s: float, m: float, t: float, color=(0.8, 0.4, 0.1)):
    terms, irradiance = _geometry()
    return (jnp.asarray(color), jnp.asarray(s), jnp.asarray(m), jnp.asarray(t), jnp.asarray(irradiance))


def _flat(function, terms):
    """The function of one vector (C, s, m, t, E) with the geometry fixed."""

    def of(vector):
        color, s, m, t = vector[:3], vector[3], vector[4], vector[5]
        irradiance = vector[6:].reshape(len(VIEWS), len(LIGHTS))
        return function(color, s, m, t, irradiance, terms, jnp.asarray(LIGHT_COLORS)).ravel()

    return of


def _vector(s, m, t, color=(0.8, 0.4, 0.1)):
    color, s, m, t, irradiance = _inputs(s, m, t, color)
    return jnp.concatenate([color, jnp.stack([s, m, t]), irradiance.ravel()])


# the grid's interior (s < 1 is where the highlight has a slope) and its extremes
SMOOTH_POINTS = [(0.3, 0.6, 0.2), (0.9, 0.0, 0.0), (0.05, 1.0, 0.7), (0.99, 0.5, 0.0), (0.6, 0.3, 1.0)]


def test_closed_form_jacobian_equals_jax_forward_and_reverse_mode():
    terms, _ = _geometry()
    xs = jnp.stack([_vector(*point) for point in SMOOTH_POINTS])
    expected = jax.jit(jax.vmap(jax.jacfwd(_flat(plain_direct_radiance, terms))))(xs)
    assert float(jnp.min(jnp.max(jnp.abs(expected), axis=(1, 2)))) > 0.1  # not a comparison of zeros
    forward = jax.jit(jax.vmap(jax.jacfwd(_flat(direct_radiance, terms))))(xs)
    reverse = jax.jit(jax.vmap(jax.jacrev(_flat(direct_radiance, terms))))(xs)
    np.testing.assert_allclose(forward, expected, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(reverse, expected, rtol=1e-12, atol=1e-13)
    # values too: the custom function renders exactly what the plain one does
    np.testing.assert_array_equal(
        jax.vmap(_flat(direct_radiance, terms))(xs), jax.vmap(_flat(plain_direct_radiance, terms))(xs)
    )


def test_closed_form_second_derivatives_equal_jax():
    terms, _ = _geometry()
    xs = jnp.stack([_vector(*point) for point in SMOOTH_POINTS])

    def hessians(function):
        half_square = lambda v: 0.5 * jnp.sum(_flat(function, terms)(v) ** 2)  # noqa: E731
        return jax.jit(jax.vmap(jax.hessian(half_square)))(xs)

    np.testing.assert_allclose(hessians(direct_radiance), hessians(plain_direct_radiance), rtol=1e-11, atol=1e-12)


def test_every_grid_extreme_gives_the_same_finite_jacobian_as_jax():
    """The 125 (s, m, t) extremes of the stability tests (0, 1e-6, ½, 1 − 1e-6, 1), where the
    highlight's exponent is infinite (s = 1), the peak clamp may tie (r_j = 1) and lights
    graze: finite everywhere and equal to JAX's own derivatives of the guarded code."""
    terms, _ = _geometry()
    jac = jax.jit(jax.vmap(jax.jacfwd(_flat(direct_radiance, terms))))
    jac_plain = jax.jit(jax.vmap(jax.jacfwd(_flat(plain_direct_radiance, terms))))
    grad = jax.jit(jax.vmap(jax.grad(lambda v: jnp.sum(_flat(direct_radiance, terms)(v)))))
    xs = jnp.stack([_vector(*row) for row in GRID])
    got, expected = jac(xs), jac_plain(xs)
    assert_all_finite(got, "closed-form Jacobian on the extreme grid")
    assert_all_finite(grad(xs), "reverse-mode gradient on the extreme grid")
    np.testing.assert_allclose(got, expected, rtol=1e-10, atol=1e-12)


def test_peak_clamp_tie_takes_half_the_slope_as_jax_does():
    """At r_n (1 + j) + j k_j = 1 exactly JAX gives ``minimum`` half its slope: a light
    head-on (j = 0 at normal incidence) and s³ = 1 with t = 0 ties r_j = 1 at s = 1, and
    the closed form must not disagree there."""
    terms, _ = _geometry()
    x = _vector(1.0, 0.5, 0.0)
    np.testing.assert_allclose(
        jax.jit(jax.jacfwd(_flat(direct_radiance, terms)))(x),
        jax.jit(jax.jacfwd(_flat(plain_direct_radiance, terms)))(x),
        atol=1e-13,
    )


def test_geometry_tangents_fall_back_to_forward_mode():
    """Differentiating through the geometry (here the light's direction, never a fit's
    parameter) is not covered by the closed form: it must still be right."""

    def image(angle):
        to_light = jnp.stack([jnp.sin(angle), 0.0, jnp.cos(angle)])
        terms = angular_terms(jnp.array([0.0, 0.0, 1.0]), to_light[None, :], jnp.asarray(direction_at(30.0, 180.0)))
        return lambda function: function(
            jnp.array([0.7, 0.5, 0.2]), 0.6, 0.3, 0.1, jnp.array([1.0]), terms, jnp.array([[1.0, 1.0, 1.0]])
        )

    angle = 0.4
    got = jax.jit(jax.jacfwd(lambda a: image(a)(direct_radiance)))(angle)
    expected = jax.jit(jax.jacfwd(lambda a: image(a)(plain_direct_radiance)))(angle)
    assert float(jnp.max(jnp.abs(expected))) > 0.01
    np.testing.assert_allclose(got, expected, rtol=1e-12)
    step = 1e-6
    plain = jax.jit(lambda a: image(a)(plain_direct_radiance))
    central = (plain(angle + step) - plain(angle - step)) / (2 * step)
    np.testing.assert_allclose(got, central, rtol=1e-6, atol=1e-9)


def test_fit_jacobian_matches_finite_differences():
    """A whole fit's residual Jacobian (colour, s, m, t and the key light's intensity free),
    built through the closed form, against central differences of the residual."""
    from strauss_fit.fitting.options import FitOptions
    from strauss_fit.fitting.problem import build_problem

    scene = key_and_fill_scene(24)
    truth = sf.Material(color=(0.7, 0.3, 0.2), smoothness=0.6, metalness=0.4, transparency=0.2)
    target = noisy_target(scene, truth, noise=0.01, seed=3)
    names = ["color", "smoothness", "metalness", "transparency", "directional_intensity_1"]
    problem, _, _ = build_problem(scene, target, names, truth, sf.plan_render(scene, truth), FitOptions())
    start = {"color": [0.5, 0.5, 0.5], "smoothness": 0.5, "metalness": 0.5, "transparency": 0.3}
    x = jnp.asarray(problem.layout.join({**start, "directional_intensity_1": 0.8}))
    jac = np.asarray(jax.jit(jax.jacfwd(lambda v: problem.residual_physical(v)))(x))
    residual = jax.jit(lambda v: problem.residual_physical(v))
    step = 1e-6
    columns = [(residual(x + step * e) - residual(x - step * e)) / (2 * step) for e in np.eye(x.size)]
    assert np.all(np.abs(jac).max(axis=0) > 1e-3)  # every column moves the image
    np.testing.assert_allclose(jac, np.stack(columns, axis=1), rtol=1e-6, atol=1e-8)
