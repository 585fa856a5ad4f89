"""Numerical stability of rendering at the extremes (issue 8, part 3; the extremes and the
rules are in ``tests/models/test_shade_stability.py``): a transparent sphere over a
checkerboard at depth 2 keeps finite values and gradients, float32 agrees with float64
inside the rim (:data:`RENDER_F32_ATOL`, :data:`RENDER_F32_ATOL_N3`), total internal
reflection keeps the light, and rendering is linear in the light intensities."""

from __future__ import annotations

import functools
import math
import tomllib

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import strauss_fit as sf
from strauss_fit.rendering.strauss import RenderPlan, interior_radiance, refract, render
from strauss_fit.scene.loading import parse_scene
from support import DTYPES, GRAZING, GRID, PROPERTY, UP, assert_all_finite, materials

pytestmark = pytest.mark.usefixtures("x64")

RENDER_F32_ATOL = 5e-4
RENDER_F32_ATOL_N3 = 1e-2


# --- 3. rendering: a transparent sphere over a checkerboard, depth 2 ---------------------

_G = math.radians(GRAZING)
RENDER_SCENE = f"""
[camera]
width = 24
height = 24
[[light]]
kind = "directional"
direction = [0.0, 0.0, 1.0]
intensity = 1.0
[[light]]
kind = "directional"
direction = [{math.sin(_G)!r}, 0.0, {math.cos(_G)!r}]
intensity = 1.0
[[light]]
kind = "directional"
direction = [0.0, 1.0, 0.0]
intensity = 1.0
[[light]]
kind = "directional"
direction = [0.3, 0.2, -1.0]
intensity = 1.0
[[light]]
kind = "point"
position = [0.5, 2.0, 1.0]
intensity = 1.0
attenuation = [1.0, 0.5, 0.25]
[[light]]
kind = "ambient"
intensity = 1.0
[background]
kind = "checkerboard"
point = [0.0, 0.0, -3.0]
square_size = 0.5
colors = [[0.9, 0.8, 0.3], [0.1, 0.2, 0.6]]
sharpness = 20.0
[render]
depth = 2
"""
# Lights: frontal, grazing (90° - 1e-6° from the view axis), exactly perpendicular,
# from behind (N·L < 0 on most of the visible half), a point light, ambient.


@functools.cache
def _render_scene():
    return parse_scene(tomllib.loads(RENDER_SCENE), source="stability")


@functools.cache
def _render_grid_function(dtype):
    scene = _render_scene()
    plan = RenderPlan(reflect=True, transmit=True)  # trace everything, even where t = 0

    def total(color, s, m, t, n, directional, point, ambient):
        material = sf.Material(color=color, smoothness=s, metalness=m, transparency=t, ior=n)
        lights = scene.lights.with_intensities({"directional": directional, "point": point, "ambient": ambient})
        image, _ = render(eqx.tree_at(lambda q: q.lights, scene, lights), material, dtype=dtype, plan=plan)
        return jnp.sum(image * jnp.linspace(1.0, 2.0, image.size, dtype=dtype).reshape(image.shape)), image

    value_and_grad = jax.value_and_grad(total, argnums=tuple(range(8)), has_aux=True)
    return jax.jit(jax.vmap(value_and_grad, in_axes=(None, 0, 0, 0, None, None, None, None)))


@functools.cache
def _render_grid(dtype, n: float, intensity: float):
    """Images (125, 24, 24, 3) and gradients over :data:`GRID` (cached across tests)."""
    f = _render_grid_function(dtype)
    dt = dtype
    (total, image), grads = f(
        jnp.asarray([0.2, 0.5, 0.9], dt),
        *(jnp.asarray(GRID[:, k], dt) for k in range(3)),
        jnp.asarray(n, dt),
        jnp.full(4, intensity, dt),
        jnp.full(1, intensity, dt),
        jnp.asarray(intensity, dt),
    )
    return np.asarray(total), np.asarray(image), [np.asarray(g) for g in grads]


@pytest.mark.parametrize("dtype", DTYPES, ids=lambda d: jnp.dtype(d).name)
@pytest.mark.parametrize("n", [1.0, 1.5, 3.0])
def test_render_values_and_gradients_finite_at_the_extremes(dtype, n):
    for intensity in (0.0, 1.0, 1e6):
        total, image, grads = _render_grid(dtype, n, intensity)
        assert image.dtype == dtype and image.shape == (len(GRID), 24, 24, 3)
        assert_all_finite((total, image), f"render values (n={n}, I={intensity})")
        names = ("color", "s", "m", "t", "n", "directional", "point", "ambient")
        for name, g in zip(names, grads):
            assert_all_finite(g, f"render gradient in {name} (n={n}, I={intensity}, {jnp.dtype(dtype).name})")


def _inner_sphere_pixels() -> np.ndarray:
    """The sphere's pixels whose 8 neighbours are all on the sphere (the outer ring dropped)."""
    size = 24  # pixel centres of shared/formats.md; the sphere where x² + y² < 1
    x = (np.arange(size) + 0.5) / size * 2 - 1
    hit = (x[None, :] ** 2 + x[:, None] ** 2) < 1
    padded = np.pad(hit, 1)
    inner = hit.copy()
    for di in (-1, 0, 1):
        for dk in (-1, 0, 1):
            inner &= padded[1 + di : 1 + di + hit.shape[0], 1 + dk : 1 + dk + hit.shape[1]]
    return inner


@pytest.mark.parametrize("n,atol", [(1.0, RENDER_F32_ATOL), (1.5, RENDER_F32_ATOL), (3.0, RENDER_F32_ATOL_N3)])
def test_render_float32_agrees_with_float64_inside_the_rim(n, atol):
    inner = _inner_sphere_pixels()
    assert 300 < inner.sum() < np.pi * 144  # 24 px: 448 sphere pixels, 356 inside the ring
    away = GRID[:, 0] <= 0.99
    _, image32, _ = _render_grid(jnp.float32, n, 1.0)
    _, image64, _ = _render_grid(jnp.float64, n, 1.0)
    error = np.abs(image32.astype(np.float64) - image64)[away][:, inner]
    assert float(error.max()) <= atol, float(error.max())


@pytest.mark.parametrize("dtype", DTYPES, ids=lambda d: jnp.dtype(d).name)
def test_total_internal_reflection_inside_the_sphere_is_finite_and_keeps_the_light(dtype):
    # Chords from the top of the sphere at internal angles around and beyond the critical
    # angle arcsin(1/n): at the exit every ray beyond it is totally reflected.
    n = 1.5
    critical = math.asin(1 / n)
    angles = np.array([0.0, critical - 1e-3, critical, critical + 1e-7, critical + 1e-3, 1.2, math.pi / 2 - 1e-6])
    origin = jnp.asarray(np.tile(UP, (angles.size, 1)), dtype=dtype)
    direction = jnp.asarray(np.stack([np.sin(angles), np.zeros_like(angles), -np.cos(angles)], -1), dtype=dtype)
    background = _render_scene().background

    def total(color, s, m, t, ior):
        material = sf.Material(color=color, smoothness=s, metalness=m, transparency=t, ior=ior)
        out = interior_radiance(material, background, origin, direction, 2)
        return jnp.sum(out), out

    f = jax.jit(
        jax.vmap(jax.value_and_grad(total, argnums=(0, 1, 2, 3, 4), has_aux=True), in_axes=(None, 0, 0, 0, None))
    )
    s, m, t = (
        jnp.asarray(v, dtype)
        for v in zip((0.0, 0.0, 1.0), (0.5, 0.5, 0.5), (1 - 1e-6, 1.0, 1e-6), (1.0, 0.0, 1.0), (1.0, 1.0, 0.0))
    )
    (_, out), grads = f(jnp.asarray((0.2, 0.5, 0.9), dtype), s, m, t, jnp.asarray(n, dtype))
    assert_all_finite(out, "interior radiance")
    assert_all_finite(grads, "interior gradients")
    # the exit's weights never create light (reflected + transmitted share ≤ 1), so no ray
    # carries more than the brightest background colour
    assert float(jnp.max(out)) <= 0.9 + 1e-5
    inward = -jnp.asarray(np.stack([np.sin(2 * angles), np.zeros_like(angles), -np.cos(2 * angles)], -1), dtype=dtype)
    _, total = refract(direction, inward, jnp.full(angles.size, n, dtype=dtype))
    assert not bool(total[0]) and not bool(total[1]) and bool(total[-1]) and bool(total[-2])


LINEAR_SCENE = """
[camera]
width = 8
height = 8
[[light]]
kind = "directional"
direction = [0.3, 0.5, 1.0]
intensity = 1.0
[[light]]
kind = "directional"
direction = [-0.9, 0.1, 0.2]
intensity = 1.0
[[light]]
kind = "point"
position = [1.0, -1.5, 2.0]
intensity = 1.0
attenuation = [0.5, 0.3, 0.2]
[[light]]
kind = "ambient"
intensity = 1.0
[render]
depth = 1
"""


@functools.cache
def _linear_render():
    scene = parse_scene(tomllib.loads(LINEAR_SCENE), source="linear")

    def image(color, s, m, t, intensities):
        material = sf.Material(color=color, smoothness=s, metalness=m, transparency=t)
        lights = scene.lights.with_intensities(
            {"directional": intensities[:2], "point": intensities[2:3], "ambient": intensities[3]}
        )
        return render(
            eqx.tree_at(lambda q: q.lights, scene, lights), material, dtype=jnp.float64, plan=RenderPlan(False, False)
        )[0]

    return jax.jit(image)


intensity_vectors = st.lists(st.floats(0.0, 1e6, allow_nan=False), min_size=4, max_size=4)


@PROPERTY
@given(material=materials, first=intensity_vectors, second=intensity_vectors, scale=st.floats(0.0, 1e3))
def test_rendering_is_linear_in_the_light_intensities(material, first, second, scale):
    f = _linear_render()
    args = tuple(jnp.asarray(material[k]) for k in ("color", "smoothness", "metalness", "transparency"))
    a, b = np.asarray(first), np.asarray(second)
    image_a, image_b = np.asarray(f(*args, jnp.asarray(a))), np.asarray(f(*args, jnp.asarray(b)))
    image_sum = np.asarray(f(*args, jnp.asarray(a + b)))
    image_scaled = np.asarray(f(*args, jnp.asarray(scale * a)))
    assert np.all(np.isfinite(image_sum)) and np.all(image_a >= 0)
    # atol: relative to the image's largest value, plus 1e-300 for products that underflow
    np.testing.assert_allclose(
        image_sum, image_a + image_b, rtol=1e-12, atol=1e-12 * float(image_a.max() + image_b.max()) + 1e-300
    )
    np.testing.assert_allclose(
        image_scaled, scale * image_a, rtol=1e-12, atol=1e-12 * scale * float(image_a.max()) + 1e-300
    )
    assert np.all(np.asarray(f(*args, jnp.zeros(4))) == 0)
