"""`strauss-fit render`: outputs and every bad-input path (one line, exit 2, nothing lost)."""

import numpy as np
import pytest

from strauss_fit.io.images import read_image
from strauss_fit_cli.main import main
from support import SCENES

BASIC = str(SCENES / "basic.toml")


def run(capsys, *argv):
    code = main(list(argv))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_render_writes_exr_and_png_that_agree(tmp_path, capsys):
    exr, png = tmp_path / "a.exr", tmp_path / "a.png"
    assert run(capsys, "render", BASIC, "-o", str(exr), "--width", "32", "--height", "24")[0] == 0
    assert run(capsys, "render", BASIC, "-o", str(png), "--width", "32", "--height", "24")[0] == 0
    linear = read_image(exr)
    decoded = read_image(png)
    assert linear.pixels.shape == (24, 32, 3) and linear.encoding == "linear"
    assert decoded.encoding == "srgb"
    # 8-bit sRGB quantisation: at most half a code step, i.e. < 0.5/255 in encoded space
    np.testing.assert_allclose(decoded.pixels, np.clip(linear.pixels, 0, 1), atol=0.01)


def test_render_mask_and_precision(tmp_path, capsys):
    out, mask = tmp_path / "f32.exr", tmp_path / "mask.png"
    code, stdout, _ = run(
        capsys,
        "render",
        BASIC,
        "-o",
        str(out),
        "--mask",
        str(mask),
        "--precision",
        "float32",
        "--width",
        "16",
        "--height",
        "16",
        "--mode",
        "table",
        "--table-size",
        "64",
        "--depth",
        "2",
    )
    assert code == 0 and "sphere pixels" in stdout
    m = read_image(mask, encoding="linear").pixels[..., 0]
    assert set(np.unique(m)) == {0.0, 1.0}


@pytest.mark.parametrize(
    "argv,pattern",
    [
        (["render", "missing.toml", "-o", "{tmp}/x.exr"], "scene file not found: missing.toml"),
        (["render", BASIC, "-o", "{tmp}/nodir/x.exr"], "output folder does not exist"),
        (["render", BASIC, "-o", "{tmp}/x.xyz"], "no image writer"),
        (["render", BASIC, "-o", "{tmp}/x.exr", "--table-size", "1"], "--table-size must be at least 2"),
    ],
)
def test_render_errors_are_one_line(tmp_path, capsys, argv, pattern):
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    code, _, err = run(capsys, *argv)
    assert code == 2
    assert err.startswith("strauss-fit: error: ") and err.count("\n") == 1
    assert pattern in err
    assert "Traceback" not in err
    assert not any(p.name.startswith(".x") for p in tmp_path.iterdir())  # no temporary left behind


def test_malformed_scene_and_out_of_range_values(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text(
        '[camera]\nwidth = 8\nheight = 8\n[material]\nmetalness = 3\n[[light]]\nkind = "ambient"\nintensity = 1\n'
    )
    code, _, err = run(capsys, "render", str(bad), "-o", str(tmp_path / "o.exr"))
    assert code == 2 and "metalness = 3" in err and "[0, 1]" in err
    empty = tmp_path / "nolight.toml"
    empty.write_text("[camera]\nwidth = 8\nheight = 8\n")
    code, _, err = run(capsys, "render", str(empty), "-o", str(tmp_path / "o.exr"))
    assert code == 2 and "no light" in err
    assert not (tmp_path / "o.exr").exists()


def test_existing_output_is_kept_without_force(tmp_path, capsys):
    out = tmp_path / "keep.png"
    out.write_bytes(b"precious")
    code, _, err = run(capsys, "render", BASIC, "-o", str(out), "--width", "8", "--height", "8")
    assert code == 2 and "exists; pass --force" in err
    assert out.read_bytes() == b"precious"
    assert run(capsys, "render", BASIC, "-o", str(out), "--width", "8", "--height", "8", "--force")[0] == 0
    assert read_image(out).pixels.shape == (8, 8, 3)


def test_unknown_option_and_help(capsys):
    assert main(["render", "--bogus"]) == 2
    err = capsys.readouterr().err
    assert (
        err.startswith("strauss-fit: error: ") and err.count("\n") == 1 and "(see 'strauss-fit render --help')" in err
    )
    assert main(["--help"]) == 0
    assert "render" in capsys.readouterr().out
