"""The global model: reflection, refraction and transmission against closed forms."""

import math
import tomllib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import strauss_fit as sf
from strauss_fit.models.strauss import K_F, K_G, K_J
from strauss_fit.rendering.strauss import RenderPlan, refract, render
from strauss_fit.scene.background import background_radiance
from strauss_fit.scene.camera import Rays, intersect_unit_sphere
from strauss_fit.scene.loading import parse_scene

pytestmark = pytest.mark.usefixtures("x64")

CHECKER = """
[background]
kind = "checkerboard"
point = [0.0, 0.0, -3.0]
square_size = 0.4
colors = [[0.9, 0.8, 0.2], [0.1, 0.2, 0.6]]
color = [0.05, 0.05, 0.05]
"""


def scene(material, lights='[[light]]\nkind = "ambient"\nintensity = 0.0', background=CHECKER, size=33, depth=4):
    text = f"""
[camera]
width = {size}
height = {size}
[material]
{material}
{lights}
{background}
[render]
depth = {depth}
"""
    return parse_scene(tomllib.loads(text), source="test.toml")


def trace_through(b, n):
    """A ray along -z at impact parameter b, refracted into and out of the sphere."""
    origin = jnp.array([[b, 0.0, 2.0]])
    direction = jnp.array([[0.0, 0.0, -1.0]])
    entry = intersect_unit_sphere(Rays(origin, direction)).point
    inside, total_in = refract(direction, entry, jnp.array([1.0 / n]))
    inside = inside / jnp.linalg.norm(inside, axis=-1, keepdims=True)
    exit_point = intersect_unit_sphere(Rays(entry, inside), from_inside=True).point
    out, total_out = refract(inside, -exit_point, jnp.array([n]))
    assert not bool(total_in[0]) and not bool(total_out[0])
    return np.asarray(entry[0]), np.asarray(exit_point[0]), np.asarray(out[0])


def test_ray_through_the_centre_is_undeviated():
    entry, exit_point, out = trace_through(0.0, 1.5)
    np.testing.assert_allclose(entry, [0, 0, 1], atol=1e-15)
    np.testing.assert_allclose(exit_point, [0, 0, -1], atol=1e-15)
    np.testing.assert_allclose(out, [0, 0, -1], atol=1e-15)


@pytest.mark.parametrize("b", [0.1, 0.4, 0.7, 0.95])
@pytest.mark.parametrize("n", [1.2, 1.5, 2.4])
def test_deviation_after_two_refractions(b, n):
    _, _, out = trace_through(b, n)
    theta_i = math.asin(b)
    theta_r = math.asin(b / n)
    deviation = math.acos(float(np.clip(np.dot(out, [0, 0, -1.0]) / np.linalg.norm(out), -1, 1)))
    assert deviation == pytest.approx(2 * (theta_i - theta_r), abs=1e-9)
    assert np.linalg.norm(out) == pytest.approx(1.0, abs=1e-12)  # Snell's T is a unit vector
    assert out[0] < 0  # a converging lens bends the ray toward the axis


@pytest.mark.parametrize("n", [1.33, 1.5, 2.0])
def test_critical_angle_of_total_internal_reflection(n):
    normal = jnp.array([0.0, 0.0, 1.0])

    def total_at(angle):
        direction = jnp.array([math.sin(angle), 0.0, -math.cos(angle)])  # travelling toward the surface
        return bool(refract(direction, normal, jnp.asarray(n))[1])

    low, high = 0.0, math.pi / 2
    assert not total_at(low) and total_at(high - 1e-12)
    for _ in range(60):
        mid = (low + high) / 2
        low, high = (low, mid) if total_at(mid) else (mid, high)
    assert high == pytest.approx(math.asin(1 / n), abs=1e-6)


def test_snell_law_holds_for_the_refracted_direction():
    normal = jnp.array([0.0, 0.0, 1.0])
    for angle in (0.1, 0.5, 1.0, 1.4):
        direction = jnp.array([math.sin(angle), 0.0, -math.cos(angle)])
        t, total = refract(direction, normal, jnp.asarray(1 / 1.5))
        sin_out = float(jnp.linalg.norm(jnp.cross(t, -normal)))
        assert sin_out == pytest.approx(math.sin(angle) / 1.5, rel=1e-12)


def F(x):
    return ((x - K_F) ** -2 - K_F**-2) / ((1 - K_F) ** -2 - K_F**-2)


def G(x):
    return ((1 - K_G) ** -2 - (x - K_G) ** -2) / ((1 - K_G) ** -2 - K_G**-2)


def test_index_one_leaves_the_background_behind_a_transparent_sphere_in_place():
    # t = 1, s = 0, m = 0, C = white, n = 1, no light: only the surface terms (reflection
    # weights) change what is seen; the transmitted rays pass undeviated.
    sc = scene("color = [1.0, 1.0, 1.0]\nsmoothness = 0.0\nmetalness = 0.0\ntransparency = 1.0\nior = 1.0", depth=2)
    image, mask = render(sc)
    image, mask = np.asarray(image), np.asarray(mask)
    size = 33
    checked = 0
    for i in range(0, size, 3):
        for k in range(0, size, 3):
            if not mask[i, k]:
                continue
            x = (k + 0.5) / size * 2 - 1
            y = 1 - (i + 0.5) / size * 2
            z = math.sqrt(1 - x * x - y * y)
            xg = 2 * math.acos(z) / math.pi  # angle of view at entry = angle at exit (n = 1)
            j = F(xg) * G(xg) ** 2
            r = min(1.0, j * K_J)  # r_n = 0 for t = 1
            weight = 1 - r  # z = t (1 - r_s) / (1 - r_n)
            straight = background_radiance(sc.background, Rays(jnp.array([x, y, 2.0]), jnp.array([0.0, 0.0, -1.0])))
            normal = np.array([x, y, z])
            mirror = 2 * z * normal - np.array([0, 0, 1.0])
            reflected = background_radiance(sc.background, Rays(jnp.asarray(normal), jnp.asarray(mirror)))
            exit_point = np.array([x, y, -z])
            internal = np.array([0, 0, -1.0]) - 2 * np.dot([0, 0, -1.0], -exit_point) * -exit_point
            left_inside = background_radiance(sc.background, Rays(jnp.asarray(exit_point), jnp.asarray(internal)))
            expected = r * np.asarray(reflected) + weight * (
                weight * np.asarray(straight) + r * np.asarray(left_inside)
            )
            np.testing.assert_allclose(image[i, k], expected, rtol=1e-10, atol=1e-12)
            checked += 1
    assert checked > 50


def test_glass_sphere_inverts_the_background():
    # Left half of the board bright, right half dark: seen through a real lens (plane beyond
    # the focal length) the sphere's centre region shows the sides swapped.
    background = """
[background]
kind = "checkerboard"
point = [0.0, 50.0, -6.0]
square_size = 100.0
colors = [[1.0, 1.0, 1.0], [0.0, 0.0, 0.0]]
sharpness = 50.0
"""
    sc = scene(
        "color = [1.0, 1.0, 1.0]\nsmoothness = 0.9\ntransparency = 1.0\nior = 1.5", background=background, size=65
    )
    image, mask = render(sc)
    lum = np.asarray(image).mean(axis=-1)
    plain, _ = render(
        scene(
            "color = [1.0, 1.0, 1.0]\nsmoothness = 0.9\ntransparency = 1.0\nior = 1.0", background=background, size=65
        )
    )
    plain = np.asarray(plain).mean(axis=-1)
    # The board's u axis is x and u = 0 a square edge (v sits mid-square), so without the
    # lens the board is bright on one side of x = 0 and dark on the other; the lens swaps them.
    left, right = (28, 20), (28, 44)
    assert (plain[left] - plain[right]) * (lum[left] - lum[right]) < 0
    assert abs(lum[left] - lum[right]) > 0.3


def test_opaque_material_gives_exactly_the_local_image():
    material = "color = [0.7, 0.4, 0.2]\nsmoothness = 0.7\nmetalness = 0.5\ntransparency = 0.0\nior = 1.5"
    lights = '[[light]]\nkind = "directional"\ndirection = [0.2, 0.4, 1.0]\nintensity = 1.0'
    black = "[background]\ncolor = [0.0, 0.0, 0.0]"
    sc = scene(material, lights, background=black)
    local, _ = render(sc, plan=RenderPlan(False, False))
    # forcing the transmitted ray through the whole machinery adds exactly nothing at t = 0
    traced, _ = render(sc, plan=RenderPlan(True, True))
    np.testing.assert_array_equal(np.asarray(traced), np.asarray(local))
    assert sf.plan_render(sc, sc.material) == RenderPlan(False, False)


def test_depth_one_is_the_local_model():
    sc = scene("color = [1.0, 1.0, 1.0]\nsmoothness = 0.9\ntransparency = 0.8", depth=1)
    assert sf.plan_render(sc, sc.material) == RenderPlan(False, False)


def test_mirror_reflects_the_background():
    # s = 1, t = 0, m = 0: r_n = 1, so the sphere is a perfect white mirror of the board.
    sc = scene(
        "color = [1.0, 1.0, 1.0]\nsmoothness = 1.0\nmetalness = 0.0\ntransparency = 0.0",
        depth=2,
        background="[background]\ncolor = [0.3, 0.5, 0.7]",
    )
    image, mask = render(sc)
    inside = np.asarray(image)[np.asarray(mask)]
    np.testing.assert_allclose(inside, np.tile([0.3, 0.5, 0.7], (inside.shape[0], 1)), atol=1e-12)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
@pytest.mark.parametrize("ior", [1.0, 1.5, 3.0])
def test_values_and_gradients_finite_through_the_global_model(dtype, ior):
    sc = scene(
        "color = [0.8, 0.9, 1.0]\nsmoothness = 0.5\ntransparency = 0.7",
        lights='[[light]]\nkind = "directional"\ndirection = [0.0, 0.0, 1.0]\nintensity = 1.0',
        size=41,
    )
    base = sf.Material(color=(0.8, 0.9, 1.0), smoothness=0.5, transparency=0.7, ior=ior)
    plan = RenderPlan(True, True)

    def total(material):
        image, _ = render(sc, material, dtype=dtype, plan=plan)
        return jnp.sum(image)

    for s, t in [(0.0, 1.0), (1.0, 1.0), (0.5, 0.0), (1 - 1e-6, 1e-6)]:
        material = sf.Material(color=(0.8, 0.9, 1.0), smoothness=s, transparency=t, ior=ior, dtype=dtype)
        value, grads = jax.value_and_grad(total)(material)
        assert np.isfinite(float(value))
        for leaf in jax.tree_util.tree_leaves(grads):
            assert np.all(np.isfinite(np.asarray(leaf))), (s, t, ior)
    assert base.ior == ior


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_refraction_gradient_finite_at_the_critical_angle_and_grazing(dtype):
    n = 1.5
    critical = math.asin(1 / n)
    normal = jnp.array([0.0, 0.0, 1.0], dtype=dtype)
    for angle in (critical, critical - 1e-7, critical + 1e-7, math.pi / 2, 0.0):
        direction = jnp.array([math.sin(angle), 0.0, -math.cos(angle)], dtype=dtype)
        g = jax.jacobian(lambda ior: refract(direction, normal, ior)[0])(jnp.asarray(n, dtype=dtype))  # noqa: B023
        assert np.all(np.isfinite(np.asarray(g))), angle


def test_checkerboard_fades_to_its_mean_towards_the_horizon_with_bounded_gradient():
    # A ray from z = 0 towards the plane z = -2 at a shrinking angle above it: the squares
    # per radian of direction (h / (size cos^2)) grow without bound, and so would
    # the pattern's derivative; the fade keeps the radiance and its gradient bounded and
    # leaves views of the board well above the horizon unchanged.
    from strauss_fit.scene.background import HORIZON_FADE, Background

    board = Background(kind="checkerboard", colors=jnp.array([[0.9, 0.8, 0.3], [0.1, 0.2, 0.6]]))
    mean = 0.5 * (np.array([0.9, 0.8, 0.3]) + np.array([0.1, 0.2, 0.6]))

    def radiance(angle):
        direction = jnp.stack([jnp.cos(angle), 0.0 * angle, -jnp.sin(angle)])
        return background_radiance(board, Rays(jnp.array([0.0, 0.0, 0.0]), direction))

    for angle in (1e-2, 1e-3, 1e-5):  # 1e-2 rad: 4e4 squares per radian (faded above 300)
        np.testing.assert_allclose(np.asarray(radiance(jnp.asarray(angle))), mean, atol=1e-12)
    slopes = [float(jnp.max(jnp.abs(jax.jacfwd(radiance)(jnp.asarray(a))))) for a in np.geomspace(1e-4, 0.5, 200)]
    assert np.all(np.isfinite(slopes)) and max(slopes) < 20 * np.pi * 2 * HORIZON_FADE
    # straight down (2 / 0.5 = 4 squares per radian) the board is the plain pattern (to (4/100)^8)
    straight = background_radiance(board, Rays(jnp.array([0.3, 0.1, 0.0]), jnp.array([0.0, 0.0, -1.0])))
    u, v = 0.3 / 0.5, 0.1 / 0.5
    weight = 0.5 + 0.5 * np.tanh(20.0 * np.sin(np.pi * u) * np.sin(np.pi * v))
    expected = np.array([0.1, 0.2, 0.6]) + weight * (np.array([0.9, 0.8, 0.3]) - np.array([0.1, 0.2, 0.6]))
    np.testing.assert_allclose(np.asarray(straight), expected, rtol=0, atol=1e-10)
    # a plane through the origin (h = 0) is not faded at all
    through = Background(
        kind="checkerboard", point=jnp.array([0.0, 0.0, 0.0]), colors=jnp.array([[0.9, 0.8, 0.3], [0.1, 0.2, 0.6]])
    )
    seen = background_radiance(through, Rays(jnp.array([0.3, 0.1, 1.0]), jnp.array([0.0, 0.0, -1.0])))
    np.testing.assert_allclose(np.asarray(seen), expected, rtol=0, atol=1e-12)
