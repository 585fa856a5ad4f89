"""Hostile input, command by command: one table each (render, fit, synth, sample, report,
phong2strauss, strauss2phong, study). Every row is an argument list and the files it
needs; it must end with the expected exit status and one line, ``strauss-fit: error:
...``, naming the problem — no traceback, no raw control character — and leave the
folder exactly as it was (nothing written, nothing overwritten, no temporary file).

Every problem is found before any work (that is the point), so the rows compile no JAX
program and the whole module runs in seconds.
"""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest

from strauss_fit.io.images import write_image
from strauss_fit_cli.main import main
from support import KEY_AND_FILL, SCENES, SYNTH_SPEC

DATA = Path(__file__).resolve().parent.parent / "data" / "mtl"
SCENE = KEY_AND_FILL.read_text()  # 40 x 40
NAN_SKY_SCENE = SCENE.split("[background]")[0] + '\n[background]\nkind = "environment"\nimage = "nan-sky.exr"\n'


def raw_exr(pixels) -> bytes:
    """An EXR holding exactly ``pixels`` (NaN included: the library refuses to write one)."""
    import os
    import tempfile

    import OpenImageIO as oiio

    data = np.asarray(pixels, dtype=np.float32)
    fd, name = tempfile.mkstemp(suffix=".exr")
    os.close(fd)
    out = oiio.ImageOutput.create(name)
    out.open(name, oiio.ImageSpec(data.shape[1], data.shape[0], 3, oiio.FLOAT))
    out.write_image(data)
    out.close()
    blob = Path(name).read_bytes()
    os.unlink(name)
    return blob


@pytest.fixture(scope="module")
def assets(tmp_path_factory):
    """Valid inputs every row may copy: a scene, a 40 x 40 target, a JPEG, a fit result,
    a chain (written by the library, a few steps), broken variants."""
    folder = tmp_path_factory.mktemp("assets")
    write_image(folder / "target.exr", np.full((40, 40, 3), 0.3))
    write_image(folder / "wide.exr", np.full((40, 80, 3), 0.3))
    write_image(folder / "small-mask.png", np.ones((10, 10, 3)))
    write_image(folder / "photo.jpg", np.random.default_rng(0).random((40, 40, 3)))
    jpeg = (folder / "photo.jpg").read_bytes()
    nan_target = np.full((40, 40, 3), 0.3)
    nan_target[3, 4] = np.nan
    sky = np.full((8, 16, 3), 0.5)
    sky[1, 1] = np.nan
    fit = {
        "color": [0.5, 0.5, 0.5],
        "smoothness": 0.5,
        "metalness": 0.0,
        "transparency": 0.0,
        "ior": 1.5,
        "free": ["smoothness"],
        "held": {},
        "residual": {},
    }
    files = {
        "scene.toml": SCENE.encode(),
        "target.exr": (folder / "target.exr").read_bytes(),
        "wide.exr": (folder / "wide.exr").read_bytes(),
        "small-mask.png": (folder / "small-mask.png").read_bytes(),
        "truncated.jpg": jpeg[: len(jpeg) // 2],
        "not-an-image.png": b"this is not an image at all",
        "nan-target.exr": raw_exr(nan_target),
        "nan-sky.exr": raw_exr(sky),
        "nan-sky.toml": NAN_SKY_SCENE.encode(),
        "bad.toml": b"[camera\nwidth = 3",
        "utf16.toml": SCENE.encode("utf-16"),
        "escape.toml": SCENE.replace("[camera]", '[camera]\n"\\u001b[31mred" = 1').encode(),
        "fit.json": json.dumps(fit).encode(),
        "not-a-fit.json": b'{"hello": 1}',
        "spec.toml": SYNTH_SPEC.encode(),
        "bad-spec.toml": b"seed = 1\nsparkle = 2\n",
        "lib.mtl": (DATA / "3dsmax.mtl").read_bytes(),
        "utf16.mtl": "newmtl a\nKd 0.5 0.5 0.5\n".encode("utf-16"),
        "empty.mtl": b"# nothing here\n",
        "strauss.json": b'{"color": [0.5, 0.5, 0.5], "smoothness": 0.5}',
        "out.json.partial": b'{"format": "strauss-fit progress", "version": 1, "key": "x"}\n',
    }
    chain = folder / "chain.h5"
    with h5py.File(chain, "w") as f:
        g = f.create_group("mcmc")
        g.attrs.update(iteration=3, nwalkers=4, ndim=1, has_blobs=False)
        g.create_dataset("chain", data=np.zeros((3, 4, 1)))
        g.create_dataset("log_prob", data=np.zeros((3, 4)))
        g.create_dataset("accepted", data=np.zeros(4))
        m = f.create_group("strauss_fit")
        m.attrs.update(format="strauss-fit chain", format_version=1, metadata="{}")
    files["empty-meta.h5"] = chain.read_bytes()
    files["not-a-chain.h5"] = b"garbage" * 20
    return files


def check(tmp_path, capsys, assets, argv, needs, code, message):
    for name in needs:
        (tmp_path / name).write_bytes(assets[name])
    (tmp_path / "exists.png").write_bytes(b"precious")
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    args = [a.replace("{tmp}", str(tmp_path)).replace("{data}", str(DATA)) for a in argv]
    got = main(args)
    err = capsys.readouterr().err
    assert got == code, err
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("strauss-fit: error: "), err
    assert message in lines[0], err
    assert "Traceback" not in err and "\x1b" not in err
    after = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    assert after == before  # nothing written, nothing overwritten, no temporary left
    assert sorted(p.name for p in tmp_path.iterdir() if p.is_dir()) == []


def rows(table):
    return pytest.mark.parametrize("argv,needs,code,message", [row[1:] for row in table], ids=[row[0] for row in table])


T = "{tmp}"
RENDER = [
    ("missing-scene", ["render", f"{T}/none.toml", "-o", f"{T}/x.exr"], [], 2, "scene file not found"),
    ("scene-is-a-folder", ["render", T, "-o", f"{T}/x.exr"], [], 2, "scene file is a directory"),
    ("not-toml", ["render", f"{T}/bad.toml", "-o", f"{T}/x.exr"], ["bad.toml"], 2, "not valid TOML"),
    ("utf16-scene", ["render", f"{T}/utf16.toml", "-o", f"{T}/x.exr"], ["utf16.toml"], 2, "cannot read scene file"),
    (
        "control-characters-escaped",
        ["render", f"{T}/escape.toml", "-o", f"{T}/x.exr"],
        ["escape.toml"],
        2,
        "\\x1b[31mred",
    ),
    (
        "nan-environment",
        ["render", f"{T}/nan-sky.toml", "-o", f"{T}/x.exr"],
        ["nan-sky.toml", "nan-sky.exr"],
        2,
        "nan-sky.exr has 1 pixel(s) with NaN or infinite values",
    ),
    (
        "unknown-format",
        ["render", f"{T}/scene.toml", "-o", f"{T}/x.xyz"],
        ["scene.toml"],
        2,
        "no image writer for .xyz",
    ),
    (
        "mask-unknown-format",
        ["render", f"{T}/scene.toml", "-o", f"{T}/x.exr", "--mask", f"{T}/m.xyz"],
        ["scene.toml"],
        2,
        "no image writer for .xyz",
    ),
    (
        "same-output-twice",
        ["render", f"{T}/scene.toml", "-o", f"{T}/x.png", "--mask", f"{T}/x.png"],
        ["scene.toml"],
        2,
        "-o and --mask name the same file",
    ),
    (
        "output-is-the-scene",
        ["render", f"{T}/scene.toml", "-o", f"{T}/scene.toml", "--force"],
        ["scene.toml"],
        2,
        "is the input SCENE",
    ),
    ("exists", ["render", f"{T}/scene.toml", "-o", f"{T}/exists.png"], ["scene.toml"], 2, "exists; pass --force"),
    ("no-folder", ["render", f"{T}/scene.toml", "-o", f"{T}/no/x.exr"], ["scene.toml"], 2, "folder does not exist"),
    (
        "width-beyond-8192",
        ["render", f"{T}/scene.toml", "-o", f"{T}/x.exr", "--width", "100000", "--height", "1"],
        ["scene.toml"],
        2,
        "argument --width: expected an integer from 1 to 8192, got 100000",
    ),
    ("width-zero", ["render", f"{T}/s.toml", "-o", f"{T}/x.exr", "--width", "0"], [], 2, "from 1 to 8192, got 0"),
    ("width-words", ["render", f"{T}/s.toml", "-o", f"{T}/x.exr", "--width", "ten"], [], 2, "expected an integer"),
    ("depth-65", ["render", f"{T}/scene.toml", "-o", f"{T}/x.exr", "--depth", "65"], [], 2, "from 1 to 64"),
    ("table-size-1", ["render", f"{T}/s.toml", "-o", f"{T}/x.exr", "--table-size", "1"], [], 2, "at least 2"),
    (
        "j-table-too-big",
        ["render", f"{T}/s.toml", "-o", f"{T}/x.exr", "--mode", "j-table", "--table-size", "100000"],
        [],
        2,
        "--table-size must be at most 4096 with --mode j-table",
    ),
    ("unknown-option", ["render", f"{T}/s.toml", "-o", f"{T}/x.exr", "--bogus"], [], 2, "unrecognized arguments"),
]


@rows(RENDER)
def test_render(tmp_path, capsys, assets, argv, needs, code, message):
    check(tmp_path, capsys, assets, argv, needs, code, message)


FIT_BASE = ["fit", f"{T}/target.exr", "--scene", f"{T}/scene.toml", "-o", f"{T}/r.json"]
FIT_NEEDS = ["target.exr", "scene.toml"]
FIT = [
    (
        "missing-target",
        ["fit", f"{T}/none.exr", "--scene", f"{T}/scene.toml", "-o", f"{T}/r.json"],
        ["scene.toml"],
        2,
        "image not found",
    ),
    (
        "truncated-jpeg",
        ["fit", f"{T}/truncated.jpg", "--scene", f"{T}/scene.toml", "-o", f"{T}/r.json"],
        ["truncated.jpg", "scene.toml"],
        2,
        "Premature end of JPEG file",
    ),
    (
        "not-an-image",
        ["fit", f"{T}/not-an-image.png", "--scene", f"{T}/scene.toml", "-o", f"{T}/r.json"],
        ["not-an-image.png", "scene.toml"],
        2,
        "cannot read image",
    ),
    (
        "nan-target",
        ["fit", f"{T}/nan-target.exr", "--scene", f"{T}/scene.toml", "-o", f"{T}/r.json"],
        ["nan-target.exr", "scene.toml"],
        2,
        "has 1 pixel(s) with NaN or infinite values",
    ),
    (
        "nan-environment-before-any-work",
        ["fit", f"{T}/target.exr", "--scene", f"{T}/nan-sky.toml", "-o", f"{T}/r.json"],
        ["target.exr", "nan-sky.toml", "nan-sky.exr"],
        2,
        "NaN or infinite values",
    ),
    (
        "other-aspect-ratio",
        ["fit", f"{T}/wide.exr", "--scene", f"{T}/scene.toml", "-o", f"{T}/r.json"],
        ["wide.exr", "scene.toml"],
        2,
        "different aspect ratio",
    ),
    ("mask-size", FIT_BASE + ["--mask", f"{T}/small-mask.png"], FIT_NEEDS + ["small-mask.png"], 2, "is 10x10 but"),
    ("render-fit-unknown-format", FIT_BASE + ["--render-fit", f"{T}/f.xyz"], FIT_NEEDS, 2, "no image writer for .xyz"),
    ("render-fit-is-result", FIT_BASE + ["--render-fit", f"{T}/r.json"], FIT_NEEDS, 2, "name the same file"),
    (
        "result-is-the-target",
        ["fit", f"{T}/target.exr", "--scene", f"{T}/scene.toml", "-o", f"{T}/target.exr", "--force"],
        FIT_NEEDS,
        2,
        "is the input TARGET",
    ),
    ("max-steps-overflow", FIT_BASE + ["--max-steps", "99999999999999999999"], [], 2, "expected an integer from 1"),
    ("starts-zero", FIT_BASE + ["--starts", "0"], [], 2, "expected an integer from 1"),
    ("reference-noise-negative", FIT_BASE + ["--reference-noise", "-1"], [], 2, "expected a number > 0, got -1"),
    ("reference-noise-nan", FIT_BASE + ["--reference-noise", "nan"], [], 2, "expected a finite number, got nan"),
    ("fix-color-two", FIT_BASE + ["--fix", "color=1,2"], [], 2, "--fix color expects R,G,B"),
    ("fix-nan", FIT_BASE + ["--fix", "smoothness=nan"], [], 2, "is not a finite number"),
    ("fix-out-of-range", FIT_BASE + ["--fix", "smoothness=2"], [], 2, "smoothness = 2.0 is outside its range"),
    ("unknown-free", FIT_BASE + ["--free", "bogus"], FIT_NEEDS, 2, "cannot free unknown parameter(s) bogus"),
    ("exists", FIT_BASE[:-1] + [f"{T}/exists.png"], FIT_NEEDS, 2, "exists; pass --force"),
]


@rows(FIT)
def test_fit(tmp_path, capsys, assets, argv, needs, code, message):
    check(tmp_path, capsys, assets, argv, needs, code, message)


SYNTH = [
    ("missing-spec", ["synth", f"{T}/none.toml", "-o", f"{T}/out"], [], 2, "dataset spec not found"),
    ("not-toml", ["synth", f"{T}/bad.toml", "-o", f"{T}/out"], ["bad.toml"], 2, "not valid TOML"),
    ("unknown-key", ["synth", f"{T}/bad-spec.toml", "-o", f"{T}/out"], ["bad-spec.toml"], 2, "unknown key(s) sparkle"),
    ("seed-negative", ["synth", f"{T}/spec.toml", "-o", f"{T}/out", "--seed", "-1"], [], 2, "from 0 to"),
    ("limit-zero", ["synth", f"{T}/spec.toml", "-o", f"{T}/out", "--limit", "0"], [], 2, "from 1 to"),
    ("output-is-a-file", ["synth", f"{T}/spec.toml", "-o", f"{T}/exists.png"], ["spec.toml"], 2, "is not a folder"),
    ("force-and-resume", ["synth", f"{T}/spec.toml", "-o", f"{T}/o", "--force", "--resume"], [], 2, "not allowed"),
]


@rows(SYNTH)
def test_synth(tmp_path, capsys, assets, argv, needs, code, message):
    check(tmp_path, capsys, assets, argv, needs, code, message)


def test_synth_refuses_a_folder_that_is_not_its_dataset(tmp_path, capsys, assets):
    (tmp_path / "spec.toml").write_bytes(assets["spec.toml"])
    folder = tmp_path / "out"
    folder.mkdir()
    (folder / "mine.txt").write_text("mine")
    assert main(["synth", str(tmp_path / "spec.toml"), "-o", str(folder)]) == 2
    assert "is not empty" in capsys.readouterr().err
    assert main(["synth", str(tmp_path / "spec.toml"), "-o", str(folder), "--resume"]) == 2
    assert "has no index.json" in capsys.readouterr().err
    assert [p.name for p in folder.iterdir()] == ["mine.txt"]


SAMPLE_BASE = ["sample", f"{T}/target.exr", "--scene", f"{T}/scene.toml", "-o", f"{T}/c.h5"]
SAMPLE = [
    ("sigma-zero", SAMPLE_BASE + ["--sigma", "0"], [], 2, "argument --sigma: expected a number > 0"),
    ("sigma-nan", SAMPLE_BASE + ["--sigma", "nan"], [], 2, "expected a finite number"),
    ("walkers-odd", SAMPLE_BASE + ["--walkers", "3"], [], 2, "--walkers must be even"),
    ("walkers-huge", SAMPLE_BASE + ["--walkers", "1000000000"], [], 2, "from 1 to 100000"),
    ("max-steps-overflow", SAMPLE_BASE + ["--max-steps", "1" + "0" * 20], [], 2, "expected an integer from 1"),
    ("tau-multiple-zero", SAMPLE_BASE + ["--min-tau-multiple", "0"], [], 2, "expected a number > 0"),
    ("seed-too-large", SAMPLE_BASE + ["--seed", str(2**40)], [], 2, "from 0 to 4294967295"),
    ("prior-reversed", SAMPLE_BASE + ["--prior", "smoothness=0.9,0.1"], [], 2, "LOW < HIGH"),
    ("resume-and-force", SAMPLE_BASE + ["--resume", "--force"], [], 2, "give one of them"),
    (
        "resume-without-chain",
        SAMPLE_BASE + ["--resume"],
        FIT_NEEDS,
        2,
        "chain file not found",
    ),
    (
        "resume-a-damaged-chain",
        ["sample", f"{T}/target.exr", "--scene", f"{T}/scene.toml", "-o", f"{T}/empty-meta.h5", "--resume"],
        FIT_NEEDS + ["empty-meta.h5"],
        2,
        "metadata is damaged",
    ),
    (
        "resume-not-a-chain",
        ["sample", f"{T}/target.exr", "--scene", f"{T}/scene.toml", "-o", f"{T}/not-a-chain.h5", "--resume"],
        FIT_NEEDS + ["not-a-chain.h5"],
        2,
        "not an HDF5 file",
    ),
    ("chain-named-json", SAMPLE_BASE[:-1] + [f"{T}/c.json"], FIT_NEEDS, 2, "name the same file"),
    (
        "not-a-fit",
        SAMPLE_BASE + ["--fit", f"{T}/not-a-fit.json"],
        FIT_NEEDS + ["not-a-fit.json"],
        2,
        "not a strauss-fit fit",
    ),
    ("fit-and-free", SAMPLE_BASE + ["--fit", f"{T}/fit.json", "--free", "color"], [], 2, "applies only when"),
    (
        "truncated-target",
        ["sample", f"{T}/truncated.jpg", "--scene", f"{T}/scene.toml", "-o", f"{T}/c.h5", "--fit", f"{T}/fit.json"],
        ["truncated.jpg", "scene.toml", "fit.json"],
        2,
        "Premature end",
    ),
]


@rows(SAMPLE)
def test_sample(tmp_path, capsys, assets, argv, needs, code, message):
    check(tmp_path, capsys, assets, argv, needs, code, message)


REPORT = [
    ("nothing", ["report", "-o", f"{T}/r.html"], [], 2, "give a fit result"),
    ("not-html", ["report", "--fit", f"{T}/fit.json", "-o", f"{T}/r.pdf"], ["fit.json"], 2, "give -o a .html name"),
    ("fit-missing", ["report", "--fit", f"{T}/none.json", "-o", f"{T}/r.html"], [], 2, "fit result not found"),
    (
        "not-a-fit",
        ["report", "--fit", f"{T}/not-a-fit.json", "-o", f"{T}/r.html"],
        ["not-a-fit.json"],
        2,
        "not a strauss-fit fit result",
    ),
    (
        "chain-garbage",
        ["report", "--chain", f"{T}/not-a-chain.h5", "-o", f"{T}/r.html"],
        ["not-a-chain.h5"],
        2,
        "not an HDF5 file",
    ),
    (
        "chain-empty-metadata",
        ["report", "--chain", f"{T}/empty-meta.h5", "-o", f"{T}/r.html"],
        ["empty-meta.h5"],
        2,
        "metadata is damaged",
    ),
    ("no-target-recorded", ["report", "--fit", f"{T}/fit.json", "-o", f"{T}/r.html"], ["fit.json"], 2, "give --target"),
    (
        "truncated-target",
        [
            "report",
            "--fit",
            f"{T}/fit.json",
            "--target",
            f"{T}/truncated.jpg",
            "--scene",
            f"{T}/scene.toml",
            "-o",
            f"{T}/r.html",
        ],
        ["fit.json", "truncated.jpg", "scene.toml"],
        2,
        "Premature end of JPEG file",
    ),
]


@rows(REPORT)
def test_report(tmp_path, capsys, assets, argv, needs, code, message):
    check(tmp_path, capsys, assets, argv, needs, code, message)


CONVERT = [
    (
        "files-and-pairs",
        ["phong2strauss", f"{T}/lib.mtl", "kd=0.5", "-o", f"{T}/o.json"],
        ["lib.mtl"],
        2,
        "is a file but other inputs are not",
    ),
    (
        "utf16-mtl",
        ["phong2strauss", f"{T}/utf16.mtl", "-o", f"{T}/o.json"],
        ["utf16.mtl"],
        2,
        "is UTF-16 text, not UTF-8",
    ),
    ("empty-mtl", ["phong2strauss", f"{T}/empty.mtl", "-o", f"{T}/o.json"], ["empty.mtl"], 2, "holds no material"),
    ("missing-input", ["phong2strauss", f"{T}/none.mtl", "-o", f"{T}/o.json"], [], 2, "input not found"),
    (
        "output-is-the-input",
        ["strauss2phong", f"{T}/strauss.json", "-o", f"{T}/strauss.json", "--force"],
        ["strauss.json"],
        2,
        "is the input",
    ),
    (
        "unfinished-run",
        ["strauss2phong", f"{T}/strauss.json", "-o", f"{T}/out.json"],
        ["strauss.json", "out.json.partial"],
        2,
        "holds an interrupted conversion",
    ),
    (
        "resume-nothing",
        ["strauss2phong", f"{T}/strauss.json", "-o", f"{T}/o.json", "--resume"],
        ["strauss.json"],
        2,
        "nothing to resume",
    ),
    (
        "resume-another-run",
        ["strauss2phong", f"{T}/strauss.json", "-o", f"{T}/out.json", "--resume", "--size", "4"],
        ["strauss.json", "out.json.partial"],
        2,
        "progress of another run",
    ),
    ("resume-and-force", ["strauss2phong", "s=0.5", "-o", f"{T}/o.json", "--resume", "--force"], [], 2, "not allowed"),
    ("size-three", ["strauss2phong", "s=0.5", "-o", f"{T}/o.json", "--size", "3"], [], 2, "at least 4 pixels"),
    ("size-huge", ["strauss2phong", "s=0.5", "-o", f"{T}/o.json", "--size", "100000"], [], 2, "from 1 to 8192"),
    (
        "mtl-into-strauss2phong",
        ["strauss2phong", f"{T}/lib.mtl", "-o", f"{T}/o.json"],
        ["lib.mtl"],
        2,
        "expected .json or .csv",
    ),
    ("phong-mtl-output", ["phong2strauss", "kd=0.5", "-o", f"{T}/o.mtl"], [], 2, "expected .json or .csv"),
    ("nan-value", ["phong2strauss", "kd=nan", "-o", f"{T}/o.json"], [], 2, "must be finite"),
    (
        "escaped-name",
        ["phong2strauss", "name=\x1b[2Jbad", "kd=2,1", "-o", f"{T}/o.json"],
        [],
        2,
        "must be 1 number or 3",
    ),
    ("starts-overflow", ["strauss2phong", "s=0.5", "-o", f"{T}/o.json", "--starts", "9" * 30], [], 2, "from 1 to"),
]


@rows(CONVERT)
def test_conversions(tmp_path, capsys, assets, argv, needs, code, message):
    check(tmp_path, capsys, assets, argv, needs, code, message)


STUDY = [
    ("seed-negative", ["study", "-o", f"{T}/out", "--seed", "-1"], [], 2, "--seed must be >= 0"),
    ("output-is-a-file", ["study", "-o", f"{T}/exists.png"], [], 2, "is not a folder"),
    ("no-parent", ["study", "-o", f"{T}/a/b"], [], 2, "parent does not exist"),
    ("unknown-size", ["study", "-o", f"{T}/out", "--size", "huge"], [], 2, "invalid choice: 'huge'"),
]


@rows(STUDY)
def test_study(tmp_path, capsys, assets, argv, needs, code, message):
    check(tmp_path, capsys, assets, argv, needs, code, message)


def test_study_refuses_to_overwrite_before_running(tmp_path, capsys):
    folder = tmp_path / "out"
    folder.mkdir()
    (folder / "study.json").write_text("{}")
    assert main(["study", "-o", str(folder), "--size", "tiny"]) == 2
    assert "exists; pass --force" in capsys.readouterr().err
    assert [p.name for p in folder.iterdir()] == ["study.json"]


def test_every_help_says_what_the_quality_presets_use(capsys):
    from strauss_fit.fitting.options import QUALITY_PRESETS

    for command, setting in (
        ("fit", "starts"),
        ("fit", "max_steps"),
        ("phong2strauss", "starts"),
        ("strauss2phong", "starts"),
        ("sample", "sample_max_steps"),
    ):
        assert main([command, "--help"]) == 0
        text = " ".join(capsys.readouterr().out.split())
        wanted = ", ".join(f"{name} {values[setting]:g}" for name, values in QUALITY_PRESETS.items())
        assert wanted in text, (command, setting)
    assert "4" not in str(QUALITY_PRESETS["balanced"]["starts"])  # the old help said 4 for balanced


del SCENES  # imported for the scenes' folder only
