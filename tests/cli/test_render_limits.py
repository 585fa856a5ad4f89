"""`strauss-fit render` and `fit` at the limits (issue 24, items 6 and 13).

- A deep render of a transparent material traces only as deep as the written float32
  image can show, and says so in one line on stderr.
- A light too bright for the renderer's range is refused before any work, in one line
  naming the light and its value (exit 2), by `render` and by `fit` alike.
"""

from __future__ import annotations

import dataclasses

import numpy as np

import strauss_fit as sf
from strauss_fit.io.images import read_image
from strauss_fit_cli.main import main
from support import SCENES

GLASS = str(SCENES / "glass_checkerboard.toml")
BASIC = str(SCENES / "basic.toml")


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_deep_glass_render_is_cut_at_the_depth_the_file_can_show(tmp_path, capsys):
    """--depth 64 over a checkerboard: traced to depth 8 (its bound: 2^-24 of the board's
    brightest radiance), one line on stderr, and the file is a depth-8 render."""
    out = tmp_path / "glass.exr"
    code, stdout, stderr = run(capsys, "render", GLASS, "-o", out, "--depth", "64", "--width", "16", "--height", "16")
    assert code == 0 and stdout.startswith(f"wrote {out} (16x16")
    assert stderr.count("\n") == 1
    assert stderr.startswith("render: depth 64 reduced to 8: further interactions inside the sphere change no pixel")
    scene = dataclasses.replace(sf.load_scene(GLASS).resized(16, 16), depth=8)
    expected = np.asarray(sf.render(scene, depth_tolerance=0)[0]).astype(np.float32)
    np.testing.assert_array_equal(read_image(out).pixels, expected)


def test_bundled_depth_is_not_reported(tmp_path, capsys):
    code, _, stderr = run(capsys, "render", GLASS, "-o", tmp_path / "g.exr", "--width", "8", "--height", "8")
    assert code == 0 and stderr == ""


def bright_scene(tmp_path):
    """basic.toml with its key light at 1e308."""
    text = (SCENES / "basic.toml").read_text().replace("intensity = 1.0", "intensity = 1e308", 1)
    assert "1e308" in text
    path = tmp_path / "bright.toml"
    path.write_text(text)
    return path


EXPECTED = "[[light]] #1: intensity 1e+308 overflows the renderer's range: a light's intensity must be at most 1e+30"


def test_render_refuses_an_intensity_that_overflows(tmp_path, capsys):
    scene = bright_scene(tmp_path)
    out = tmp_path / "bright.exr"
    code, stdout, stderr = run(capsys, "render", scene, "-o", out, "--width", "8", "--height", "8")
    assert code == 2 and stdout == ""
    assert stderr == f"strauss-fit: error: {scene}: {EXPECTED}\n"
    assert not out.exists()


def test_fit_refuses_the_same_scene_the_same_way(tmp_path, capsys):
    target = tmp_path / "target.exr"
    assert run(capsys, "render", BASIC, "-o", target, "--width", "8", "--height", "8")[0] == 0
    scene = bright_scene(tmp_path)
    result = tmp_path / "fit.json"
    code, stdout, stderr = run(capsys, "fit", target, "--scene", scene, "-o", result, "--quiet")
    assert code == 2
    assert stderr == f"strauss-fit: error: {scene}: {EXPECTED}\n"
    assert "Traceback" not in stderr and not result.exists()
