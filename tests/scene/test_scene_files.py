"""Scene files: every bundled scene loads and renders; malformed files and values out of
range are one-line errors that name the file, the place and the problem."""

import numpy as np
import pytest

import strauss_fit as sf

HEAD = "[camera]\nwidth = 8\nheight = 8\n"
AMBIENT = '[[light]]\nkind = "ambient"\nintensity = 1\n'


def test_bundled_scenes_load_and_render(scenes_dir):
    paths = sorted(scenes_dir.glob("*.toml"))
    assert paths
    for path in paths:
        scene = sf.load_scene(path).resized(16, 16)
        image, mask = sf.render(scene)
        assert np.all(np.isfinite(np.asarray(image))), path
        assert np.asarray(mask).any(), path


@pytest.mark.parametrize(
    "text,pattern",
    [
        ("[camera]\nwidth = 8\nheight = 8\n", "no light"),
        (
            HEAD + '[[light]]\nkind = "directional"\ndirection = [0, 0, 1]\nintensity = 1\ncolour = [1, 1, 1]\n',
            r"\[\[light\]\] #1: unknown key\(s\) 'colour'",
        ),
        ('[camera]\nwidth = 8\nheight = 8\n[[light]]\nkind = "spot"\nintensity = 1\n', "kind must be one of"),
        (
            '[camera]\nwidth = 8\nheight = 8\n[[light]]\nkind = "directional"\ndirection = [0, 0, 0]\nintensity = 1\n',
            "direction must not be the zero vector",
        ),
        (
            '[camera]\nwidth = 8\nheight = 8\n[[light]]\nkind = "ambient"\nintensity = -1\n',
            "intensity = -1 must be >= 0",
        ),
        (
            '[camera]\nwidth = 0\nheight = 8\n[[light]]\nkind = "ambient"\nintensity = 1\n',
            r"width = 0 must be in \[1, 8192\]",
        ),
        (
            HEAD + "[material]\nsmoothness = 2.0\n" + AMBIENT,
            r"\[material\]: material smoothness = 2.0 is outside its range",
        ),
        (
            '[camera]\nwidth = 8\nheight = 8\n[[light]]\nkind = "point"\nposition = [0.1, 0, 0]\nintensity = 1\n',
            "inside the unit sphere",
        ),
        ("[camera]\nwidth = 8\nheight = 8\n[lights]\n", r"unknown section\(s\) lights"),
        (
            '[camera]\nwidth = 8\nheight = 8\nprojection = "fisheye"\n[[light]]\nkind = "ambient"\nintensity = 1\n',
            "projection must be",
        ),
        (
            HEAD + AMBIENT + '[background]\nkind = "environment"\n',
            "needs image",
        ),
        (
            HEAD + AMBIENT + '[background]\nkind = "environment"\nimage = "missing.exr"\n',
            "image not found",
        ),
    ],
)
def test_scene_errors_are_one_line_and_name_the_problem(tmp_path, text, pattern):
    path = tmp_path / "scene.toml"
    path.write_text(text)
    with pytest.raises(sf.SceneError, match=pattern) as info:
        sf.load_scene(path)
    assert "\n" not in str(info.value)
    assert str(path) in str(info.value)


def test_malformed_and_missing_scene_files(tmp_path):
    with pytest.raises(sf.SceneError, match="scene file not found"):
        sf.load_scene(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[camera\nwidth = 3")
    with pytest.raises(sf.SceneError, match="not valid TOML"):
        sf.load_scene(bad)
