"""Tests of the Mitsuba 3 backend: the BSDF schema and scene translation (no Mitsuba), the
bundled reference targets (no Mitsuba), and, when Mitsuba is installed, the calibration of
a Lambertian sphere against ``strauss-fit render``, the sphere's pixel coverage, the
environment map's orientation (a mirror) and the checkerboard's placement.

``MITSUBA_VARIANT`` picks the variant of the Mitsuba tests (default: ``llvm_ad_rgb`` when it
loads — 4-5x faster — else ``scalar_rgb``).
"""

from __future__ import annotations

import copy
import json
import math
import os
import tomllib

import numpy as np
import pytest

from data_synth import BUNDLED_MITSUBA as BUNDLED
from data_synth import SCENES
from data_synth import mitsuba_backend as mb
from strauss_fit import Material, parse_scene, render
from strauss_fit.errors import SceneError, StraussFitError

LAMBERT = {"smoothness": 0.0, "metalness": 0.0, "transparency": 0.0, "ior": 1.5}


def load_definition(name: str, size: int | None = None) -> dict:
    definition = tomllib.loads((SCENES / f"{name}.toml").read_text())
    definition.pop("material", None)
    if size is not None:
        definition["camera"]["width"] = definition["camera"]["height"] = size
    return definition


def strauss_box(definition: dict, material: dict, k: int = 8) -> np.ndarray:
    """strauss-fit's render box-filtered like a camera pixel: rendered at k× the size (its
    pixel centres are then a k×k stratified grid of each pixel) and averaged."""
    d = copy.deepcopy(definition)
    width, height = d["camera"]["width"], d["camera"]["height"]
    d["camera"]["width"], d["camera"]["height"] = width * k, height * k
    image, _ = render(parse_scene(d, base_dir=SCENES), Material.from_dict(material))
    return np.asarray(image).reshape(height, k, width, k, 3).mean(axis=(1, 3))


def strauss_diffuse_part(definition: dict, albedo: list[float], k: int = 8) -> np.ndarray:
    """The part of strauss-fit's s = m = t = 0 image proportional to C: C·Σ I cos α + C·I_a.

    Strauss at s = 0 is not Lambertian: its off-specular term r_s = k_j·j·cos³β (white for
    m = 0) and the global model's reflection of the background stay. For m = 0 both are
    independent of C, so render(C) − render(0) is exactly the Lambertian part.
    """
    return strauss_box(definition, {"color": albedo, **LAMBERT}, k) - strauss_box(
        definition, {"color": [0.0, 0.0, 0.0], **LAMBERT}, k
    )


# --- BSDF schema (no Mitsuba) -------------------------------------------------------------


@pytest.mark.parametrize(
    "bsdf, message",
    [
        ({"type": "lambert"}, "unknown BSDF type 'lambert'"),
        ({"reflectance": 0.5}, "unknown BSDF type None"),
        ({"type": "diffuse", "albedo": 0.5}, "unknown key(s) albedo for type 'diffuse'"),
        ({"type": "diffuse", "reflectance": 1.2}, "reflectance must be in [0, 1]"),
        ({"type": "diffuse", "reflectance": [0.5, 0.5]}, "reflectance must be a number or a list of 3 numbers"),
        ({"type": "roughplastic", "alpha": 0.0}, "alpha must be a number in [0.0001, 1]"),
        ({"type": "roughplastic", "distribution": "phong"}, "distribution must be one of ggx, beckmann"),
        ({"type": "plastic", "int_ior": 0.8}, "int_ior must be a number in [1, 4]"),
        ({"type": "plastic", "int_ior": 1.0}, "int_ior and ext_ior must differ"),
        ({"type": "roughconductor", "material": "Gold"}, "unknown metal 'Gold'"),
        ({"type": "conductor", "eta": [0.2, 0.4, 1.4]}, "eta and k must be given together"),
        ({"type": "conductor", "material": "Au", "eta": 0.2, "k": 3.0}, "either material or eta and k"),
        ({"type": "principled", "eta": 1.5, "specular": 0.5}, "either specular or eta"),
        ({"type": "principled", "metallic": True}, "metallic must be a number in [0, 1]"),
        ("diffuse", "must be a table"),
    ],
)
def test_bad_bsdf_is_one_line_error(bsdf, message):
    with pytest.raises(mb.MitsubaBackendError) as info:
        mb.validate_bsdf(bsdf)
    text = str(info.value)
    assert message in text and "\n" not in text
    assert isinstance(info.value, StraussFitError)  # the CLI prints it as one line, exit 2


def test_bsdf_defaults_filled_and_colours_expanded():
    b = mb.validate_bsdf({"type": "roughplastic", "diffuse_reflectance": 0.3})
    assert b == {
        "type": "roughplastic",
        "diffuse_reflectance": [0.3, 0.3, 0.3],
        "int_ior": 1.5,
        "ext_ior": 1.0,
        "distribution": "ggx",
        "alpha": 0.1,
        "nonlinear": False,
        "specular_reflectance": [1.0, 1.0, 1.0],
    }
    assert mb.validate_bsdf({"type": "principled"})["specular"] == 0.5
    assert "material" not in mb.validate_bsdf({"type": "conductor", "eta": 0.2, "k": 3.0})
    for kind in mb.BSDF_SCHEMA:  # every type validates with its defaults and converts
        assert mb.bsdf_to_mitsuba({"type": kind})["type"] == kind


def test_named_metals_match_installed_mitsuba():
    pytest.importorskip("mitsuba")
    assert {"Au", "Cu", "Ag", "Al", "none"} <= mb.NAMED_METALS
    assert mb.named_metals() == mb.NAMED_METALS


# --- scene translation (no Mitsuba) -------------------------------------------------------


def test_lights_translate_with_pi_factor():
    definition = {
        "camera": {"width": 8, "height": 8},
        "light": [
            {"kind": "directional", "direction": [0.0, 3.0, 4.0], "intensity": 2.0, "color": [1, 0.5, 0.25]},
            {"kind": "point", "position": [0, 0, 5], "intensity": 9.0, "attenuation": [0.0, 0.0, 2.0]},
            {"kind": "ambient", "intensity": 0.1},
            {"kind": "ambient", "intensity": 0.05},
        ],
    }
    t = mb.translate_scene(definition)
    sun, bulb = t.emitters
    assert sun["direction"] == pytest.approx([0.0, -0.6, -0.8])  # Mitsuba: the direction light travels
    assert sun["irradiance"] == pytest.approx([2 * math.pi, math.pi, math.pi / 2])
    assert bulb["intensity"] == pytest.approx([9 * math.pi / 2] * 3)
    assert t.ambient == pytest.approx(0.15)
    assert any("ambient" in note for note in t.notes)


@pytest.mark.parametrize("attenuation", [[1.0, 0.0, 1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
def test_non_physical_attenuation_is_refused(attenuation):
    definition = {
        "camera": {"width": 8, "height": 8},
        "light": [{"kind": "point", "position": [0, 0, 5], "intensity": 9.0, "attenuation": attenuation}],
    }
    with pytest.raises(mb.MitsubaBackendError) as info:
        mb.translate_scene(definition)
    assert "no physical counterpart" in str(info.value) and "[0.0, 0.0, c2]" in str(info.value)
    with pytest.raises(mb.MitsubaBackendError):  # refused before Mitsuba is imported
        mb.render_mitsuba(definition, {"type": "diffuse"}, spp=4, seed=0)


def test_default_point_attenuation_is_refused():
    """strauss-fit's default attenuation is (1, 0, 0): no falloff, not physical."""
    definition = {
        "camera": {"width": 8, "height": 8},
        "light": [{"kind": "point", "position": [0, 0, 5], "intensity": 1.0}],
    }
    with pytest.raises(mb.MitsubaBackendError, match="attenuation"):
        mb.translate_scene(definition)


def test_invalid_definition_is_refused_by_strauss_fit():
    with pytest.raises(SceneError):
        mb.translate_scene({"camera": {"width": 8, "height": 8}, "light": [{"kind": "spot", "intensity": 1.0}]})


def test_bad_spp_and_seed():
    definition = load_definition("key_light")
    with pytest.raises(mb.MitsubaBackendError, match="spp"):
        mb.render_mitsuba(definition, {"type": "diffuse"}, spp=0, seed=0)
    with pytest.raises(mb.MitsubaBackendError, match="seed"):
        mb.render_mitsuba(definition, {"type": "diffuse"}, spp=4, seed=-1)


# --- coverage and the directly seen background (no Mitsuba) -------------------------------


@pytest.mark.parametrize("width, height", [(64, 64), (48, 32), (7, 5)])
def test_orthographic_coverage_is_the_disk_area(width, height):
    cover = mb.sphere_coverage({"projection": "orthographic", "width": width, "height": height})
    assert cover.sum() == pytest.approx(math.pi * width * height / 4, rel=1e-6)
    _, mask = render(
        parse_scene({"camera": {"width": width, "height": height}, "light": [{"kind": "ambient", "intensity": 1.0}]})
    )
    mask = np.asarray(mask)
    assert np.all(cover[mask] > 0)  # every strauss-fit sphere pixel is at least partly covered
    assert np.all(mask[cover >= 1.0])  # every fully covered pixel is a strauss-fit sphere pixel
    assert 0 < ((cover > 0) & (cover < 1)).sum() < cover.size


@pytest.mark.parametrize("name", ["key_light", "checker", "metal_environment", "point_light"])
def test_numpy_background_matches_strauss_fit(name):
    """The composited background (what the camera sees beside the sphere) is strauss-fit's,
    including the defaults of the scene format."""
    definition = load_definition(name, 32)
    t = mb.translate_scene(definition, SCENES)
    origin, direction = mb._subpixel_rays(t.camera, 1)
    ours = mb.background_radiance(t.background, origin, direction)[..., 0, :]
    image, mask = render(parse_scene(definition, base_dir=SCENES), Material.from_dict({"color": [0.5] * 3, **LAMBERT}))
    miss = ~np.asarray(mask)
    np.testing.assert_allclose(ours[miss], np.asarray(image)[miss], rtol=1e-6, atol=1e-7)


def test_environment_resampling_reproduces_strauss_lookup():
    """Emulating Mitsuba 3.9's envmap lookup on the resampled map gives strauss-fit's value."""
    rng = np.random.default_rng(0)
    image = rng.random((8, 16, 3))
    resampled = mb.environment_for_mitsuba(image)
    h2, w2 = resampled.shape[:2]
    d = rng.normal(size=(2000, 3))
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    u = (np.arctan2(d[:, 0], -d[:, 2]) / (2 * np.pi)) % 1.0
    v = np.arccos(d[:, 1]) / np.pi
    x = u * w2 - 0.5  # column centres at (c + 1/2)/W', periodic
    y = v * (h2 - 1)  # rows at the poles' ends
    x0, y0 = np.floor(x), np.clip(np.floor(y), 0, h2 - 2)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    c0, c1 = x0.astype(int) % w2, (x0.astype(int) + 1) % w2
    r0 = y0.astype(int)
    mitsuba = (resampled[r0, c0] * (1 - fx) + resampled[r0, c1] * fx) * (1 - fy) + (
        resampled[r0 + 1, c0] * (1 - fx) + resampled[r0 + 1, c1] * fx
    ) * fy
    np.testing.assert_allclose(mitsuba, mb.environment_lookup(image, d), atol=1e-12)


def test_checker_tile_is_strauss_fits_board():
    tile = mb.checker_tile([[1.0, 1.0, 1.0], [0.0, 0.0, 0.0]], 20.0, texels=64)
    t = 2 * (np.arange(64) + 0.5) / 64
    np.testing.assert_allclose(tile[..., 0], mb.checker_weight(t[None, :], t[:, None], 20.0), atol=1e-6)
    assert tile[8, 8, 0] > 0.99 and tile[8, 40, 0] < 0.01  # u, v in (0, 1): colours[0]


# --- the bundled targets (no Mitsuba) -----------------------------------------------------


def _bundled_samples():
    index = json.loads((BUNDLED / "index.json").read_text())
    return index, index["samples"]


def test_bundled_index_and_sidecars():
    import hashlib

    index, samples = _bundled_samples()
    assert index["format"] == "strauss-fit synth index" and index["complete"] == index["total"] == len(samples)
    assert 10 <= len(samples) <= 14
    total = 0
    for entry in samples:
        for name, digest in entry["sha256"].items():
            data = (BUNDLED / name).read_bytes()
            total += len(data)
            assert hashlib.sha256(data).hexdigest() == digest, name
        sidecar = json.loads((BUNDLED / entry["files"]["sidecar"]).read_text())
        assert sidecar["model"] == "mitsuba" and sidecar["parameters"] == mb.validate_bsdf(sidecar["parameters"])
        assert sidecar["render"]["spp"] >= 1024 and len(sidecar["render"]["seeds"]) == 2
        assert all(0 < n < 0.01 for n in sidecar["noise"]["relative"])
        mb.translate_scene(sidecar["scene"]["definition"], BUNDLED)  # still a valid, translatable scene
    assert total < 600_000  # a few hundred KB


def test_bundled_coverage_matches_scene():
    from strauss_fit import read_image

    _, samples = _bundled_samples()
    for entry in samples:
        sidecar = json.loads((BUNDLED / entry["files"]["sidecar"]).read_text())
        t = mb.translate_scene(sidecar["scene"]["definition"], BUNDLED)
        stored = read_image(BUNDLED / entry["files"]["coverage"]).pixels[..., 0]
        np.testing.assert_allclose(stored, mb.sphere_coverage(t.camera), atol=1e-6)
        image = read_image(BUNDLED / entry["files"]["exr"]).pixels
        assert image.shape == (t.camera["height"], t.camera["width"], 3) and np.all(np.isfinite(image))


def test_bundled_lambertian_is_calibrated():
    """The bundled calibration target agrees with strauss-fit's diffuse part to 1 % on
    every fully covered pixel, and on average to 0.05 %."""
    from strauss_fit import read_image

    _, samples = _bundled_samples()
    entry = next(e for e in samples if e["group"] == "mitsuba-diffuse")
    sidecar = json.loads((BUNDLED / entry["files"]["sidecar"]).read_text())
    definition = sidecar["scene"]["definition"]
    image = read_image(BUNDLED / entry["files"]["exr"]).pixels
    full = mb.sphere_coverage(mb.translate_scene(definition).camera) >= 1
    reference = strauss_diffuse_part(definition, sidecar["parameters"]["reflectance"])
    relative = (image - reference)[full] / reference[full]  # fully covered: no background share
    assert np.abs(relative).max() < 0.01
    assert np.abs(relative.mean(axis=0)).max() < 5e-4


# --- with Mitsuba -------------------------------------------------------------------------


@pytest.fixture(scope="module")
def variant():
    pytest.importorskip("mitsuba")
    wanted = os.environ.get("MITSUBA_VARIANT")
    if wanted:
        return wanted
    try:
        mb._mitsuba("llvm_ad_rgb")
        return "llvm_ad_rgb"
    except mb.MitsubaUnavailableError:
        return "scalar_rgb"


@pytest.mark.slow
@pytest.mark.parametrize("scene", ["key_light", "two_lights", "point_light"])
@pytest.mark.parametrize("albedo", [[0.8, 0.5, 0.2], [0.3, 0.3, 0.3], [0.05, 0.9, 0.6]])
def test_lambertian_calibration(variant, scene, albedo):
    """A Mitsuba diffuse sphere equals strauss-fit's C = albedo, s = m = t = 0 (its part
    proportional to C) to 1 % on every fully covered pixel; on average to 0.05 %."""
    definition = load_definition(scene)
    result = mb.render_mitsuba_full(
        definition, {"type": "diffuse", "reflectance": albedo}, spp=1024, seed=7, variant=variant, base_dir=SCENES
    )
    reference = strauss_diffuse_part(definition, albedo)
    full = result.coverage >= 1
    relative = (result.sphere_part - reference)[full] / reference[full]
    assert np.abs(relative).max() < 0.01
    assert np.abs(relative.mean(axis=0)).max() < 5e-4
    # the composited image outside the sphere is strauss-fit's background
    outside = result.coverage == 0
    np.testing.assert_allclose(
        result.image[outside], np.broadcast_to(definition["background"]["color"], (outside.sum(), 3)), atol=1e-7
    )


@pytest.mark.parametrize(
    "camera",
    [
        {"projection": "orthographic", "width": 64, "height": 64},
        {"projection": "orthographic", "width": 48, "height": 32},
        {
            "projection": "perspective",
            "width": 64,
            "height": 48,
            "position": [0.5, 1.0, 4.0],
            "look_at": [0.1, 0.0, 0.0],
            "fov_deg": 40.0,
            "up": [0.1, 1.0, 0.0],
        },
    ],
)
def test_sphere_lands_on_the_same_pixels(variant, camera):
    """Mitsuba's alpha (the fraction of a pixel's samples that hit the sphere, emitters
    hidden) equals the analytic coverage: same pixel grid, orientation and aspect."""
    mi = mb._mitsuba(variant)
    t = mb.translate_scene({"camera": camera, "light": [{"kind": "ambient", "intensity": 1.0}]})
    # max_depth 2: with 1, scalar variants return from the path loop before marking a hit as
    # valid, so their alpha is 0 everywhere (JIT variants are not affected)
    scene = mb.mitsuba_scene_dict(t, {"type": "diffuse"}, spp=1024, max_depth=2, rr_depth=5, mi=mi)
    scene["sensor"]["film"]["pixel_format"] = "rgba"
    alpha = np.array(mi.render(mi.load_dict(scene), seed=0, spp=1024))[..., 3]
    coverage = mb.sphere_coverage(t.camera)
    assert np.abs(alpha - coverage).max() < 0.02
    assert alpha.sum() == pytest.approx(coverage.sum(), rel=2e-3)


@pytest.mark.parametrize("projection", ["perspective", "orthographic"])
def test_mirror_reflects_environment_like_strauss_fit(variant, projection):
    """A perfect Mitsuba mirror (conductor 'none') in the studio environment equals
    strauss-fit's s = 1, m = 1, C = 1 (a perfect mirror of the background): the map's
    orientation and interpolation correspond."""
    definition = load_definition("metal_environment", 48)
    if projection == "orthographic":
        definition["camera"] = {"projection": "orthographic", "width": 48, "height": 48}
    result = mb.render_mitsuba_full(
        definition, {"type": "conductor", "material": "none"}, spp=256, seed=3, variant=variant, base_dir=SCENES
    )
    reference = strauss_box(
        definition, {"color": [1.0, 1.0, 1.0], "smoothness": 1.0, "metalness": 1.0, "transparency": 0.0, "ior": 1.5}
    )
    full = result.coverage >= 1
    error = np.abs(result.image - reference)[full].mean(axis=0) / reference[full].mean(axis=0)
    assert error.max() < 3e-3
    # a half-turn error in azimuth would be off by tens of per cent
    assert (
        np.abs(np.roll(reference, 1, axis=1) - reference)[full].mean()
        > 10 * np.abs(result.image - reference)[full].mean()
    )


@pytest.mark.parametrize("normal", [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [0.2, 0.3, 1.0]])
def test_checkerboard_plane_is_strauss_fits_board(variant, normal):
    """Through a sphere of index 1 (no refraction, no reflection) Mitsuba sees its emitting
    board exactly where strauss-fit's board is."""
    definition = load_definition("checker")
    definition["background"]["normal"] = normal
    definition["light"] = [light for light in definition["light"] if light["kind"] != "ambient"]
    t = mb.translate_scene(definition, SCENES)
    result = mb.render_mitsuba_full(
        definition,
        {"type": "dielectric", "int_ior": 1.0, "ext_ior": 1.0},
        spp=64,
        seed=3,
        variant=variant,
        base_dir=SCENES,
    )
    origin, direction = mb._subpixel_rays(t.camera, 8)
    board = mb.background_radiance(t.background, origin, direction).mean(axis=-2)
    full = result.coverage >= 1
    assert np.abs(result.sphere_part - board)[full].mean() < 1e-3
    assert np.abs(result.sphere_part - board)[full].max() < 0.03


def test_same_seed_same_image(variant):
    definition = load_definition("key_light", 16)
    a, _ = mb.render_mitsuba(definition, {"type": "roughplastic"}, spp=16, seed=11, variant=variant)
    b, _ = mb.render_mitsuba(definition, {"type": "roughplastic"}, spp=16, seed=11, variant=variant)
    c, _ = mb.render_mitsuba(definition, {"type": "roughplastic"}, spp=16, seed=12, variant=variant)
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_unknown_variant(variant):
    with pytest.raises(mb.MitsubaBackendError, match="unknown Mitsuba variant"):
        mb.render_mitsuba(load_definition("key_light", 8), {"type": "diffuse"}, spp=1, seed=0, variant="cuda_ad_rgb")
