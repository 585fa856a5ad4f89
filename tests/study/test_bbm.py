"""bbm's NganCookTorrance BRDF (the MERL fits of Ngan et al. 2005): a value worked out by
hand, reciprocity, and the radiance convention of its sphere images."""

import math

import numpy as np
import pytest

from strauss_fit.scene.loading import parse_scene
from strauss_fit.study._bbm import NganMaterial, beckmann, brdf, render_material


def _unit(theta_deg: float, phi_deg: float = 0.0) -> np.ndarray:
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


def test_a_value_worked_out_by_hand():
    # light along the normal, eye 70° off it: the half vector lies 35° from the normal and
    # 35° from both directions. With m = 0.5, F0 = 0.1, kd = 0.2, ks = 0.3:
    #   D = exp(-tan²35° / 0.25) / (π · 0.25 · cos⁴35°) = 0.39785978...
    #   G = min(1, 2 cos35° cos0° / cos35°, 2 cos35° cos70° / cos35°) = 2 cos70° = 0.68404028...
    #   F = 0.1 + 0.9 (1 - cos35°)^5 = 0.10017410...
    #   f = 0.2/π + 0.3 D G F / (π · 1 · cos70°) = 0.0712737687...
    material = NganMaterial("hand", (0.2, 0.2, 0.2), (0.3, 0.3, 0.3), 0.1, 0.5)
    f = brdf(material, np.array([0.0, 0.0, 1.0]), _unit(0.0), _unit(70.0))
    np.testing.assert_allclose(f, 0.0712737687743586, rtol=1e-12)
    # the Beckmann distribution is normalised: ∫ D cos θ_h dω_h = 1 (bbm's Normalize = true)
    theta = np.linspace(0.0, math.pi / 2, 200001)
    for m in (0.05, 0.3):
        integrand = beckmann(np.cos(theta), m) * np.cos(theta) * np.sin(theta) * 2 * math.pi
        integral = float(np.sum((integrand[1:] + integrand[:-1]) / 2 * np.diff(theta)))  # trapezoid rule
        assert integral == pytest.approx(1.0, abs=1e-4)


def test_the_specular_albedo_and_f0_scale_the_lobe_and_the_diffuse_term_is_kd_over_pi():
    normal = np.array([0.0, 0.0, 1.0])
    to_light, to_eye = _unit(30.0, 0.0), _unit(30.0, 180.0)  # mirror configuration: h = n
    matte = NganMaterial("matte", (0.5, 0.25, 0.1), (0.0, 0.0, 0.0), 0.05, 0.2)
    np.testing.assert_allclose(brdf(matte, normal, to_light, to_eye), np.array([0.5, 0.25, 0.1]) / math.pi)
    glossy = NganMaterial("glossy", (0.0, 0.0, 0.0), (1.0, 0.5, 0.0), 1.0, 0.1)
    # at h = n: D = 1/(π m²), G = 1, F = 1 (F0 = 1): f = ks / (π² m² cos²30°)
    expected = np.array([1.0, 0.5, 0.0]) / (math.pi**2 * 0.01 * math.cos(math.radians(30)) ** 2)
    np.testing.assert_allclose(brdf(glossy, normal, to_light, to_eye), expected, rtol=1e-12)
    # below the horizon nothing is reflected
    assert np.all(brdf(glossy, normal, _unit(100.0), to_eye) == 0)


def test_reciprocity():
    rng = np.random.default_rng(26)
    material = NganMaterial("any", (0.1, 0.2, 0.3), (0.4, 0.3, 0.2), 0.3, 0.25)
    normal = np.array([0.0, 0.0, 1.0])
    a = np.stack([_unit(t, p) for t, p in zip(rng.uniform(0, 89, 500), rng.uniform(0, 360, 500))])
    b = np.stack([_unit(t, p) for t, p in zip(rng.uniform(0, 89, 500), rng.uniform(0, 360, 500))])
    forward, backward = brdf(material, normal, a, b), brdf(material, normal, b, a)
    assert np.all(forward > 0)
    np.testing.assert_allclose(forward, backward, rtol=1e-12)


def test_a_white_lambertian_sphere_shows_the_projects_radiance_convention():
    """π f_r cos θ_i I: a white Lambertian (kd = 1) under a light of intensity 0.7 shows
    0.7 cos θ_i (the mean over each pixel's footprint), plus ambient A · kd."""
    scene = parse_scene(
        {
            "camera": {"projection": "orthographic", "width": 16, "height": 16},
            "light": [
                {"kind": "directional", "direction": [0.0, 0.0, 1.0], "intensity": 0.7},
                {"kind": "ambient", "intensity": 0.05},
            ],
        }
    )
    white = NganMaterial("white", (1.0, 1.0, 1.0), (0.0, 0.0, 0.0), 0.05, 0.2)
    image, usable = render_material(white, scene, supersample=16)
    assert usable.sum() > 100 and np.all(image[~usable] == 0)
    rows, cols = np.nonzero(usable)
    x = (cols + 0.5) / 16 * 2 - 1
    y = 1 - (rows + 0.5) / 16 * 2
    cos = np.sqrt(1 - x**2 - y**2)  # the light is along the view axis: cos θ_i = n_z
    # the pixel mean of n_z differs from its centre value by the curvature, O(pixel²)
    np.testing.assert_allclose(image[usable][:, 0], 0.7 * cos + 0.05, atol=0.02)
    np.testing.assert_allclose(image[usable][:, 0], image[usable][:, 2])
