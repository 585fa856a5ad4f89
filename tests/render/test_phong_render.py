"""The Phong renderer: hand-computed pixels, an independent reference, validation, gradients."""

import math
import tomllib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import strauss_fit as sf
from strauss_fit.errors import MaterialError
from strauss_fit.models.phong import PhongMaterial, phong_shade
from strauss_fit.rendering.phong import render_phong
from strauss_fit.scene.loading import parse_scene

pytestmark = pytest.mark.usefixtures("x64")

CD = [1.0, 0.5, 0.25]
CS = [1.0, 1.0, 0.5]


def scene(text, width=1, height=1, camera_extra="", background="color = [0.0, 0.0, 0.0]"):
    return parse_scene(
        tomllib.loads(f"""
[camera]
width = {width}
height = {height}
{camera_extra}
{text}
[background]
{background}
"""),
        source="test.toml",
    )


ONE_LIGHT = """
[[light]]
kind = "directional"
direction = [0.0, 1.0, 1.0]
intensity = 2.0
color = [1.0, 0.8, 0.6]
[[light]]
kind = "ambient"
intensity = 0.5
"""


def material(**overrides):
    values = dict(ka=0.2, kd=0.6, ks=0.4, exponent=4.0, diffuse_color=CD, specular_color=CS)
    values.update(overrides)
    return PhongMaterial(**values)


def test_single_pixel_by_hand():
    # A 1x1 orthographic image sees the sphere's front point: N = V = (0, 0, 1).
    # L = (0, 1, 1)/sqrt2: N.L = 1/sqrt2; R = 2(N.L)N - L = (0, -1, 1)/sqrt2, R.V = 1/sqrt2,
    # (R.V)^4 = 1/4. Ambient 0.2 * 0.5 * Cd = 0.1 Cd. Light 2 * C_L * (0.6 Cd / sqrt2 + 0.4 Cs / 4):
    #   R: 0.1      + 2 * 1.0 * (0.6/sqrt2 * 1.0  + 0.1 * 1.0) = 1.14852814
    #   G: 0.05     + 2 * 0.8 * (0.6/sqrt2 * 0.5  + 0.1 * 1.0) = 0.54941125
    #   B: 0.025    + 2 * 0.6 * (0.6/sqrt2 * 0.25 + 0.1 * 0.5) = 0.21227922
    image, mask = render_phong(scene(ONE_LIGHT), material())
    assert bool(mask[0, 0])
    np.testing.assert_allclose(np.asarray(image[0, 0]), [1.14852814, 0.54941125, 0.21227922], atol=1e-8)


def test_single_pixel_blinn_by_hand():
    # Blinn-Phong: H = (L + V)/|L + V| is at 22.5 degrees from N, so N.H = cos(pi/8) and
    # (N.H)^4 = ((1 + cos(pi/4))/2)^2 = 0.72855339. Specular 0.4 * Cs * 0.72855339.
    #   R: 0.1   + 2 * 1.0 * (0.42426407 + 0.29142136) = 1.53137085
    #   G: 0.05  + 2 * 0.8 * (0.21213203 + 0.29142136) = 0.85568542
    #   B: 0.025 + 2 * 0.6 * (0.10606602 + 0.14571068) = 0.32713203
    image, _ = render_phong(scene(ONE_LIGHT), material(blinn=True))
    np.testing.assert_allclose(np.asarray(image[0, 0]), [1.53137085, 0.85568542, 0.32713203], atol=1e-8)


def test_two_by_two_by_hand():
    # Pixels at x, y = +-0.5: N = (+-0.5, +-0.5, sqrt(0.5)); light along V = (0, 0, 1), intensity 1.
    # N.L = sqrt(0.5) = 0.70710678; R.V = 2 (N.L)^2 - 1 = 0, so Phong has no highlight:
    # pixel = 0.2 * 0.5 * Cd + 0.6 * Cd * 0.70710678 = 0.52426407 Cd.
    # Blinn: H = V, N.H = 0.70710678, squared (n = 2) = 0.5: + 0.4 * Cs * 0.5 = 0.2 Cs.
    lights = """
[[light]]
kind = "directional"
direction = [0.0, 0.0, 1.0]
intensity = 1.0
[[light]]
kind = "ambient"
intensity = 0.5
"""
    s = scene(lights, width=2, height=2)
    phong, _ = render_phong(s, material(exponent=2.0))
    blinn, _ = render_phong(s, material(exponent=2.0, blinn=True))
    for i in range(2):
        for k in range(2):
            np.testing.assert_allclose(np.asarray(phong[i, k]), 0.52426407 * np.array(CD), atol=1e-8)
            np.testing.assert_allclose(
                np.asarray(blinn[i, k]), 0.52426407 * np.array(CD) + 0.2 * np.array(CS), atol=1e-8
            )


def reference_image(width, height, perspective, lights, ambient, m, background):
    """An independent per-pixel implementation of the module docstring's formulas."""
    out = np.zeros((height, width, 3))
    ka, kd, ks = (np.broadcast_to(np.asarray(v, float), 3) for v in (m["ka"], m["kd"], m["ks"]))
    for i in range(height):
        for k in range(width):
            x = (k + 0.5) / width * 2 - 1
            y = 1 - (i + 0.5) / height * 2
            if perspective:
                half = math.tan(math.radians(30.0) / 2)
                origin = np.array([0.0, 0.0, 4.0])
                d = np.array([x * half * width / height, y * half, -1.0])
                d /= np.linalg.norm(d)
            else:
                origin = np.array([x, y, 2.0])
                d = np.array([0.0, 0.0, -1.0])
            b = origin @ d
            disc = b * b - (origin @ origin - 1)
            if disc <= 0 or -b - math.sqrt(disc) <= 0:
                out[i, k] = background
                continue
            p = origin + (-b - math.sqrt(disc)) * d
            n = p / np.linalg.norm(p)
            v = -d
            value = ka * ambient * np.array(m["diffuse_color"])
            for kind, where, intensity, color, att in lights:
                if kind == "directional":
                    l_vec = np.array(where) / np.linalg.norm(where)
                    irradiance = intensity
                else:
                    offset = np.array(where) - p
                    dist = np.linalg.norm(offset)
                    l_vec = offset / dist
                    irradiance = intensity / (att[0] + att[1] * dist + att[2] * dist**2)
                if n @ l_vec <= 0 or n @ v <= 0:
                    continue
                if m["blinn"]:
                    h = (l_vec + v) / np.linalg.norm(l_vec + v)
                    cos_b = max(n @ h, 0.0)
                else:
                    r = 2 * (n @ l_vec) * n - l_vec
                    cos_b = max(r @ v, 0.0)
                spec = cos_b ** m["exponent"] if cos_b > 0 else 0.0
                value = value + irradiance * np.array(color) * (
                    kd * np.array(m["diffuse_color"]) * (n @ l_vec) + ks * np.array(m["specular_color"]) * spec
                )
            out[i, k] = value
    return out


@pytest.mark.parametrize("perspective", [False, True])
@pytest.mark.parametrize("blinn", [False, True])
def test_every_pixel_matches_an_independent_reference(perspective, blinn):
    lights = [
        ("directional", [0.4, 0.5, 1.0], 1.2, [1.0, 0.9, 0.8], None),
        ("point", [1.5, -1.0, 2.5], 6.0, [0.7, 0.8, 1.0], [0.5, 0.1, 0.8]),
    ]
    text = """
[[light]]
kind = "directional"
direction = [0.4, 0.5, 1.0]
intensity = 1.2
color = [1.0, 0.9, 0.8]
[[light]]
kind = "point"
position = [1.5, -1.0, 2.5]
intensity = 6.0
color = [0.7, 0.8, 1.0]
attenuation = [0.5, 0.1, 0.8]
[[light]]
kind = "ambient"
intensity = 0.15
"""
    cam = 'projection = "perspective"' if perspective else ""
    s = scene(text, width=13, height=9, camera_extra=cam, background="color = [0.1, 0.2, 0.3]")
    m = dict(
        ka=[0.5, 1.0, 1.5],
        kd=0.7,
        ks=[0.2, 0.3, 0.4],
        exponent=17.5,
        diffuse_color=[0.9, 0.4, 0.1],
        specular_color=[1.0, 0.9, 0.8],
        blinn=blinn,
    )
    image, mask = render_phong(s, PhongMaterial(**m))
    expected = reference_image(13, 9, perspective, lights, 0.15, m, [0.1, 0.2, 0.3])
    np.testing.assert_allclose(np.asarray(image), expected, rtol=1e-10, atol=1e-12)
    assert int(np.sum(mask)) > 0 and not bool(np.all(mask))


def test_misses_show_the_background_like_the_strauss_renderer():
    s = scene(ONE_LIGHT, width=24, height=16, background='kind = "checkerboard"\nsquare_size = 0.3')
    phong, phong_mask = render_phong(s, material())
    strauss, strauss_mask = sf.render(s, plan=sf.RenderPlan(False, False))
    miss = ~np.asarray(phong_mask)
    np.testing.assert_array_equal(np.asarray(phong_mask), np.asarray(strauss_mask))
    np.testing.assert_array_equal(np.asarray(phong)[miss], np.asarray(strauss)[miss])
    assert np.ptp(np.asarray(phong)[miss]) > 0.5  # the board is really there


def test_lights_behind_the_surface_add_nothing():
    behind = '[[light]]\nkind = "directional"\ndirection = [0.0, 0.0, -1.0]\nintensity = 5.0\n'
    image, mask = render_phong(scene(behind, width=8, height=8), material(exponent=0.0))
    assert np.all(np.asarray(image) == 0.0) and bool(np.any(mask))
    # directly: N.L <= 0 or N.V <= 0 gives 0, even with exponent 0
    n = jnp.array([0.0, 0.0, 1.0])
    assert np.all(np.asarray(phong_shade(material(exponent=0.0), n, jnp.array([1.0, 0.0, 0.0]), n)) == 0)
    assert np.all(np.asarray(phong_shade(material(exponent=0.0), n, n, jnp.array([0.0, 1.0, 0.0]))) == 0)


def test_exponent_zero_gives_a_flat_highlight_where_cos_beta_is_positive():
    n = jnp.array([0.0, 0.0, 1.0])
    to_light = jnp.array([0.0, 0.6, 0.8])
    value = phong_shade(material(exponent=0.0), n, to_light, n)
    np.testing.assert_allclose(np.asarray(value), 0.6 * np.array(CD) * 0.8 + 0.4 * np.array(CS), atol=1e-12)


@pytest.mark.parametrize("exponent", [0.0, 1.0, 60.0, 10000.0])
def test_gradients_are_finite(exponent):
    s = scene(ONE_LIGHT.replace("[0.0, 1.0, 1.0]", "[1.0, 0.0, 0.0]"), width=10, height=10)  # grazing light

    def loss(m):
        return jnp.sum(render_phong(s, m)[0] ** 2)

    for blinn in (False, True):
        grads = jax.grad(loss)(material(exponent=exponent, blinn=blinn))
        for leaf in jax.tree_util.tree_leaves(grads):
            assert np.all(np.isfinite(np.asarray(leaf)))
    g32 = jax.grad(lambda m: jnp.sum(render_phong(s, m, dtype=jnp.float32)[0]))(material(exponent=exponent))
    assert all(np.all(np.isfinite(np.asarray(x))) for x in jax.tree_util.tree_leaves(g32))


def test_float32_agrees_with_float64():
    s = scene(ONE_LIGHT, width=16, height=16)
    f64, _ = render_phong(s, material(exponent=30.0))
    f32, _ = render_phong(s, material(exponent=30.0), dtype=jnp.float32)
    assert f32.dtype == jnp.float32 and f64.dtype == jnp.float64
    np.testing.assert_allclose(np.asarray(f32), np.asarray(f64), atol=1e-5)


@pytest.mark.parametrize(
    "field,value,message",
    [
        ("ka", -0.1, "phong ka = -0.1 is outside its range [0, inf]"),
        ("kd", [0.5, -1.0, 0.5], "phong kd = [0.5, -1.0, 0.5] is outside its range [0, inf] per channel"),
        ("ks", [1.0, 2.0], "phong ks must be a number or an RGB triple"),
        ("ks", float("nan"), "phong ks must be finite"),
        ("exponent", 10000.5, "phong exponent = 10000.5 is outside its range [0, 10000]"),
        ("exponent", -1.0, "phong exponent = -1.0 is outside its range [0, 10000]"),
        ("exponent", [1.0, 2.0, 3.0], "phong exponent must be a number"),
        ("diffuse_color", [1.5, 0.0, 0.0], "phong diffuse_color = [1.5, 0.0, 0.0] is outside its range [0, 1]"),
        ("specular_color", [1.0, 1.0], "phong specular_color must be an RGB triple"),
        ("blinn", 1, "phong blinn must be true or false"),
    ],
)
def test_out_of_range_values_name_the_field_and_range(field, value, message):
    with pytest.raises(MaterialError) as info:
        material(**{field: value})
    assert message in str(info.value) and "\n" not in str(info.value)


def test_dict_round_trip_is_exact():
    m = PhongMaterial(
        ka=0.1 + 0.2,
        kd=[1 / 3, 2 / 3, 0.7],
        ks=0.30000000000000004,
        exponent=123.456789012345,
        diffuse_color=[0.1, 0.2, 0.3],
        specular_color=[1.0, 1.0, 1.0],
        blinn=True,
    )
    d = m.to_dict()
    assert d["ka"] == 0.1 + 0.2 and isinstance(d["ka"], float)
    assert d["kd"] == [1 / 3, 2 / 3, 0.7] and d["blinn"] is True
    again = PhongMaterial.from_dict(d)
    assert again.to_dict() == d
    with pytest.raises(MaterialError, match="unknown phong key"):
        PhongMaterial.from_dict({"shininess": 3.0})
    with pytest.raises(MaterialError, match="phong kd must be a number or a list of 3 numbers"):
        PhongMaterial.from_dict({"kd": "0.5"})
    with pytest.raises(MaterialError, match="phong blinn must be true or false"):
        PhongMaterial.from_dict({"blinn": "yes"})


def test_jit_and_vmap_over_materials():
    s = scene(ONE_LIGHT, width=6, height=6)
    batch = jax.tree_util.tree_map(lambda x: jnp.stack([x, x * 0.5]), material())
    images = jax.vmap(lambda m: render_phong(s, m)[0])(batch)
    assert images.shape == (2, 6, 6, 3)
    np.testing.assert_allclose(np.asarray(images[0]), np.asarray(render_phong(s, material())[0]), atol=1e-12)
