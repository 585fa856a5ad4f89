"""Directional-hemispherical reflectance (albedo) against closed forms and brute force."""

import jax.numpy as jnp
import numpy as np
import pytest

from strauss_fit.models.albedo import phong_reflectance, strauss_reflectance
from strauss_fit.models.material import Material
from strauss_fit.models.strauss import shade

pytestmark = pytest.mark.usefixtures("x64")

ANGLES = np.array([0.0, 30.0, 60.0, 85.0, 89.5])


def test_lambertian_albedo_matches_the_closed_form():
    # Q = kd Cd cos(alpha): rho = (1 / (pi cos a)) * integral of kd Cd cos(a) cos(theta) = kd Cd
    rho = phong_reflectance(
        [0.7, 0.25], [0.0, 0.0], [10.0, 500.0], [[1.0, 0.5, 0.25], [1.0, 1.0, 1.0]], np.ones((2, 3)), ANGLES
    )
    np.testing.assert_allclose(rho[0], np.tile([0.7, 0.35, 0.175], (ANGLES.size, 1)), atol=1e-4)
    np.testing.assert_allclose(rho[1], 0.25, atol=1e-4)
    # Strauss at normal incidence: F(0) = 0 so j = 0, and s = 0 has no lobe: rho = C exactly
    strauss = strauss_reflectance([[0.9, 0.5, 0.2]], [0.0], [0.0], [0.0], [0.0])
    np.testing.assert_allclose(strauss[0, 0], [0.9, 0.5, 0.2], atol=1e-4)


@pytest.mark.parametrize("n", [0.0, 1.0, 10.0, 1000.0, 10000.0])
def test_phong_lobe_at_normal_incidence_matches_the_closed_form(n):
    # integral of cos^n(beta) cos(theta) over the hemisphere with R = N is 2 pi / (n + 2)
    rho = phong_reflectance([0.0], [1.0], [n], [[1.0, 1.0, 1.0]], [[1.0, 1.0, 1.0]], [0.0])
    assert rho[0, 0, 0] == pytest.approx(2 / (n + 2), rel=1e-4)


def brute_force(q_of_directions, alpha_deg, count=700):
    """(1 / (pi cos a)) * sum of Q cos(theta) dOmega on a midpoint grid over the hemisphere."""
    a = np.radians(alpha_deg)
    theta = (np.arange(count) + 0.5) / count * np.pi / 2
    phi = (np.arange(2 * count) + 0.5) / (2 * count) * 2 * np.pi
    t, p = np.meshgrid(theta, phi, indexing="ij")
    view = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)
    light = np.array([np.sin(a), 0.0, np.cos(a)])
    q = q_of_directions(light, view)
    d_omega = np.sin(t) * (np.pi / 2 / count) * (np.pi / count)
    return np.sum(q * (np.cos(t) * d_omega)[..., None], axis=(0, 1)) / (np.pi * np.cos(a))


def test_oblique_phong_lobe_matches_brute_force():
    def q(light, view):
        r = 2 * light[2] * np.array([0.0, 0.0, 1.0]) - light
        return np.clip(view @ r, 0, 1)[..., None] ** 5 * np.ones(3)

    for alpha in (40.0, 75.0):
        expected = brute_force(q, alpha)
        got = phong_reflectance([0.0], [1.0], [5.0], [[1.0] * 3], [[1.0] * 3], [alpha])[0, 0]
        np.testing.assert_allclose(got, expected, rtol=2e-4)


def test_strauss_albedo_integrates_the_model_evaluator():
    material = Material(color=(0.9, 0.5, 0.2), smoothness=0.4, metalness=0.3, transparency=0.2)

    def q(light, view):
        normal = jnp.array([0.0, 0.0, 1.0])
        return np.asarray(shade(material, normal, jnp.asarray(light), jnp.asarray(view)))

    for alpha in (20.0, 70.0):
        expected = brute_force(q, alpha, count=500)
        got = strauss_reflectance([[0.9, 0.5, 0.2]], [0.4], [0.3], [0.2], [alpha])[0, 0]
        np.testing.assert_allclose(got, expected, rtol=5e-4)


def test_energy_creation_by_hand():
    # Phong kd = ks = 1, n = 1, white: rho(0) = 1 + 2/3
    rho = phong_reflectance([1.0], [1.0], [1.0], [[1.0] * 3], [[1.0] * 3], [0.0])
    assert rho[0, 0, 0] == pytest.approx(5 / 3, rel=1e-5)
    # a white matte Strauss surface reflects exactly 1 head-on and more at oblique incidence (k_j j)
    white = strauss_reflectance([[1.0] * 3], [0.0], [0.0], [0.0], [0.0, 60.0])[0, :, 0]
    assert white[0] == pytest.approx(1.0, abs=1e-6) and white[1] > 1.001
