"""`strauss-fit fit` end to end, and every bad-input path (one line, exit 2, nothing lost)."""

import json

import numpy as np
import pytest

from strauss_fit.io.images import read_image, write_image
from strauss_fit_cli.main import main

SCENE = """
[camera]
width = 24
height = 24
[material]
color = [0.5, 0.5, 0.5]
smoothness = 0.5
[[light]]
kind = "directional"
direction = [0.3, 0.5, 1.0]
intensity = 1.0
"""


@pytest.fixture
def scene(tmp_path):
    path = tmp_path / "scene.toml"
    path.write_text(SCENE)
    return path


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def render_target(tmp_path, scene, capsys, name="target.exr", material=None):
    text = SCENE.replace(
        "color = [0.5, 0.5, 0.5]\nsmoothness = 0.5",
        material or "color = [0.7, 0.3, 0.2]\nsmoothness = 0.7\nmetalness = 0.5",
    )
    truth = tmp_path / "truth.toml"
    truth.write_text(text)
    out = tmp_path / name
    assert run(capsys, "render", truth, "-o", out)[0] == 0
    return out


def test_fit_recovers_a_rendered_target_and_writes_outputs(tmp_path, scene, capsys):
    target = render_target(tmp_path, scene, capsys)
    result, fitted = tmp_path / "fit.json", tmp_path / "fit.exr"
    code, out, err = run(capsys, "fit", target, "--scene", scene, "-o", result, "--render-fit", fitted)
    assert code == 0, err
    data = json.loads(result.read_text())
    np.testing.assert_allclose(data["color"], [0.7, 0.3, 0.2], atol=1e-3)
    assert data["smoothness"] == pytest.approx(0.7, abs=1e-3)
    assert data["metalness"] == pytest.approx(0.5, abs=1e-2)
    assert data["free"] == ["color", "smoothness", "metalness"]
    assert "transparency" in data["held"] and data["uncertainty"]["smoothness"] >= 0
    assert "parameter" in out and "smoothness" in out and "held:" in out
    np.testing.assert_allclose(read_image(fitted).pixels, read_image(target).pixels, atol=1e-3)
    compare = read_image(tmp_path / "fit.compare.png").pixels
    assert compare.shape == (24, 24 * 3 + 4, 3)
    # a second run refuses to overwrite
    before = result.read_bytes()
    code, _, err = run(capsys, "fit", target, "--scene", scene, "-o", result)
    assert code == 2 and "exists; pass --force" in err and result.read_bytes() == before


def test_fit_of_an_ldr_png_excludes_clipped_pixels(tmp_path, capsys):
    scene = tmp_path / "bright.toml"
    scene.write_text(SCENE.replace("intensity = 1.0", "intensity = 1.6"))
    truth = tmp_path / "truth.toml"
    truth.write_text(
        SCENE.replace("intensity = 1.0", "intensity = 1.6").replace(
            "color = [0.5, 0.5, 0.5]\nsmoothness = 0.5", "color = [0.9, 0.6, 0.4]\nsmoothness = 0.8\nmetalness = 0.0"
        )
    )
    target = tmp_path / "target.png"
    assert run(capsys, "render", truth, "-o", target)[0] == 0
    loaded = read_image(target)
    assert loaded.clipped.any()
    result = tmp_path / "fit.json"
    code, _, err = run(capsys, "fit", target, "--scene", scene, "-o", result, "--fix", "metalness=0")
    assert code == 0, err
    data = json.loads(result.read_text())
    assert data["settings"]["clipped_pixels_excluded"] == int(loaded.clipped.sum())
    assert data["smoothness"] == pytest.approx(0.8, abs=0.02)
    np.testing.assert_allclose(data["color"], [0.9, 0.6, 0.4], atol=0.02)
    assert data["held"]["metalness"]["reason"] == "fixed by the user (--fix)"


def write_raw(path, pixels):
    import OpenImageIO as oiio

    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(pixels.shape[1], pixels.shape[0], 3, oiio.FLOAT))
    out.write_image(pixels.astype(np.float32))
    out.close()


@pytest.mark.parametrize(
    "case,pattern",
    [
        ("missing", "image not found"),
        ("corrupt", "cannot read image"),
        ("aspect", "a different aspect ratio"),
        ("black", "is black on every usable sphere pixel"),
        ("clipped", "no usable sphere pixels"),
        ("nan", "NaN or infinite"),
        ("mask-size", "mask"),
        ("bad-fix", "smoothness = 1.5 is outside its range"),
        ("bad-fix-syntax", "--fix expects NAME=VALUE"),
        ("unknown-free", "cannot free unknown parameter"),
        # once "the scene constrains none of the candidates", which blamed the scene
        ("free-and-fix", "smoothness both freed and fixed: free a parameter or fix it, not both"),
        ("free-no-name", "--free ',,' names no parameter"),
        ("free-empty", "--free '' names no parameter"),  # once the automatic choice, silently
        ("fix-twice", "--fix smoothness is given twice"),
        ("unknown-model-first", "unknown reflectance model 'foo'"),  # not "--quality is not available"
    ],
)
def test_fit_bad_inputs_are_one_line_errors(tmp_path, scene, capsys, case, pattern):
    target = tmp_path / "t.exr"
    extra = []
    if case == "corrupt":
        target.write_bytes(b"this is not an image at all")
    elif case == "aspect":
        write_image(target, np.full((24, 48, 3), 0.5))
    elif case == "black":
        write_image(target, np.zeros((24, 24, 3)))
    elif case == "clipped":
        target = tmp_path / "t.png"
        write_image(target, np.ones((24, 24, 3)))
    elif case == "nan":
        pixels = np.full((24, 24, 3), 0.5)
        pixels[3, 4, 1] = np.nan
        write_raw(target, pixels)
    elif case != "missing":
        write_image(target, np.full((24, 24, 3), 0.3))
    if case == "mask-size":
        mask = tmp_path / "m.png"
        write_image(mask, np.ones((10, 10, 3)))
        extra = ["--mask", mask]
    elif case == "bad-fix":
        extra = ["--fix", "smoothness=1.5"]
    elif case == "bad-fix-syntax":
        extra = ["--fix", "smoothness"]
    elif case == "unknown-free":
        extra = ["--free", "roughness"]
    elif case == "free-and-fix":
        extra = ["--free", "smoothness", "--fix", "smoothness=0.5"]
    elif case == "free-no-name":
        extra = ["--free", ",,"]
    elif case == "free-empty":
        extra = ["--free", ""]
    elif case == "fix-twice":
        extra = ["--fix", "smoothness=0.3", "--fix", "smoothness=0.4"]
    elif case == "unknown-model-first":
        extra = ["--model", "foo", "--quality", "fast"]
    result = tmp_path / "r.json"
    code, _, err = run(capsys, "fit", target, "--scene", scene, "-o", result, *extra)
    assert code == 2
    assert err.startswith("strauss-fit: error: ") and err.count("\n") == 1, err
    assert pattern in err
    assert not result.exists()


def test_target_of_another_size_is_rendered_at_its_size(tmp_path, scene, capsys):
    text = SCENE.replace("width = 24\nheight = 24", "width = 32\nheight = 32").replace(
        "color = [0.5, 0.5, 0.5]", "color = [0.2, 0.4, 0.6]"
    )
    big = tmp_path / "big.toml"
    big.write_text(text)
    target = tmp_path / "big.exr"
    assert run(capsys, "render", big, "-o", target)[0] == 0
    code, _, err = run(capsys, "fit", target, "--scene", scene, "-o", tmp_path / "r.json")
    assert code == 0
    assert "rendering at the target's size" in err
    data = json.loads((tmp_path / "r.json").read_text())
    np.testing.assert_allclose(data["color"], [0.2, 0.4, 0.6], atol=1e-3)


def test_quality_presets_set_and_record_the_solver_settings(tmp_path, scene, capsys):
    target = render_target(tmp_path, scene, capsys)
    for quality, starts, rtol in (("fast", 2, 1e-2), ("balanced", 2, 1e-4), ("accurate", 4, 1e-8)):
        result = tmp_path / f"{quality}.json"
        assert run(capsys, "fit", target, "--scene", scene, "-o", result, "--quality", quality)[0] == 0
        settings = json.loads(result.read_text())["settings"]
        assert (settings["quality"], settings["starts"], settings["rtol"]) == (quality, starts, rtol)
    # an explicit option wins over the preset
    result = tmp_path / "explicit.json"
    assert run(capsys, "fit", target, "--scene", scene, "-o", result, "--quality", "fast", "--starts", "3")[0] == 0
    assert json.loads(result.read_text())["settings"]["starts"] == 3


@pytest.mark.parametrize("quality", ["balanced", "fast"])
def test_the_command_and_the_library_give_the_same_fit_for_the_same_preset(tmp_path, scene, capsys, quality):
    import strauss_fit as sf

    target = render_target(tmp_path, scene, capsys)
    result = tmp_path / "cli.json"
    assert run(capsys, "fit", target, "--scene", scene, "-o", result, "--quality", quality)[0] == 0
    cli = json.loads(result.read_text())
    loaded_scene, loaded_target = sf.load_scene(scene), sf.load_target(target)
    loaded_scene, _ = sf.match_scene(loaded_scene, loaded_target)
    options = sf.FitOptions() if quality == "balanced" else sf.FitOptions.preset(quality)
    library = sf.fit(loaded_scene, loaded_target, options).to_json()
    for key in (
        "color",
        "smoothness",
        "metalness",
        "transparency",
        "ior",
        "free",
        "held",
        "uncertainty",
        "correlation",
        "residual",
        "solver",
        "starts",
        "lights",
        "pixels_used",
    ):
        assert cli[key] == library[key], key
    assert {k: v for k, v in cli["settings"].items() if k != "quality"} == library["settings"]


def test_a_target_above_the_pixel_limit_gets_a_comparison_image_at_the_fitted_size(
    tmp_path, scene, capsys, monkeypatch
):
    """The fit of a target above the pixel limit is block-averaged: the comparison image is
    made from the target as fitted (a 2x2-averaged 24x24 target gives 12x12 panels)."""
    import strauss_fit.io.targets as targets

    monkeypatch.setattr(targets.reduce_target, "__defaults__", (12 * 12,))
    target = render_target(tmp_path, scene, capsys)
    result, fitted = tmp_path / "fit.json", tmp_path / "fit.exr"
    code, _, err = run(capsys, "fit", target, "--scene", scene, "-o", result, "--render-fit", fitted)
    assert code == 0, err
    assert "averaged over 2x2 blocks, at 12x12" in err
    assert read_image(fitted).pixels.shape[:2] == (12, 12)
    compare = read_image(tmp_path / "fit.compare.png").pixels
    assert compare.shape[0] == 12 and compare.shape[1] > 12


def test_no_equivalence_turns_off_the_accurate_presets_equivalence_ranges(tmp_path, scene, capsys):
    target = render_target(tmp_path, scene, capsys)
    on, off = tmp_path / "on.json", tmp_path / "off.json"
    assert run(capsys, "fit", target, "--scene", scene, "-o", on, "--quality", "accurate")[0] == 0
    assert run(capsys, "fit", target, "--scene", scene, "-o", off, "--quality", "accurate", "--no-equivalence")[0] == 0
    assert json.loads(on.read_text()).get("equivalence")
    assert not json.loads(off.read_text()).get("equivalence")
