"""Rendering the sphere: pixel geometry, lights, cameras, precision."""

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import strauss_fit as sf
from strauss_fit.rendering.strauss import RenderPlan, plan_render, prepare
from strauss_fit.scene.loading import parse_scene

pytestmark = pytest.mark.usefixtures("x64")


def scene_from(text_light, width=24, height=24, background="[background]\ncolor = [0.0, 0.0, 0.0]", extra=""):
    import tomllib

    text = f"""
[camera]
projection = "orthographic"
width = {width}
height = {height}

[material]
color = [0.7, 0.5, 0.3]
smoothness = 0.6
metalness = 0.3
transparency = 0.0

{text_light}

{background}
{extra}
"""
    return parse_scene(tomllib.loads(text), source="test.toml")


DIRECTIONAL = '[[light]]\nkind = "directional"\ndirection = [0.3, 0.5, 1.0]\nintensity = 1.5\ncolor = [1.0, 0.9, 0.8]'


def pixel_normal(i, k, width, height):
    x = (k + 0.5) / width * 2 - 1
    y = 1 - (i + 0.5) / height * 2
    return np.array([x, y, math.sqrt(1 - x * x - y * y)])


def test_pixel_convention_and_mask():
    scene = scene_from(DIRECTIONAL, width=20, height=10)
    _, mask = sf.render(scene)
    mask = np.asarray(mask)
    assert mask.shape == (10, 20)
    for i in range(10):
        for k in range(20):
            x = (k + 0.5) / 20 * 2 - 1
            y = 1 - (i + 0.5) / 10 * 2
            assert mask[i, k] == (x * x + y * y < 1)


def test_rendered_pixel_equals_shade_at_its_normal():
    scene = scene_from(DIRECTIONAL)
    image, mask = sf.render(scene)
    material = scene.material
    direction = np.array([0.3, 0.5, 1.0]) / np.linalg.norm([0.3, 0.5, 1.0])
    for i, k in [(12, 12), (5, 9), (3, 12), (20, 4), (11, 22)]:
        assert mask[i, k]
        normal = pixel_normal(i, k, 24, 24)
        expected = 1.5 * np.asarray(sf.shade(material, normal, direction, [0, 0, 1.0], light_color=[1.0, 0.9, 0.8]))
        np.testing.assert_allclose(np.asarray(image[i, k]), expected, rtol=1e-12, atol=1e-14)


def test_background_fills_the_missed_pixels():
    scene = scene_from(DIRECTIONAL, background="[background]\ncolor = [0.2, 0.4, 0.6]")
    image, mask = sf.render(scene)
    np.testing.assert_array_equal(
        np.asarray(image)[~np.asarray(mask)], np.tile([0.2, 0.4, 0.6], ((~np.asarray(mask)).sum(), 1))
    )


def test_point_light_attenuation_and_direction():
    light = '[[light]]\nkind = "point"\nposition = [1.0, 2.0, 3.0]\nintensity = 7.0\nattenuation = [0.5, 0.2, 0.1]'
    scene = scene_from(light)
    image, _ = sf.render(scene)
    i, k = 9, 14
    normal = pixel_normal(i, k, 24, 24)
    offset = np.array([1.0, 2.0, 3.0]) - normal
    d = np.linalg.norm(offset)
    expected = (
        7.0 / (0.5 + 0.2 * d + 0.1 * d * d) * np.asarray(sf.shade(scene.material, normal, offset / d, [0, 0, 1.0]))
    )
    np.testing.assert_allclose(np.asarray(image[i, k]), expected, rtol=1e-12)


def test_lights_add_up_and_ambient_is_rd_times_c():
    two = DIRECTIONAL + '\n[[light]]\nkind = "directional"\ndirection = [-1.0, 0.0, 0.5]\nintensity = 0.5'
    ambient = '[[light]]\nkind = "ambient"\nintensity = 0.3'
    second = '[[light]]\nkind = "directional"\ndirection = [-1.0, 0.0, 0.5]\nintensity = 0.5'
    both, mask = sf.render(scene_from(two + "\n" + ambient))
    first, _ = sf.render(scene_from(DIRECTIONAL))
    other, _ = sf.render(scene_from(second))
    amb, _ = sf.render(scene_from(ambient))
    np.testing.assert_allclose(np.asarray(both), np.asarray(first + other + amb), atol=1e-14)
    material = scene_from(ambient).material
    r_d = (1 - 0.6**3) * (1 - 0.0)
    expected = 0.3 * r_d * np.array([0.7, 0.5, 0.3])
    np.testing.assert_allclose(np.asarray(amb)[np.asarray(mask)], np.tile(expected, (int(mask.sum()), 1)), atol=1e-15)
    assert material.transparency == 0.0


def test_only_the_terms_the_scene_has_are_computed():
    ambient_only = scene_from('[[light]]\nkind = "ambient"\nintensity = 0.3')
    prepared = prepare(ambient_only, plan_render(ambient_only, ambient_only.material))
    assert prepared.direct is None and prepared.irradiance is None
    directional = scene_from(DIRECTIONAL)
    prepared = prepare(directional, plan_render(directional, directional.material))
    assert prepared.ambient is None and prepared.reflected_radiance is None
    assert plan_render(directional, directional.material) == RenderPlan(reflect=False, transmit=False)


def test_perspective_camera_sees_the_sphere_centred():
    extra = ""
    import tomllib

    text = f"""
[camera]
projection = "perspective"
width = 33
height = 33
position = [0.0, 0.0, 5.0]
look_at = [0.0, 0.0, 0.0]
fov_deg = 30.0

{DIRECTIONAL}
{extra}
"""
    scene = parse_scene(tomllib.loads(text), source="p.toml")
    image, mask = sf.render(scene)
    mask = np.asarray(mask)
    # centre pixel looks straight at (0, 0, 1); the sphere's silhouette half-angle is asin(1/5)
    direction = np.array([0.3, 0.5, 1.0]) / np.linalg.norm([0.3, 0.5, 1.0])
    expected = 1.5 * np.asarray(
        sf.shade(scene.material, [0, 0, 1.0], direction, [0, 0, 1.0], light_color=[1.0, 0.9, 0.8])
    )
    np.testing.assert_allclose(np.asarray(image[16, 16]), expected, rtol=1e-10)
    half = math.tan(math.radians(15))
    radius_px = math.tan(math.asin(1 / 5)) / half * 16.5
    ys, xs = np.nonzero(mask)
    assert abs((xs.max() - xs.min() + 1) / 2 - radius_px) <= 1.0
    assert mask[16].sum() == mask[:, 16].sum()


def test_render_in_float32():
    scene = scene_from(DIRECTIONAL)
    image32, _ = sf.render(scene, dtype=jnp.float32)
    image64, _ = sf.render(scene)
    assert image32.dtype == jnp.float32 and image64.dtype == jnp.float64
    np.testing.assert_allclose(np.asarray(image32), np.asarray(image64), atol=1e-5)


def test_light_intensities_are_differentiable_through_render():
    import jax

    scene = scene_from(DIRECTIONAL, width=8, height=8)

    def total(intensity):
        lights = scene.lights.with_intensities({"directional": intensity})
        image, _ = sf.render(eqx.tree_at(lambda s: s.lights, scene, lights))
        return jnp.sum(image)

    g = jax.grad(total)(jnp.array([1.5]))
    # the image is linear in the intensity: d(sum)/dI = sum / I
    np.testing.assert_allclose(float(g[0]), float(total(jnp.array([1.5]))) / 1.5, rtol=1e-12)


def test_a_plan_made_without_the_material_does_not_trace_transmission_of_an_opaque_one(monkeypatch):
    # plan_render(scene) plans transmission in case the material is transparent; rendering an
    # opaque one with that plan traced the global model for nothing (twice the time)
    from strauss_fit.rendering import strauss

    scene = scene_from(DIRECTIONAL, background='[background]\nkind = "checkerboard"', extra="[render]\ndepth = 4")
    plan = plan_render(scene)
    assert plan == RenderPlan(reflect=True, transmit=True)
    with sf.float64():  # the global model traced in full, as the plan said before
        reference, _ = strauss.render_jit(scene, scene.material, plan, "exact", 64, jnp.float64)
    used = []
    real = strauss.render_jit
    monkeypatch.setattr(
        strauss,
        "render_jit",
        lambda scene, material, plan, *rest: used.append(plan) or real(scene, material, plan, *rest),
    )
    image, _ = sf.render(scene, plan=plan)
    assert used == [RenderPlan(reflect=True, transmit=False)]
    np.testing.assert_array_equal(np.asarray(image), np.asarray(reference))
    transparent = eqx.tree_at(lambda m: m.transparency, scene.material, jnp.asarray(0.5))
    sf.render(scene, transparent, plan=plan)
    assert used[-1] == plan  # a transparent material keeps the plan's transmission
