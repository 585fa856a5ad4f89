"""The local Strauss model against the identities and hand-computed values of the model page."""

import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import strauss_fit as sf
from strauss_fit.models.strauss import (
    K_F,
    K_G,
    K_J,
    angular_terms,
    diffuse_reflectivity,
    highlight_falloff,
    normalised_angle,
    shade,
    shade_terms,
    specular_base,
)
from support import SCENES

pytestmark = pytest.mark.usefixtures("x64")

UP = np.array([0.0, 0.0, 1.0])


def direction_at(angle_deg, azimuth_deg=0.0):
    a, b = math.radians(angle_deg), math.radians(azimuth_deg)
    return np.array([math.sin(a) * math.cos(b), math.sin(a) * math.sin(b), math.cos(a)])


def F_hand(x):
    return ((x - K_F) ** -2 - K_F**-2) / ((1 - K_F) ** -2 - K_F**-2)


def G_hand(x):
    return ((1 - K_G) ** -2 - (x - K_G) ** -2) / ((1 - K_G) ** -2 - K_G**-2)


def test_fresnel_and_shadow_end_points():
    assert float(sf.fresnel(0.0)) == pytest.approx(0.0, abs=1e-15)
    assert float(sf.fresnel(1.0)) == pytest.approx(1.0, abs=1e-15)
    assert float(sf.shadow(0.0)) == pytest.approx(1.0, abs=1e-15)
    assert float(sf.shadow(1.0)) == pytest.approx(0.0, abs=1e-15)
    x = np.linspace(0, 1, 101)
    assert np.all(np.diff(np.asarray(sf.fresnel(x))) > 0)  # F rises, G falls
    assert np.all(np.diff(np.asarray(sf.shadow(x))) < 0)
    np.testing.assert_allclose(np.asarray(sf.fresnel(x)), F_hand(x), rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(np.asarray(sf.shadow(x)), G_hand(x), rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_fresnel_and_shadow_vanish_exactly_at_their_zero_in_both_precisions(dtype):
    # The textbook difference of reciprocals gives G(1) = -1.95e-6 in float32; the factored
    # form is exactly zero, and never negative just inside grazing.
    assert float(sf.fresnel(jnp.asarray(0.0, dtype))) == 0.0
    assert float(sf.shadow(jnp.asarray(1.0, dtype))) == 0.0
    tiny = jnp.asarray([0.0, 1e-33, 1e-20, 1e-12, 1e-7, 1e-4], dtype)
    x = normalised_angle(tiny)  # angles a hair short of 90°
    assert float(jnp.max(x)) <= 1.0
    assert np.all(np.asarray(sf.shadow(x)) >= 0)


def test_constants_are_the_lecture_values():
    assert (K_F, K_G, K_J) == (1.12, 1.01, 0.1)


@pytest.mark.parametrize("s,t", [(0.0, 0.0), (0.5, 0.2), (0.9, 0.7), (1.0, 0.0), (0.3, 1.0)])
def test_reflectivities(s, t):
    material = sf.Material(smoothness=s, transparency=t)
    assert float(specular_base(material)) == pytest.approx((1 - t) * s**3, abs=1e-15)
    # r_n = 1 - t - r_d
    assert float(specular_base(material)) == pytest.approx(1 - t - float(diffuse_reflectivity(material)), abs=1e-15)


def test_hand_computed_normal_incidence():
    # alpha = gamma = 0: F = 0, j = 0, cos(beta) = 1, so r_s = r_n and C_s = C_L + m (C - C_L).
    material = sf.Material(color=(0.8, 0.3, 0.2), smoothness=0.5, metalness=0.5, transparency=0.2)
    out = np.asarray(shade(material, UP, UP, UP))
    r_d = (1 - 0.125) * 0.8
    diffuse = (1 - 0.25) * r_d * np.array([0.8, 0.3, 0.2])
    r_n = 0.8 * 0.125
    c_s = 1 + 0.5 * (np.array([0.8, 0.3, 0.2]) - 1)
    np.testing.assert_allclose(out, diffuse + r_n * c_s, rtol=0, atol=1e-14)
    np.testing.assert_allclose(out, [0.51, 0.2225, 0.165], atol=1e-14)


def test_hand_computed_oblique_light():
    # Light at 60 degrees of incidence, viewer along the normal: cos(beta) = cos(120 - 60...) = 0.5.
    material = sf.Material(color=(0.6, 0.5, 0.4), smoothness=0.5, metalness=0.25, transparency=0.0)
    to_light = direction_at(60.0)
    light_color = np.array([1.0, 0.9, 0.8])
    out = np.asarray(shade(material, UP, to_light, UP, light_color=light_color))
    x_a = 2 * (math.pi / 3) / math.pi
    f = F_hand(x_a)
    j = f * G_hand(x_a) * G_hand(0.0)
    r_n = 0.125
    r_j = min(1.0, r_n + j * (r_n + K_J))
    r_s = r_j * 0.5**6  # h = 3 / (1 - 0.5)
    c = np.array([0.6, 0.5, 0.4])
    c_s = light_color + 0.25 * (1 - f) * (c - light_color)
    diffuse = (1 - 0.125) * (1 - 0.125) * c * 0.5 * light_color
    np.testing.assert_allclose(out, diffuse + r_s * c_s, rtol=1e-12, atol=1e-14)


def test_zero_where_light_or_viewer_is_behind():
    material = sf.Material(color=(1, 1, 1), smoothness=0.7)
    below = direction_at(100.0)
    assert np.all(np.asarray(shade(material, UP, below, UP)) == 0)
    assert np.all(np.asarray(shade(material, UP, UP, below)) == 0)
    assert np.all(np.asarray(shade(material, UP, np.array([1.0, 0.0, 0.0]), UP)) == 0)  # grazing


def test_full_transparency_leaves_only_the_j_kj_highlight():
    material = sf.Material(color=(0.2, 0.7, 0.4), smoothness=0.6, metalness=0.0, transparency=1.0)
    to_light, to_eye = direction_at(50.0), direction_at(50.0, 180.0)  # mirror configuration
    terms = angular_terms(UP, to_light, to_eye)
    out = np.asarray(shade(material, UP, to_light, to_eye))
    expected = float(terms.j) * K_J  # r_d = r_n = 0, cos(beta) = 1
    np.testing.assert_allclose(out, [expected] * 3, rtol=1e-12)
    # and there is no diffuse light off the mirror direction either
    off = np.asarray(shade(material, UP, to_light, direction_at(10.0, 90.0)))
    assert np.all(off < expected)


def test_non_metal_highlight_is_white_under_white_light():
    material = sf.Material(color=(0.9, 0.1, 0.1), smoothness=0.8, metalness=0.0)
    to_light, to_eye = direction_at(30.0), direction_at(30.0, 180.0)
    dark = sf.Material(color=(0.9, 0.1, 0.1), smoothness=0.8, metalness=0.0, transparency=0.0)
    terms = angular_terms(UP, to_light, to_eye)
    # Remove the diffuse part by hand: what remains must be grey.
    full = np.asarray(shade_terms(material, terms))
    diffuse = np.asarray((1 - 0.0) * diffuse_reflectivity(dark) * terms.cos_alpha * dark.color)
    specular = full - diffuse
    assert specular[0] > 0.05
    np.testing.assert_allclose(specular, [specular[0]] * 3, rtol=1e-12)


def test_metal_highlight_takes_the_surface_colour():
    colour = np.array([0.9, 0.6, 0.2])
    metal = sf.Material(color=colour, smoothness=0.9, metalness=1.0)
    out = np.asarray(shade(metal, UP, UP, UP))  # F = 0 at normal incidence: C_s = C
    r_n = 0.9**3
    np.testing.assert_allclose(out, (1 - 0.9) * (1 - 0.9**3) * colour + r_n * colour, rtol=1e-12)


def test_smoothness_one_is_a_delta_highlight():
    material = sf.Material(color=(0.5, 0.5, 0.5), smoothness=1.0)
    # Exactly in the mirror direction: r_s = r_j; any other direction: no highlight.
    mirror = np.asarray(shade(material, UP, UP, UP))
    np.testing.assert_allclose(mirror, [1.0, 1.0, 1.0], atol=1e-15)  # r_n = 1, no diffuse
    off = np.asarray(shade(material, UP, UP, direction_at(1e-3)))
    np.testing.assert_allclose(off, 0.0, atol=1e-15)
    assert float(highlight_falloff(1.0, 1.0)) == 1.0
    assert float(highlight_falloff(0.999999, 1.0)) == 0.0
    assert float(highlight_falloff(-0.5, 0.3)) == 0.0


def test_shade_broadcasts_over_leading_axes():
    material = sf.Material(color=(0.5, 0.4, 0.3), smoothness=0.4)
    normals = np.stack([direction_at(a, 20.0) for a in (0, 10, 20, 30)])[:, None, :]
    lights = np.stack([direction_at(a) for a in (0, 45)])[None, :, :]
    out = np.asarray(shade(material, normals, lights, UP))
    assert out.shape == (4, 2, 3)
    for i, j in itertools.product(range(4), range(2)):
        np.testing.assert_allclose(out[i, j], np.asarray(shade(material, normals[i, 0], lights[0, j], UP)), atol=1e-15)


def test_shade_is_jit_grad_and_vmap_compatible():
    material = sf.Material(color=(0.5, 0.4, 0.3), smoothness=0.4, metalness=0.3)

    def total(m):
        return jnp.sum(shade(m, UP, direction_at(20.0), direction_at(15.0, 180.0)))

    grads = jax.jit(jax.grad(total))(material)
    assert np.all(np.isfinite(np.asarray(grads.color)))
    batch = jax.tree_util.tree_map(lambda x: jnp.stack([x, x * 0.5]), material)
    out = jax.vmap(lambda m: shade(m, UP, UP, UP))(batch)
    assert out.shape == (2, 3)
    np.testing.assert_allclose(out[0], shade(material, UP, UP, UP), atol=1e-15)


# --- gradients against central finite differences ---------------------------------------

GEOMETRIES = [(direction_at(35.0, 10.0), direction_at(25.0, 200.0)), (direction_at(70.0), direction_at(5.0, 90.0))]


@pytest.mark.parametrize("to_light,to_eye", GEOMETRIES)
@pytest.mark.parametrize("name", ["color", "smoothness", "metalness", "transparency"])
def test_gradient_matches_finite_differences(name, to_light, to_eye):
    base = dict(color=jnp.array([0.6, 0.4, 0.3]), smoothness=0.55, metalness=0.35, transparency=0.25)
    weights = jnp.array([0.3, 0.5, 0.2])

    def f(value):
        params = dict(base)
        params[name] = value
        return jnp.sum(weights * shade(sf.Material(**params), UP, to_light, to_eye, light_color=(1.0, 0.8, 0.6)))

    x0 = jnp.asarray(base[name], dtype=jnp.float64)
    grad = np.atleast_1d(np.asarray(jax.grad(f)(x0)))
    eps = 1e-6
    numeric = []
    for k in range(x0.size):
        step = np.zeros(x0.size)
        step[k] = eps
        step = jnp.asarray(step.reshape(x0.shape))
        numeric.append((f(x0 + step) - f(x0 - step)) / (2 * eps))
    np.testing.assert_allclose(grad, np.asarray(numeric), rtol=1e-6, atol=1e-9)


def test_gradient_in_light_intensity_matches_finite_differences():
    scene = sf.load_scene(SCENES / "basic.toml").resized(16, 16)
    material = scene.material

    def f(directional, ambient):
        lights = scene.lights.with_intensities({"directional": directional, "ambient": ambient})
        image, _ = sf.render(eqx_replace(scene, lights), material)
        return jnp.sum(image**2)

    d0, a0 = scene.lights.directional.intensity, scene.lights.ambient
    gd, ga = jax.grad(f, argnums=(0, 1))(d0, a0)
    eps = 1e-6
    nd = (f(d0 + eps, a0) - f(d0 - eps, a0)) / (2 * eps)
    na = (f(d0, a0 + eps) - f(d0, a0 - eps)) / (2 * eps)
    np.testing.assert_allclose(float(gd[0]), float(nd), rtol=1e-6)
    np.testing.assert_allclose(float(ga), float(na), rtol=1e-6)


def eqx_replace(scene, lights):
    import equinox as eqx

    return eqx.tree_at(lambda s: s.lights, scene, lights)


# --- extremes: values and gradients finite in float32 and float64 ---------------------

EXTREME_VALUES = [0.0, 1e-6, 0.5, 1 - 1e-6, 1.0]
EXTREME_ANGLES = [0.0, 45.0, 90.0 - 1e-6, 90.0, 120.0]


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_values_and_gradients_finite_at_the_extremes(dtype):
    s, m, t = np.meshgrid(EXTREME_VALUES, EXTREME_VALUES, EXTREME_VALUES, indexing="ij")
    s, m, t = (jnp.asarray(v.ravel(), dtype=dtype) for v in (s, m, t))
    light_angles = jnp.asarray([direction_at(a) for a in EXTREME_ANGLES], dtype=dtype)
    eye_angles = jnp.asarray(
        [direction_at(a, 180.0) for a in EXTREME_ANGLES] + [direction_at(a, 90.0) for a in EXTREME_ANGLES], dtype=dtype
    )
    normal = jnp.asarray(UP, dtype=dtype)

    def total(color, s, m, t, intensity):
        material = sf.Material(color=color, smoothness=s, metalness=m, transparency=t)
        out = shade(material, normal, light_angles[:, None, :], eye_angles[None, :, :])
        return intensity * jnp.sum(out)

    color = jnp.asarray([0.0, 0.5, 1.0], dtype=dtype)
    intensity = jnp.asarray(1.0, dtype=dtype)
    value_and_grad = jax.jit(
        jax.vmap(jax.value_and_grad(total, argnums=(0, 1, 2, 3, 4)), in_axes=(None, 0, 0, 0, None))
    )
    value, grads = value_and_grad(color, s, m, t, intensity)
    assert np.all(np.isfinite(np.asarray(value)))
    for g in grads:
        assert np.all(np.isfinite(np.asarray(g))), g
    # zero-intensity light: still finite
    value0, grads0 = value_and_grad(color, s, m, t, jnp.asarray(0.0, dtype=dtype))
    assert np.all(np.asarray(value0) == 0)
    assert all(np.all(np.isfinite(np.asarray(g))) for g in grads0)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_gradient_near_smoothness_one_is_finite_and_bounded(dtype):
    cos_beta = jnp.linspace(0.0, 1.0, 20001, dtype=dtype)
    for s in (0.99, 1 - 1e-4, 1 - 1e-6):
        g = jax.vmap(jax.grad(highlight_falloff, argnums=1), in_axes=(0, None))(cos_beta, jnp.asarray(s, dtype=dtype))
        assert np.all(np.isfinite(np.asarray(g)))
        # |d/ds cos^h beta| <= 1 / (e (1 - s)) (its maximum over cos beta)
        assert float(jnp.max(jnp.abs(g))) <= 1.01 / (math.e * (1 - s)) * (1.05 if dtype == jnp.float32 else 1.0)


def test_float32_agrees_with_float64_away_from_singular_points():
    rng = np.random.default_rng(0)
    normals = np.tile(UP, (500, 1))
    to_light = np.stack([direction_at(a, b) for a, b in rng.uniform([0, 0], [85, 360], (500, 2))])
    to_eye = np.stack([direction_at(a, b) for a, b in rng.uniform([0, 0], [85, 360], (500, 2))])
    for s in (0.0, 0.3, 0.8):
        m64 = sf.Material(color=(0.7, 0.5, 0.2), smoothness=s, metalness=0.4, transparency=0.3)
        out64 = np.asarray(shade(m64, normals, to_light, to_eye))
        out32 = np.asarray(
            shade(
                m64.astype(jnp.float32),
                normals.astype(np.float32),
                to_light.astype(np.float32),
                to_eye.astype(np.float32),
            )
        )
        assert out32.dtype == np.float32
        np.testing.assert_allclose(out32, out64, atol=2e-5)


# --- table modes: measured worst-case error, as stated in shade's docstring -------------


@pytest.mark.parametrize(
    "mode,size,bound",
    [("table", 256, 4.3e-2), ("table", 1024, 3.1e-3), ("j-table", 256, 4.8e-2), ("j-table", 1024, 3.5e-3)],
)
def test_table_mode_error_bounds(mode, size, bound):
    angles = np.linspace(0.0, 89.999, 721)
    to_light = np.stack([direction_at(a) for a in angles])[:, None, :]
    to_eye = np.stack([direction_at(a, 180.0) for a in angles] + [direction_at(a, 90.0) for a in angles])[None, :, :]
    worst = 0.0
    for s, m, t in itertools.product([0.0, 0.5, 0.9, 1.0], [0.0, 1.0], [0.0, 0.5]):
        material = sf.Material(color=(1.0, 1.0, 1.0), smoothness=s, metalness=m, transparency=t)
        exact = shade(material, UP, to_light, to_eye)
        approx = shade(material, UP, to_light, to_eye, mode=mode, table_size=size)
        worst = max(worst, float(jnp.max(jnp.abs(approx - exact))))
    assert worst <= bound
    assert worst > bound / 100  # the bound is tight enough to mean something


def test_unknown_mode_is_an_error():
    with pytest.raises(ValueError, match="unknown mode"):
        shade(sf.Material(), UP, UP, UP, mode="fast")


# --- material validation ------------------------------------------------------------------


@pytest.mark.parametrize(
    "field,value,pattern",
    [
        ("smoothness", 1.5, r"smoothness = 1.5 is outside its range \[0, 1\]"),
        ("metalness", -0.1, r"metalness = -0.1 is outside its range \[0, 1\]"),
        ("transparency", float("nan"), r"transparency must be a finite number"),
        ("ior", 0.9, r"ior = 0.9 is outside its range \[1, inf\]"),
        ("color", (1.2, 0.0, 0.0), r"color = \[1.2, 0.0, 0.0\] is outside its range"),
        ("color", (0.5, 0.5), r"color must be an RGB triple"),
    ],
)
def test_material_validation_names_field_and_range(field, value, pattern):
    with pytest.raises(sf.MaterialError, match=pattern):
        sf.Material(**{field: value})


def test_material_from_dict_rejects_unknown_keys_and_round_trips():
    with pytest.raises(sf.MaterialError, match="unknown material key"):
        sf.Material.from_dict({"roughness": 0.2})
    values = {"color": [0.1, 0.2, 0.3], "smoothness": 0.25, "metalness": 1.0, "transparency": 0.0, "ior": 1.33}
    assert sf.Material.from_dict(values).to_dict() == values


def test_material_is_not_validated_under_tracing():
    # Inside jit the values are tracers; construction must not try to inspect them.
    out = jax.jit(lambda s: sf.Material(smoothness=s).smoothness * 2)(0.25)
    assert float(out) == 0.5
