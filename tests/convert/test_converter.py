"""Phong <-> Strauss conversion: closed-form guesses by hand, round trips within the reported
residual, batches that survive bad materials, and the entry points (the material tables:
tests/io/test_material_tables.py; the commands: tests/cli/test_cli_convert.py)."""

import math
import tomllib

import numpy as np
import pytest

from strauss_fit.color import delta_e_2000
from strauss_fit.convert.converter import Converter, Entry, Settings, conversion_scene, phong_guess, strauss_guess
from strauss_fit.convert.phong_fit import LOG_MAX_EXPONENT, phong_problem, vector_from_material
from strauss_fit.fitting.problem import render_at
from strauss_fit.models.material import Material
from strauss_fit.models.phong import PhongMaterial, highlight_power
from strauss_fit.models.strauss import highlight_falloff
from strauss_fit.rendering.phong import render_phong
from strauss_fit.scene.loading import parse_scene

pytestmark = pytest.mark.usefixtures("x64")

SIZE = 24  # the study's tests use the same size, so compiled solvers are shared


@pytest.fixture(scope="module")
def converter():
    return Converter(conversion_scene(size=SIZE), Settings())


def rms(a, b):
    return float(np.sqrt(np.mean((np.asarray(a) - np.asarray(b)) ** 2)))


# --- closed-form guesses ------------------------------------------------------------------------


@pytest.mark.parametrize("n", [3.5, 10.0, 30.0, 250.0, 1000.0, 9999.0])
def test_guess_recovers_s_exactly_for_a_pure_specular_lobe(n):
    guess, notes = strauss_guess(PhongMaterial(ka=0.0, kd=0.0, ks=1.0, exponent=n))
    assert guess["smoothness"] == 1 - 3 / n  # h = 3 / (1 - s) = n
    assert guess["metalness"] == 0.0 and guess["color"] == [0.0, 0.0, 0.0]  # white lobe, no diffuse term
    cos_beta = np.linspace(0.0, 1.0, 201)
    np.testing.assert_allclose(
        np.asarray(highlight_falloff(cos_beta, guess["smoothness"])),
        np.asarray(highlight_power(cos_beta, n)),
        rtol=1e-9,
        atol=1e-300,
    )


def test_guess_for_blinn_uses_a_quarter_of_the_exponent_and_clips_wide_lobes():
    assert strauss_guess(PhongMaterial(kd=0.0, ks=1.0, exponent=40.0, blinn=True))[0]["smoothness"] == 1 - 12 / 40
    assert strauss_guess(PhongMaterial(kd=0.0, ks=1.0, exponent=2.0))[0]["smoothness"] == 0.0


def test_guess_colour_and_metalness_by_hand():
    # s = 1 - 3/6 = 0.5; D = kd Cd = (0.5, 0.25, 0.125), hue (1, 0.5, 0.25), chroma 0.75;
    # tint = S / max S = (1, 0.75, 0.625) -> m = (1 - 0.625) / 0.75 = 0.5;
    # C = D / ((1 - m s)(1 - s^3)) = D / (0.75 * 0.875) = D / 0.65625
    guess, notes = strauss_guess(
        PhongMaterial(kd=0.5, ks=0.5, exponent=6.0, diffuse_color=(1.0, 0.5, 0.25), specular_color=(1.0, 0.75, 0.625))
    )
    assert guess["smoothness"] == pytest.approx(0.5)
    assert guess["metalness"] == pytest.approx(0.5)
    np.testing.assert_allclose(guess["color"], [0.76190476190, 0.38095238095, 0.19047619048], atol=1e-10)
    assert notes == []
    # no diffuse term and a tinted highlight: a metal of the highlight's colour
    metal, _ = strauss_guess(PhongMaterial(kd=0.0, ks=0.9, exponent=100.0, specular_color=(1.0, 0.8, 0.4)))
    assert metal["metalness"] == 1.0
    np.testing.assert_allclose(metal["color"], [1.0, 0.8, 0.4])
    # a diffuse term brighter than Strauss allows at this smoothness: scaled down, with a note
    bright, notes = strauss_guess(PhongMaterial(kd=1.0, ks=0.5, exponent=30.0))
    np.testing.assert_allclose(bright["color"], [1.0, 1.0, 1.0])
    assert notes and "brighter than Strauss allows" in notes[0]


def test_phong_guess_from_strauss_by_hand():
    # h = 3/(1 - 0.5) = 6; D = (1 - 0.25)(1 - 0.125) C = 0.65625 C; ka = (1 - s^3) max C = 0.7
    vector, ka = phong_guess(Material(color=(0.8, 0.4, 0.2), smoothness=0.5, metalness=0.5))
    np.testing.assert_allclose(vector[:3], [0.525, 0.2625, 0.13125])
    assert vector[6] == pytest.approx(math.log(6.0) / LOG_MAX_EXPONENT)
    assert ka == pytest.approx(0.7)
    assert np.all(vector[3:6] > 0) and vector[3] > vector[5]  # a highlight tinted towards C


# --- the Phong fitter's renderer --------------------------------------------------------------


@pytest.mark.parametrize("blinn", [False, True])
def test_fitter_geometry_renders_like_render_phong(blinn):
    """The fitter renders from angles precomputed per pixel and light
    (:class:`~strauss_fit.convert.phong_fit.PhongGeometry`), summed in another order than
    :func:`render_phong`: the same image to rounding, for Phong and Blinn–Phong, and the
    same Jacobian as rendering from the vectors."""
    scene = parse_scene(
        tomllib.loads("""
[camera]
width = 12
height = 12
[[light]]
kind = "directional"
direction = [0.3, 0.5, 1.0]
intensity = 0.8
color = [1.0, 0.9, 0.8]
[[light]]
kind = "point"
position = [2.0, 1.0, 3.0]
intensity = 5.0
attenuation = [1.0, 0.0, 0.5]
[[light]]
kind = "ambient"
intensity = 0.2
""")
    )
    material = PhongMaterial(
        ka=0.3,
        kd=0.6,
        ks=0.4,
        exponent=12.0,
        diffuse_color=(0.9, 0.5, 0.2),
        specular_color=(1.0, 0.9, 0.7),
        blinn=blinn,
    )
    image, mask = render_phong(scene, material)
    index = np.flatnonzero(np.asarray(mask).ravel())
    problem = phong_problem(scene, index)
    import dataclasses

    import jax
    import jax.numpy as jnp

    from strauss_fit.convert.phong_fit import material_from_vector
    from strauss_fit.models.phong import phong_shade

    # the fitter's ambient term is ka * Cd with Cd = D / max D (here Cd itself, max 0.9 -> scaled)
    x = vector_from_material(material)
    problem = dataclasses.replace(problem, ambient_ka=jnp.asarray(0.3 * 0.9 / 1.0), blinn=blinn)
    model = np.asarray(render_at(problem, jnp.asarray(x)))
    assert np.max(model) > 0.1
    np.testing.assert_allclose(model, np.asarray(image).reshape(-1, 3)[index], atol=1e-12)

    # the Jacobian in D, S and u equals that of the render from vectors (render_phong's code)
    from strauss_fit.scene.camera import intersect_unit_sphere, primary_rays
    from strauss_fit.scene.lights import sample_lights

    scene64 = scene.astype(jnp.float64)
    rays = primary_rays(scene64.camera, jnp.float64)
    hits = intersect_unit_sphere(rays)
    samples = sample_lights(scene64.lights, hits.point)

    def from_vectors(vector):
        phong = material_from_vector(vector, problem.ambient_ka, blinn)
        per_light = phong_shade(
            phong, hits.point[..., None, :], samples.to_light, -rays.direction[..., None, :], samples.color
        )
        radiance = jnp.sum(per_light * samples.irradiance[..., None], axis=-2)
        radiance = radiance + scene64.lights.ambient * problem.ambient_ka * phong.diffuse_color
        return radiance.reshape(-1, 3)[index].ravel()

    expected = jax.jit(jax.jacfwd(from_vectors))(jnp.asarray(x))
    got = jax.jit(jax.jacfwd(lambda v: problem.render_physical(v).ravel()))(jnp.asarray(x))
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-11)


# --- conversions ----------------------------------------------------------------------------


def test_round_trip_reproduces_the_image_within_the_reported_residual(converter):
    source = PhongMaterial(ka=0.0, kd=0.6, ks=0.25, exponent=8.0, diffuse_color=(0.9, 0.45, 0.2))
    forward = converter.phong_to_strauss([Entry("clay", "test", source)])[0]
    assert forward["status"] == "ok", forward
    strauss = Material(**{**forward["strauss"], "transparency": 0.0})
    back = converter.strauss_to_phong([Entry("clay", "test", strauss)])[0]
    assert back["status"] == "ok", back
    original = converter.phong_target(source)
    as_strauss = converter.strauss_target(strauss)
    returned = converter.phong_target(PhongMaterial.from_dict(back["phong"]))
    # the reported residuals are the real ones ...
    assert forward["residual"]["rms"] == pytest.approx(rms(as_strauss, original), rel=1e-9)
    assert back["residual"]["rms"] == pytest.approx(rms(returned, as_strauss), rel=1e-9)
    # ... so the round trip stays within their sum (RMS is a norm)
    assert rms(returned, original) <= forward["residual"]["rms"] + back["residual"]["rms"] + 1e-12
    # and this material is one Strauss can match well
    assert forward["residual"]["delta_e2000_mean"] < 2.0
    assert forward["uncertainty"]["smoothness"] > 0 and len(forward["uncertainty"]["color"]) == 3
    # the fit improves on its closed-form start
    guess_image = converter.strauss_target(Material(**forward["guess"]))
    assert forward["residual"]["rms"] <= rms(guess_image, original) + 1e-12


def test_strauss_to_phong_matches_a_dielectric_closely(converter):
    result = converter.strauss_to_phong([Entry("plastic", "test", Material(color=(0.2, 0.5, 0.8), smoothness=0.5))])[0]
    assert result["status"] == "ok"
    assert result["residual"]["delta_e2000_mean"] < 0.5
    assert result["phong"]["exponent"] == pytest.approx(6.0, rel=0.5)  # h = 3 / (1 - s) = 6 as the start
    assert set(result["uncertainty"]) == {"diffuse", "specular", "exponent"}
    assert result["opacity"] == 1.0 and result["ior"] == 1.5


def test_a_bad_material_is_reported_and_the_batch_goes_on(converter):
    good = PhongMaterial(ka=0.0, kd=0.5, ks=0.3, exponent=12.0, diffuse_color=(0.3, 0.6, 0.9))
    other = PhongMaterial(ka=0.0, kd=0.4, ks=0.5, exponent=5.0, diffuse_color=(0.8, 0.8, 0.2))
    entries = [
        Entry("good", "test", good),
        Entry("unreadable", "test", error="Kd needs 3 numbers"),
        Entry("broken", "test", material=None),
        Entry("other", "test", other),
        Entry("black", "test", PhongMaterial(ka=0.0, kd=0.0, ks=0.0)),
    ]
    seen = []
    results = converter.phong_to_strauss(entries, lambda done, total, message: seen.append((done, total)))
    assert [r["name"] for r in results] == ["good", "unreadable", "broken", "other", "black"]
    assert [r["status"] for r in results] == ["ok", "error", "error", "ok", "ok"]
    assert results[1]["message"] == "Kd needs 3 numbers"
    assert results[2]["message"].startswith("unexpected AttributeError")
    # Phong black: Strauss's darkest material, C = 0, m = 1, s = 0 (only k_j j F is left)
    assert "renders black" in results[4]["notes"][-1]
    assert results[4]["strauss"]["color"] == [0.0, 0.0, 0.0] and results[4]["strauss"]["metalness"] == 1.0
    assert 0 < results[4]["residual"]["rms"] < 1e-3
    assert sorted(seen) == [(k, 5) for k in range(1, 6)]
    alone = converter.phong_to_strauss([Entry("good", "test", good)])[0]
    np.testing.assert_allclose(alone["strauss"]["color"], results[0]["strauss"]["color"], atol=1e-9)
    assert alone["strauss"]["smoothness"] == pytest.approx(results[0]["strauss"]["smoothness"], abs=1e-9)


def test_each_residual_is_measured_against_its_own_target(converter):
    # CIEDE2000 exposes both images for the target (its 99th percentile, when above 1): a
    # material's reported colour difference must not depend on what was converted with it,
    # here a white sphere whose broad highlight is brighter than 1 over much of the image
    dim = PhongMaterial(ka=0.0, kd=0.3, ks=0.2, exponent=40.0, diffuse_color=(0.2, 0.5, 0.3))
    bright = PhongMaterial(ka=0.0, kd=1.0, ks=1.0, exponent=2.0)
    assert np.percentile(converter.phong_target(bright), 99) > 1.2
    alone = converter.phong_to_strauss([Entry("dim", "test", dim)])[0]
    beside = converter.phong_to_strauss([Entry("bright", "test", bright), Entry("dim", "test", dim)])
    for key in ("rms", "delta_e2000_mean", "delta_e2000_p95"):
        assert beside[1]["residual"][key] == pytest.approx(alone["residual"][key], rel=1e-6), key
    strauss = Material(**{**alone["strauss"], "transparency": 0.0})
    expected = delta_e_2000(converter.strauss_target(strauss), converter.phong_target(dim))
    assert alone["residual"]["delta_e2000_mean"] == pytest.approx(float(np.mean(expected)), rel=1e-9)
    # the same the other way
    bright_strauss = Material(**{**beside[0]["strauss"], "transparency": 0.0})
    back = converter.strauss_to_phong([Entry("bright", "test", bright_strauss), Entry("dim", "test", strauss)])
    back_alone = converter.strauss_to_phong([Entry("dim", "test", strauss)])[0]
    mean = back_alone["residual"]["delta_e2000_mean"]
    assert back[1]["residual"]["delta_e2000_mean"] == pytest.approx(mean, rel=1e-6)


def test_opacity_and_ior_are_carried_over(converter):
    result = converter.phong_to_strauss(
        [Entry("glass", "test", PhongMaterial(ka=0.0, kd=0.2, ks=0.8, exponent=50.0), opacity=0.25, ior=1.33)]
    )[0]
    assert result["strauss"]["transparency"] == pytest.approx(0.75)
    assert result["strauss"]["ior"] == pytest.approx(1.33)
    assert any("carried over" in note for note in result["notes"])


def test_the_entry_points_convert_single_materials(converter):
    import strauss_fit as sf

    phong = PhongMaterial(ka=0.0, kd=0.5, ks=0.3, exponent=12.0, diffuse_color=(0.3, 0.6, 0.9))
    [result] = sf.phong_to_strauss(phong, scene=conversion_scene(size=SIZE))
    assert result == converter.phong_to_strauss([Entry("material-1", "python", phong)])[0]
    assert result["status"] == "ok" and result["residual"]["delta_e2000_mean"] < 5
    [back] = sf.strauss_to_phong(Material(**result["strauss"]), scene=conversion_scene(size=SIZE))
    assert back["status"] == "ok" and back["phong"]["kd"] > 0


# --- what the conversion image constrains (issue 13.4) ------------------------------------------


@pytest.mark.parametrize("quality", ["fast", "balanced", "accurate"])
def test_a_matte_wall_keeps_metalness_held_at_0_under_every_preset(quality):
    """Ks = 0: the image barely depends on m (it only dims the diffuse term with C), so m is
    held at 0, the value of a source without a metallic highlight — never reported at a
    bound with deviation 0, and no preset flips it to 1."""
    wall = PhongMaterial(ka=0.0, kd=(0.8, 0.78, 0.7), ks=0.0, exponent=10.0)
    result = Converter(conversion_scene(size=SIZE), Settings.preset(quality)).phong_to_strauss(
        [Entry("wall", "test", wall)]
    )[0]
    assert result["status"] == "ok"
    assert result["strauss"]["metalness"] == 0.0
    assert result["held"]["metalness"]["value"] == 0.0
    assert "does not determine it" in result["held"]["metalness"]["reason"]
    assert result["uncertainty"]["metalness"] is None  # a held value has no interval
    assert "metalness" not in result["solver"]["at_bound"]
    assert not any("best Strauss match is not" in note for note in result["notes"])
    np.testing.assert_allclose(result["strauss"]["color"], (0.8, 0.78, 0.7), atol=0.02)
    assert result["residual"]["delta_e2000_mean"] < 0.1


def test_phong_gold_converts_to_a_metal(converter):
    """A tinted Phong highlight (gold: Kd 0.1 0.07 0.02, Ks 1 0.78 0.34, Ns 200) is a metal's;
    least squares in linear RGB alone can land on a smooth plastic with a white highlight."""
    gold = PhongMaterial(ka=0.0, kd=(0.1, 0.07, 0.02), ks=(1.0, 0.78, 0.34), exponent=200.0)
    result = converter.phong_to_strauss([Entry("gold", "test", gold)])[0]
    assert result["status"] == "ok"
    assert result["strauss"]["metalness"] > 0.9
    color = np.asarray(result["strauss"]["color"])
    assert color[0] > color[1] > color[2]  # a gold tint
    assert result["residual"]["delta_e2000_mean"] < 3.0
