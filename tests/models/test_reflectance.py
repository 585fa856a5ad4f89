"""The reflectance models behind one interface (strauss_fit.models.reflectance): hand-computed
values, reciprocity, energy, the linear decomposition, guards, serialisation and the registry."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from strauss_fit.errors import MaterialError, StraussFitError
from strauss_fit.models.albedo import phong_reflectance, strauss_reflectance
from strauss_fit.models.material import Material
from strauss_fit.models.reflectance import REFLECTANCE_MODELS, Parameter, ReflectanceModel, reflectance_model
from strauss_fit.models.strauss import K_F, K_G, K_J, angular_terms, shade, shade_terms
from support import PROPERTY, assert_all_finite, direction_at

pytestmark = pytest.mark.usefixtures("x64")

NAMES = ("strauss", "lambert", "phong", "blinn-phong", "cook-torrance")
UP = np.array([0.0, 0.0, 1.0])
#: One geometry for the hand-computed values: light 35° off the normal, view 50° on the other
#: side and 20° out of the plane of incidence (so R·V, N·H and V·H are all generic).
LIGHT = direction_at(35.0, 0.0)
VIEW = direction_at(50.0, 160.0)

#: One material per model, away from every bound.
VALUES = {
    "strauss": {"color": [0.8, 0.45, 0.2], "smoothness": 0.6, "metalness": 0.3, "transparency": 0.25, "ior": 1.4},
    "lambert": {"albedo": [0.7, 1.3, 0.2]},
    "phong": {"diffuse": [0.6, 0.3, 0.1], "specular": 0.8, "exponent": 7.0},
    "blinn-phong": {"diffuse": [0.6, 0.3, 0.1], "specular": 0.8, "exponent": 7.0},
    "cook-torrance": {"kd": [0.5, 0.3, 0.1], "f0": [0.9, 0.6, 0.3], "roughness": 0.35},
}


def evaluate(name, values, normal=UP, light=LIGHT, view=VIEW):
    model = REFLECTANCE_MODELS[name]
    plain = not any(hasattr(v, "shape") for v in values.values())
    x = model.from_dict(values) if plain else values
    return np.asarray(model.radiance(x, model.terms(normal, light, view)))


# --- hand-computed values ---------------------------------------------------------------------


def test_geometry_is_generic():
    r = 2 * LIGHT[2] * UP - LIGHT
    h = (LIGHT + VIEW) / np.linalg.norm(LIGHT + VIEW)
    assert 0.2 < r @ VIEW < 0.95 and 0.3 < h @ UP < 0.99 and 0.3 < h @ VIEW < 0.99


def strauss_by_hand(c, s, m, t):
    cos_a, cos_g = LIGHT[2], VIEW[2]
    r = 2 * cos_a * UP - LIGHT
    cos_b = max(r @ VIEW, 0.0)

    def f(x):
        return ((x - K_F) ** -2 - K_F**-2) / ((1 - K_F) ** -2 - K_F**-2)

    def g(x):
        return ((1 - K_G) ** -2 - (x - K_G) ** -2) / ((1 - K_G) ** -2 - K_G**-2)

    xa, xg = 2 * math.acos(cos_a) / math.pi, 2 * math.acos(cos_g) / math.pi
    r_d = (1 - s**3) * (1 - t)
    r_n = (1 - t) * s**3
    j = f(xa) * g(xa) * g(xg)
    r_j = min(1.0, r_n + j * (r_n + K_J))
    r_s = r_j * cos_b ** (3 / (1 - s))
    c = np.asarray(c)
    c_s = 1 + m * (1 - f(xa)) * (c - 1)
    return (1 - m * s) * r_d * c * cos_a + r_s * c_s


def test_strauss_by_hand():
    v = VALUES["strauss"]
    expected = strauss_by_hand(v["color"], v["smoothness"], v["metalness"], v["transparency"])
    np.testing.assert_allclose(evaluate("strauss", v), expected, rtol=1e-12)


def test_lambert_by_hand():
    np.testing.assert_allclose(
        evaluate("lambert", VALUES["lambert"]), np.array([0.7, 1.3, 0.2]) * math.cos(math.radians(35))
    )


def test_phong_by_hand():
    r = 2 * LIGHT[2] * UP - LIGHT
    expected = np.array([0.6, 0.3, 0.1]) * LIGHT[2] + 0.8 * (r @ VIEW) ** 7
    np.testing.assert_allclose(evaluate("phong", VALUES["phong"]), expected, rtol=1e-13)


def test_blinn_phong_by_hand():
    h = (LIGHT + VIEW) / np.linalg.norm(LIGHT + VIEW)
    brdf = np.array([0.6, 0.3, 0.1]) / math.pi + 0.8 * (7 + 8) / (8 * math.pi) * (h @ UP) ** 7
    np.testing.assert_allclose(evaluate("blinn-phong", VALUES["blinn-phong"]), math.pi * brdf * LIGHT[2], rtol=1e-13)


def cook_torrance_by_hand(kd, f0, alpha, light=LIGHT, view=VIEW):
    """The textbook form: f = kd/π + F D G / (4 (N·L)(N·V)), radiance π f N·L."""
    h = (light + view) / np.linalg.norm(light + view)
    nl, nv, nh, vh = light[2], view[2], h[2], view @ h
    d = alpha**2 / (math.pi * (nh**2 * (alpha**2 - 1) + 1) ** 2)

    def g1(c):
        tan2 = (1 - c * c) / (c * c)
        return 1 / (1 + (math.sqrt(1 + alpha**2 * tan2) - 1) / 2)

    f0 = np.asarray(f0)
    fresnel = f0 + (1 - f0) * (1 - vh) ** 5
    brdf = np.asarray(kd) / math.pi + fresnel * d * g1(nl) * g1(nv) / (4 * nl * nv)
    return math.pi * brdf * nl


def test_cook_torrance_by_hand():
    v = VALUES["cook-torrance"]
    expected = cook_torrance_by_hand(v["kd"], v["f0"], v["roughness"])
    np.testing.assert_allclose(evaluate("cook-torrance", v), expected, rtol=1e-12)
    # near grazing view and light, where the rewritten G1/(4 N·V) matters
    light, view = direction_at(89.9, 0.0), direction_at(89.5, 170.0)
    got = evaluate("cook-torrance", v, light=light, view=view)
    np.testing.assert_allclose(got, cook_torrance_by_hand(v["kd"], v["f0"], 0.35, light, view), rtol=1e-9)


# --- the Strauss model is the project's ---------------------------------------------------------


@pytest.mark.parametrize("s, m, t", [(0.0, 0.0, 0.0), (0.6, 0.3, 0.25), (0.95, 1.0, 0.0), (1.0, 0.5, 0.5)])
def test_strauss_matches_the_model_module(s, m, t):
    rng = np.random.default_rng(3)
    normal = rng.normal(size=(200, 3)) + [0, 0, 1]
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    light = rng.normal(size=(200, 3))
    light /= np.linalg.norm(light, axis=-1, keepdims=True)
    view = np.array([0.0, 0.3, 1.0]) / math.hypot(0.3, 1.0)
    model = reflectance_model("strauss")
    values = {"color": [0.9, 0.5, 0.2], "smoothness": s, "metalness": m, "transparency": t, "ior": 1.3}
    material = Material(**values)
    got = np.asarray(model.radiance(model.from_dict(values), model.terms(normal, light, view)))
    expected = np.asarray(shade_terms(material, angular_terms(normal, light, view)))
    if s < 1:  # (s = 1 is a delta lobe without a diffuse part: black almost everywhere)
        assert np.count_nonzero(expected) > 100
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(got, np.asarray(shade(material, normal, light, view)), rtol=1e-12, atol=1e-12)
    # the ambient term of docs/model.md: r_d C
    np.testing.assert_allclose(model.ambient(model.from_dict(values)), (1 - s**3) * (1 - t) * np.array([0.9, 0.5, 0.2]))


# --- unlit ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", NAMES)
def test_nothing_where_unlit(name):
    behind = direction_at(120.0, 10.0)
    grazing = direction_at(90.0, 40.0)  # N·L = 0 exactly
    for light, view in ((behind, VIEW), (LIGHT, behind), (grazing, VIEW), (LIGHT, grazing), (behind, behind)):
        assert np.all(evaluate(name, VALUES[name], light=light, view=view) == 0.0)
    assert np.all(evaluate(name, VALUES[name]) > 0.0)


# --- reciprocity -----------------------------------------------------------------------------------


def brdf(name, light, view):
    return evaluate(name, VALUES[name], light=light, view=view) / (math.pi * light[2])


PAIRS = [
    (direction_at(a, p), direction_at(b, q)) for a, p, b, q in [(35, 0, 50, 160), (10, 30, 80, 200), (70, 0, 65, 5)]
]


@pytest.mark.parametrize("name", ["lambert", "blinn-phong", "cook-torrance"])
def test_reciprocal_models(name):
    for light, view in PAIRS:
        np.testing.assert_allclose(brdf(name, light, view), brdf(name, view, light), rtol=1e-12)


def test_phong_and_strauss_are_not_reciprocal():
    light, view = direction_at(20.0, 0.0), direction_at(60.0, 170.0)
    for name in ("phong", "strauss"):
        forward, backward = brdf(name, light, view), brdf(name, view, light)
        assert np.max(np.abs(forward - backward) / backward) > 0.05, name
    # what holds for Phong: the highlight *radiance* k_s (R·V)^n is symmetric (R·V is), so the
    # BRDF is symmetric only once multiplied by cos α
    model = REFLECTANCE_MODELS["phong"]
    x = model.from_dict({"diffuse": [0.0, 0.0, 0.0], "specular": 1.0, "exponent": 3.0})
    for light, view in PAIRS:
        np.testing.assert_allclose(
            model.radiance(x, model.terms(UP, light, view)), model.radiance(x, model.terms(UP, view, light)), rtol=1e-12
        )


# --- energy (albedo) ---------------------------------------------------------------------------------

COSINES = np.cos(np.radians([0.0, 20.0, 45.0, 70.0, 85.0]))


def test_lambert_albedo_is_exact():
    model = reflectance_model("lambert")
    x = model.from_dict({"albedo": [1.0, 0.5, 0.25]})
    for c in (1.0, 0.5, 0.01):
        np.testing.assert_allclose(model.albedo(x, c), [1.0, 0.5, 0.25], rtol=1e-13)
    assert np.all(np.asarray(model.albedo(x, 0.0)) == 0.0)


@pytest.mark.parametrize("n", [0.5, 5.0, 100.0, 10000.0])
def test_phong_albedo_matches_the_albedo_module(n):
    model = reflectance_model("phong")
    x = model.from_dict({"diffuse": [0.3, 0.2, 0.1], "specular": 0.7, "exponent": n})
    angles = np.array([0.0, 30.0, 60.0, 80.0])
    expected = phong_reflectance([1.0], [0.7], [n], [[0.3, 0.2, 0.1]], [[1.0] * 3], angles, nodes=96)[0]
    got = np.stack([model.albedo(x, c) for c in np.cos(np.radians(angles))])
    np.testing.assert_allclose(got, expected, rtol=2e-5)


@pytest.mark.parametrize("s, m", [(0.0, 0.0), (0.3, 1.0), (0.7, 0.5), (0.95, 0.0), (1.0, 1.0)])
def test_strauss_albedo_matches_the_albedo_module(s, m):
    model = reflectance_model("strauss")
    values = {"color": [0.9, 0.5, 0.2], "smoothness": s, "metalness": m, "transparency": 0.2, "ior": 1.5}
    angles = np.array([0.0, 30.0, 60.0, 80.0])
    expected = strauss_reflectance([values["color"]], [s], [m], [0.2], angles, nodes=96)[0]
    x = model.from_dict(values)
    got = np.stack([model.albedo(x, c) for c in np.cos(np.radians(angles))])
    np.testing.assert_allclose(got, expected, atol=3e-5)


def blinn_phong_normal_albedo(e):
    """∫ (e + 8)/(8π) cos^e(θ/2) cos θ dω at normal incidence (H halves the angle), in closed
    form: (e + 8)(e + 2^(−e/2)) / ((e + 2)(e + 4))."""
    return (e + 8) * (e + 2 ** (-e / 2)) / ((e + 2) * (e + 4))


@pytest.mark.parametrize("e", [0.0, 1.0, 8.76, 100.0, 3000.0])
def test_blinn_phong_albedo_at_normal_incidence(e):
    model = reflectance_model("blinn-phong")
    x = model.from_dict({"diffuse": [0.0, 0.0, 0.0], "specular": 1.0, "exponent": e})
    assert float(model.albedo(x, 1.0)[0]) == pytest.approx(blinn_phong_normal_albedo(e), rel=1e-4)


def test_blinn_phong_energy_bound():
    """Normalised Blinn–Phong with k_d + k_s = 1 is *not* bounded by 1: the (e + 8)/(8π) factor
    overshoots by up to 7.5 % at normal incidence (e ≈ 8.8); that is the bound that holds, and
    towards grazing the albedo falls (the lobe is cut by the horizon)."""
    peak = max(blinn_phong_normal_albedo(e) for e in np.linspace(0, 50, 5001))
    assert peak == pytest.approx(1.0752, abs=1e-4)
    model = reflectance_model("blinn-phong")
    for e in (0.0, 2.0, 8.8, 40.0, 1000.0):
        x = model.from_dict({"diffuse": [0.6, 0.3, 0.0], "specular": 0.4, "exponent": e})
        rho = np.stack([model.albedo(x, c) for c in COSINES])
        assert np.all(rho <= 0.6 + 0.4 * peak + 1e-4)
        assert np.all(np.diff(rho[:, 2]) <= 1e-4)  # decreasing with the angle of incidence


@pytest.mark.parametrize("alpha", [0.001, 0.02, 0.1, 0.3, 0.6, 1.0])
def test_cook_torrance_energy(alpha):
    """With F ≡ 1 (F0 = 1) and no diffuse part the microfacet lobe never creates energy (the
    white furnace: ρ ≤ 1, less at large α where single scattering loses light). kd + F0 ≤ 1
    keeps ρ ≤ 1 near normal incidence; not claimed beyond (F rises, the diffuse part is not
    weighted by 1 − F: ρ reaches 1.6 at 85° for α = 0.02)."""
    model = reflectance_model("cook-torrance")
    furnace = model.from_dict({"kd": [0.0, 0.0, 0.0], "f0": [1.0, 1.0, 1.0], "roughness": alpha})
    rho = np.stack([model.albedo(furnace, c) for c in COSINES])
    assert np.all(rho <= 1 + 1e-4)
    assert rho[0, 0] > (0.98 if alpha <= 0.1 else 0.3)
    mixed = model.from_dict({"kd": [0.96, 0.5, 0.0], "f0": [0.04, 0.5, 1.0], "roughness": alpha})
    assert np.all(np.asarray(model.albedo(mixed, 1.0)) <= 1 + 1e-4)


def test_cook_torrance_albedo_matches_brute_force():
    model = reflectance_model("cook-torrance")
    x = model.from_dict({"kd": [0.2, 0.1, 0.0], "f0": [1.0, 0.5, 0.04], "roughness": 0.3})
    count, a = 800, math.radians(60.0)
    theta = (np.arange(count) + 0.5) / count * np.pi / 2
    phi = (np.arange(2 * count) + 0.5) / (2 * count) * 2 * np.pi
    t, p = np.meshgrid(theta, phi, indexing="ij")
    view = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)
    light = np.array([math.sin(a), 0.0, math.cos(a)])
    radiance = np.asarray(model.radiance(x, model.terms(UP, light, view)))
    d_omega = np.sin(t) * (np.pi / 2 / count) * (np.pi / count)
    expected = np.sum(radiance * (np.cos(t) * d_omega)[..., None], axis=(0, 1)) / (math.pi * math.cos(a))
    np.testing.assert_allclose(model.albedo(x, math.cos(a)), expected, rtol=1e-4)


# --- the linear decomposition --------------------------------------------------------------------------


def random_nonlinear(model, rng):
    out = {}
    for name in model.nonlinear:
        p = model.parameter(name)
        high = 50.0 if p.high is None else p.high
        value = rng.uniform(p.low, high, size=p.size)
        out[name] = float(value[0]) if p.size == 1 else value
    return out


@pytest.mark.parametrize("name", NAMES)
def test_linear_parts_reproduce_the_radiance(name):
    model = REFLECTANCE_MODELS[name]
    rng = np.random.default_rng(len(name))
    normal = UP
    light = np.stack([direction_at(a, 0.0) for a in (0.0, 20.0, 45.0, 70.0, 89.0, 100.0)])[:, None]
    view = np.stack([direction_at(a, p) for a, p in ((0, 0), (30, 170), (50, 10), (80, 90))])[None]
    terms = model.terms(normal, light, view)
    for _ in range(6):
        nonlinear = random_nonlinear(model, rng)
        b = rng.uniform(0.1, 5.0)
        a = b * rng.uniform(0.0, 1.0, 3) if model.bounded_scale else rng.uniform(0.0, 3.0, 3)
        per_channel, shared = model.linear_parts(nonlinear, terms)
        assert per_channel.shape == shared.shape == (6, 4, 3)
        values, scale = model.from_linear(nonlinear, a, b)
        assert set(values) == set(model.names)
        assert (scale is not None) == model.bounded_scale
        expected = np.asarray(model.radiance(values, terms)) * (1.0 if scale is None else float(scale))
        got = a * np.asarray(per_channel) + b * np.asarray(shared)
        np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-14)
        for key, value in nonlinear.items():
            np.testing.assert_allclose(values[key], value, rtol=1e-15)


@pytest.mark.parametrize("name", NAMES)
def test_from_linear_clips_to_the_ranges(name):
    model = REFLECTANCE_MODELS[name]
    values, _ = model.from_linear(model.start_grid()[0], jnp.array([-1.0, 5.0, 0.5]), 2.0)
    for p in model.parameters:
        assert p.contains(np.asarray(values[p.name])), p.name
        assert np.shape(values[p.name]) == (() if p.size == 1 else (3,))


@pytest.mark.parametrize("name", NAMES)
def test_start_grid(name):
    model = REFLECTANCE_MODELS[name]
    grid = model.start_grid()
    assert grid and all(set(start) == set(model.nonlinear) for start in grid)
    for start in grid:
        for key, value in start.items():
            assert model.parameter(key).contains(value)
    expected = {"strauss": 35, "lambert": 1, "phong": 14, "blinn-phong": 14, "cook-torrance": 24}
    assert len(grid) == expected[name]


def test_phong_start_grid_is_the_capture_fitters():
    exponents = [start["exponent"] for start in reflectance_model("phong").start_grid()]
    np.testing.assert_allclose(exponents, np.geomspace(2.0, 5000.0, 14))


# --- guards: finite value and gradient at the extremes ----------------------------------------------------

EXTREME_GEOMETRY = [
    (direction_at(0.0), direction_at(0.0)),  # the exact mirror direction at normal incidence
    (direction_at(89.9999, 0.0), direction_at(30.0, 180.0)),  # grazing light
    (direction_at(30.0, 0.0), direction_at(89.9999, 180.0)),  # grazing view
    (direction_at(89.9999, 0.0), direction_at(89.9999, 180.0)),  # both, at the mirror direction
    (direction_at(90.0, 0.0), direction_at(30.0, 180.0)),  # N·L = 0 exactly
    (direction_at(40.0, 0.0), direction_at(40.0, 180.0)),  # the mirror direction (cos β = 1)
    (direction_at(40.0, 0.0), direction_at(60.0, 0.0)),  # cos β < 0
]
LIGHTS = np.stack([g[0] for g in EXTREME_GEOMETRY])
VIEWS = np.stack([g[1] for g in EXTREME_GEOMETRY])

PHONG_EXTREMES = [
    {"diffuse": [0.0, 1.0, 2.0], "specular": k, "exponent": n} for k in (0.0, 1.0) for n in (0.0, 1e-6, 1e4, 1e7)
]
EXTREMES = {
    "strauss": [
        {"color": [c] * 3, "smoothness": s, "metalness": m, "transparency": t, "ior": 1.0}
        for c in (0.0, 1.0)
        for s in (0.0, 1e-6, 0.5, 1 - 1e-6, 1.0)
        for m in (0.0, 1.0)
        for t in (0.0, 1.0)
    ],
    "lambert": [{"albedo": [0.0, 1.0, 1e6]}],
    "phong": [
        {"diffuse": [0.0, 1.0, 2.0], "specular": k, "exponent": n} for k in (0.0, 1.0) for n in (0.0, 1e-6, 1e4, 1e7)
    ],
    "blinn-phong": [
        {"diffuse": [0.0, 1.0, 2.0], "specular": k, "exponent": n} for k in (0.0, 1.0) for n in (0.0, 1e-6, 1e4, 1e7)
    ],
    "cook-torrance": [
        {"kd": [c] * 3, "f0": [f, 0.5, 1.0 - f], "roughness": r}
        for c in (0.0, 1.0)
        for f in (0.0, 1.0)
        for r in (0.0, 1e-12, 1e-6, 1e-3, 0.5, 1.0)
    ],
}


@pytest.mark.parametrize("name", NAMES)
def test_finite_value_and_gradient_at_the_extremes(name):
    model = REFLECTANCE_MODELS[name]
    terms = model.terms(UP, LIGHTS, VIEWS)

    def total(x):
        return jnp.sum(model.radiance(x, terms))

    def total_geometry(x, light, view):
        return jnp.sum(model.radiance(x, model.terms(UP, light, view)))

    def total_albedo(x):
        return jnp.sum(model.albedo(x, 0.3, nodes=16))

    # compiled once: every material of the list has the same structure
    value = jax.jit(lambda x: (model.radiance(x, terms), model.ambient(x)))
    gradient = jax.jit(jax.grad(total))
    geometry_gradient = jax.jit(jax.grad(total_geometry, argnums=(1, 2)))
    albedo_gradient = jax.jit(jax.grad(total_albedo))
    for values in EXTREMES[name]:
        x = model.from_dict(values)
        assert_all_finite(value(x), f"{name} {values}")
        assert_all_finite(gradient(x), f"{name} gradient {values}")
        assert_all_finite(geometry_gradient(x, LIGHTS, VIEWS), f"{name} geometry gradient {values}")
        assert_all_finite(albedo_gradient(x), f"{name} albedo gradient {values}")


def test_cook_torrance_roughness_zero_is_a_lossless_delta():
    model = reflectance_model("cook-torrance")
    x = model.from_dict({"kd": [0.2, 0.2, 0.2], "f0": [1.0, 1.0, 1.0], "roughness": 0.0})
    np.testing.assert_allclose(evaluate("cook-torrance", x), 0.2 * LIGHT[2], rtol=1e-14)
    np.testing.assert_allclose(model.albedo(x, 0.7), 0.2, rtol=1e-5)  # the quadrature's error


# --- values: dictionaries, parameters --------------------------------------------------------------------


@pytest.mark.parametrize("name", NAMES)
def test_dict_round_trip(name):
    model = REFLECTANCE_MODELS[name]
    plain = model.to_dict(model.from_dict(VALUES[name]))
    assert plain == VALUES[name]
    assert model.to_dict(model.defaults()) == {
        p.name: (float(p.default) if p.size == 1 else [float(p.default)] * 3) for p in model.parameters
    }


@given(data=st.data())
@PROPERTY
def test_dict_round_trip_of_random_values(data):
    name = data.draw(st.sampled_from(NAMES))
    model = REFLECTANCE_MODELS[name]
    values = {}
    for p in model.parameters:
        number = st.floats(p.low, 1e6 if p.high is None else p.high, allow_nan=False)
        values[p.name] = data.draw(number) if p.size == 1 else data.draw(st.lists(number, min_size=3, max_size=3))
    assert model.to_dict(model.from_dict(values)) == values


BAD = [
    ({"albedo": [0.5, 0.5, 0.5], "sheen": 1.0}, "unknown lambert parameter(s) sheen"),
    ({}, "missing lambert parameter(s) albedo"),
    ({"albedo": [0.5, -0.1, 0.5]}, "lambert albedo = [0.5, -0.1, 0.5] is outside its range [0, inf) per channel"),
    ({"albedo": [0.5, 0.5]}, "lambert albedo must be a list of 3 numbers"),
    ({"albedo": 0.5}, "lambert albedo must be a list of 3 numbers"),
    ({"albedo": [0.5, float("nan"), 0.5]}, "outside its range"),
    ({"albedo": [True, 0.5, 0.5]}, "must be a list of 3 numbers"),
]


@pytest.mark.parametrize("values, message", BAD)
def test_bad_dicts_are_one_line_errors(values, message):
    with pytest.raises(MaterialError) as error:
        reflectance_model("lambert").from_dict(values)
    assert message in str(error.value) and "\n" not in str(error.value)


@pytest.mark.parametrize(
    "name, change, message",
    [
        ("strauss", {"smoothness": 1.5}, "strauss smoothness = 1.5 is outside its range [0, 1]"),
        ("strauss", {"ior": 0.9}, "strauss ior = 0.9 is outside its range [1, inf)"),
        ("phong", {"exponent": "20"}, "phong exponent must be a number"),
        ("phong", {"specular": [0.1, 0.2, 0.3]}, "phong specular must be a number"),
        ("cook-torrance", {"f0": [0.5, 1.2, 0.5]}, "cook-torrance f0 = [0.5, 1.2, 0.5] is outside its range [0, 1]"),
        ("blinn-phong", {"exponent": float("inf")}, "outside its range"),
    ],
)
def test_out_of_range_values(name, change, message):
    with pytest.raises(StraussFitError) as error:
        REFLECTANCE_MODELS[name].from_dict({**VALUES[name], **change})
    assert message in str(error.value) and "\n" not in str(error.value)


def test_to_dict_checks_names_and_sizes():
    model = reflectance_model("phong")
    with pytest.raises(MaterialError, match="missing phong parameter"):
        model.to_dict({"diffuse": [1.0, 1.0, 1.0], "specular": 1.0})
    with pytest.raises(MaterialError, match="phong specular must have 1 value"):
        model.to_dict({"diffuse": [1.0, 1.0, 1.0], "specular": [1.0, 2.0], "exponent": 3.0})
    # the capture fitter's (1,)-shaped scalars are accepted
    assert model.to_dict({"diffuse": jnp.ones(3), "specular": jnp.array([2.0]), "exponent": jnp.array([3.0])}) == {
        "diffuse": [1.0, 1.0, 1.0],
        "specular": 2.0,
        "exponent": 3.0,
    }


def test_nonlinear_values_are_checked():
    with pytest.raises(MaterialError, match="color not among strauss's non-linear parameters"):
        reflectance_model("strauss").linear_parts({"color": 1.0}, {})


def test_parameter_kinds_and_checks():
    assert Parameter("a", 1, 0.0, 1.0, 0.5, "", "").kind == "unit"
    assert Parameter("a", 3, 0.0, None, 0.5, "", "").kind == "positive"
    assert Parameter("a", 1, None, None, 0.0, "", "").kind == "free"
    assert reflectance_model("strauss").parameter("ior").kind == "positive"
    for bad in (
        dict(size=2),
        dict(low=None),
        dict(low=1.0, high=0.0),
        dict(default=2.0),
    ):
        fields = {"name": "a", "size": 1, "low": 0.0, "high": 1.0, "default": 0.5, "doc": "", "needs": ""} | bad
        with pytest.raises(ValueError):
            Parameter(**fields)


# --- the registry ----------------------------------------------------------------------------------------


def test_registry():
    assert tuple(REFLECTANCE_MODELS) == NAMES
    for name, model in REFLECTANCE_MODELS.items():
        assert isinstance(model, ReflectanceModel) and model.name == name and reflectance_model(name) is model
        assert jax.tree_util.tree_leaves(model) == []  # no fields: a static pytree
        assert set(model.nonlinear) <= set(model.names)
        for p in model.parameters:
            assert p.doc and p.needs and "\n" not in p.doc + p.needs
    assert {n for n, m in REFLECTANCE_MODELS.items() if m.bounded_scale} == {"strauss", "cook-torrance"}
    with pytest.raises(StraussFitError) as error:
        reflectance_model("ward")
    assert str(error.value) == (
        "unknown reflectance model 'ward'; expected one of strauss, lambert, phong, blinn-phong, cook-torrance"
    )
    with pytest.raises(TypeError):
        REFLECTANCE_MODELS["ward"] = REFLECTANCE_MODELS["lambert"]  # read-only


def test_ambient_is_the_diffuse_albedo():
    for name, key in (("lambert", "albedo"), ("phong", "diffuse"), ("blinn-phong", "diffuse"), ("cook-torrance", "kd")):
        model = REFLECTANCE_MODELS[name]
        np.testing.assert_allclose(model.ambient(model.from_dict(VALUES[name])), VALUES[name][key])


@pytest.mark.parametrize("name", NAMES)
def test_radiance_compiles_and_broadcasts(name):
    model = REFLECTANCE_MODELS[name]
    x = model.from_dict(VALUES[name])
    light = np.stack([LIGHT, direction_at(10.0, 40.0)])[:, None]  # (2, 1, 3)
    view = np.stack([VIEW, direction_at(20.0, 200.0), direction_at(5.0, 90.0)])[None]  # (1, 3, 3)
    radiance = jax.jit(lambda m, x: m.radiance(x, m.terms(UP, light, view)))(model, x)
    assert radiance.shape == (2, 3, 3)
    np.testing.assert_allclose(radiance[0, 0], evaluate(name, VALUES[name]), rtol=1e-13)
