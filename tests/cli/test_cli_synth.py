"""``strauss-fit synth`` end to end: resuming damaged and limited runs, a full disk, --force
and --resume, and one-line errors for bad specs."""

import errno

import pytest

import data_synth.files
import strauss_fit.io.files
from data_synth import read_index
from strauss_fit_cli.main import main
from support import SYNTH_SPEC, files_of, write_spec
from support import SYNTH_TOTAL as TOTAL


def run_cli(capsys, *argv):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_resume_redoes_damaged_samples_and_skips_intact_ones(tmp_path, reference, capsys):
    spec_path, out = reference
    folder = tmp_path / "copy"
    folder.mkdir()
    for name, data in files_of(out).items():
        (folder / name).write_bytes(data)
    (folder / "p-0002.exr").write_bytes(b"corrupt")
    (folder / "s-0001.png").unlink()
    code, stdout, err = run_cli(capsys, "synth", spec_path, "-o", folder, "--resume")
    assert code == 0 and "wrote 2 sample(s)" in stdout and f"{TOTAL - 2} already complete" in stdout
    assert err.count("synth: [") == 2
    assert files_of(folder) == files_of(out)


def test_full_disk_is_one_line_and_leaves_a_consistent_index(tmp_path, reference, capsys, monkeypatch):
    spec_path, out = reference
    folder = tmp_path / "full"
    calls = {"n": 0}
    real = strauss_fit.io.files._write_file

    def filling_disk(path, data):
        calls["n"] += 1
        if calls["n"] >= 12:
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        real(path, data)

    monkeypatch.setattr(strauss_fit.io.files, "_write_file", filling_disk)
    code, _, err = run_cli(capsys, "synth", spec_path, "-o", folder, "--quiet")
    assert code == 2
    assert err.startswith("strauss-fit: error: ") and err.count("\n") == 1 and "Traceback" not in err
    assert "No space left on device" in err and "samples are complete" in err and "--resume" in err
    index = read_index(folder)
    assert 0 < index["complete"] < TOTAL and f"{index['complete']} of {TOTAL}" in err
    for entry in index["samples"]:  # every listed sample is whole
        for name, digest in entry["sha256"].items():
            assert data_synth.files.sha256(folder / name) == digest
    monkeypatch.undo()
    assert run_cli(capsys, "synth", spec_path, "-o", folder, "--resume")[0] == 0
    assert files_of(folder) == files_of(out)


def test_limit_then_resume_and_progress_lines(tmp_path, reference, capsys):
    spec_path, out = reference
    folder = tmp_path / "limited"
    code, stdout, err = run_cli(capsys, "synth", spec_path, "-o", folder, "--limit", "4")
    assert code == 0 and f"4 of {TOTAL} complete" in stdout and "--resume" in stdout
    assert [line.split()[1] for line in err.splitlines()] == ["[1/13]", "[2/13]", "[3/13]", "[4/13]"]
    code, stdout, _ = run_cli(capsys, "synth", spec_path, "-o", folder, "--resume", "--quiet")
    assert code == 0 and f"{TOTAL} of {TOTAL} complete" in stdout
    assert files_of(folder) == files_of(out)


def test_force_replaces_only_the_old_dataset(tmp_path, capsys):
    spec_path = write_spec(tmp_path)
    folder = tmp_path / "out"
    assert run_cli(capsys, "synth", spec_path, "-o", folder, "--quiet")[0] == 0
    (folder / "notes.txt").write_text("mine")
    code, _, _ = run_cli(
        capsys, "synth", spec_path.parent / spec_path.name, "-o", folder, "--force", "--seed", "9", "--quiet"
    )
    assert code == 0
    index = read_index(folder)
    assert index["seed"] == 9 and (folder / "notes.txt").read_text() == "mine"
    listed = {name for e in index["samples"] for name in e["files"].values()}
    assert {p.name for p in folder.iterdir()} == listed | {"index.json", "notes.txt"}


BAD_SPECS = [
    (
        SYNTH_SPEC.replace('model = "phong"', 'model = "ward"'),
        "unknown model 'ward'; expected one of strauss, phong, lambert, blinn-phong, cook-torrance",
    ),
    (  # a registry model: its own parameters, not the classic Phong's
        SYNTH_SPEC.replace('model = "phong"', 'model = "cook-torrance"'),
        "unknown cook-torrance parameter(s) diffuse_color, exponent; expected kd, f0, roughness",
    ),
    (
        SYNTH_SPEC.replace("smoothness = { low = 0.0, high = 1.0 }", "smoothness = { low = 0.0, high = 1.5 }"),
        "parameters: smoothness = 1.5 is outside its range [0, 1]",
    ),
    (
        SYNTH_SPEC.replace("exponent = [5.0, 50.0]", "exponent = [5.0, 20000.0]"),
        "exponent = 20000.0 is outside its range [0, 10000]",
    ),
    (
        SYNTH_SPEC.replace("diffuse_color = [0.1, 0.2, 0.30000000000000004]", "diffuse_color = [0.1, 1.2, 0.3]"),
        "diffuse_color = [0.1, 1.2, 0.3] is outside its range [0, 1]",
    ),
    (
        SYNTH_SPEC.replace("exponent = [5.0, 50.0]", "exponent = { low = 5.0, high = 50.0 }"),
        "a range in a grid needs steps",
    ),
    (SYNTH_SPEC.replace("transparency = 0.0", "shininess = 3.0"), "unknown strauss parameter(s) shininess"),
    (SYNTH_SPEC.replace("read_noise = 0.01", "read_noise = -0.01"), "sensor read_noise = -0.01 must be >= 0"),
    (SYNTH_SPEC.replace("two_lights.toml", "nowhere.toml"), "scene file not found"),
    (SYNTH_SPEC.replace('formats = ["exr"]', 'formats = ["tiff"]'), "formats must be a non-empty list"),
    (SYNTH_SPEC.replace("count = 1", "count = -1"), "count must be an integer in [0, 100000]"),
    (SYNTH_SPEC.replace('name = "p"', 'name = "s"'), "name 's' is used by another group"),
    (SYNTH_SPEC + "\n[oops\n", "not valid TOML"),
]


@pytest.mark.parametrize("text,message", BAD_SPECS)
def test_bad_specs_are_one_line_errors_and_write_nothing(tmp_path, capsys, text, message):
    spec_path = write_spec(tmp_path, text)
    code, stdout, err = run_cli(capsys, "synth", spec_path, "-o", tmp_path / "out")
    assert code == 2 and stdout == ""
    assert err.startswith("strauss-fit: error: ") and err.count("\n") == 1 and "Traceback" not in err
    assert message in err
    assert not (tmp_path / "out").exists()


def test_missing_spec_and_existing_output(tmp_path, capsys, reference):
    code, _, err = run_cli(capsys, "synth", tmp_path / "missing.toml", "-o", tmp_path / "out")
    assert code == 2 and "dataset spec not found" in err and err.count("\n") == 1
    spec_path, _ = reference
    folder = tmp_path / "existing"
    folder.mkdir()
    (folder / "keep.exr").write_bytes(b"precious")
    code, _, err = run_cli(capsys, "synth", spec_path, "-o", folder)
    assert code == 2 and err.count("\n") == 1
    assert "is not empty; pass --resume to continue the dataset in it or --force to replace it" in err
    assert [p.name for p in folder.iterdir()] == ["keep.exr"] and (folder / "keep.exr").read_bytes() == b"precious"
    code, _, err = run_cli(capsys, "synth", spec_path, "-o", folder, "--resume")
    assert code == 2 and "cannot resume" in err and [p.name for p in folder.iterdir()] == ["keep.exr"]


def test_resume_refuses_another_spec(tmp_path, capsys):
    spec_path = write_spec(tmp_path)
    folder = tmp_path / "out"
    assert run_cli(capsys, "synth", spec_path, "-o", folder, "--limit", "1", "--quiet")[0] == 0
    before = files_of(folder)
    changed = write_spec(
        tmp_path, SYNTH_SPEC.replace("exponent = [5.0, 50.0]", "exponent = [5.0, 60.0]"), "changed.toml"
    )
    code, _, err = run_cli(capsys, "synth", changed, "-o", folder, "--resume")
    assert code == 2 and "another spec or seed" in err and err.count("\n") == 1
    assert files_of(folder) == before


def test_force_and_resume_exclude_each_other(tmp_path, capsys):
    assert main(["synth", str(write_spec(tmp_path)), "-o", str(tmp_path / "o"), "--force", "--resume"]) == 2
    assert "not allowed with argument" in capsys.readouterr().err


def write_raw_exr(path, pixels):
    """An EXR holding exactly ``pixels`` (NaN included: the library refuses to write one)."""
    import numpy as np
    import OpenImageIO as oiio

    data = np.asarray(pixels, dtype=np.float32)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), oiio.ImageSpec(data.shape[1], data.shape[0], 3, oiio.FLOAT))
    assert out.write_image(data)
    out.close()


BAD_ITEM_SPEC = """
seed = 3

[[group]]
name = "g"
model = "strauss"
scenes = ["good.toml", "nan-sky.toml"]
size = [12, 12]
formats = ["exr"]

[group.parameters]
smoothness = [0.2, 0.8]
"""


def test_one_bad_scene_fails_its_samples_only_and_resume_does_the_same(tmp_path, capsys):
    import numpy as np

    from support import SCENES

    sky = np.full((8, 16, 3), 0.5)
    sky[2, 3] = np.nan
    write_raw_exr(tmp_path / "sky.exr", sky)
    scene = (SCENES / "two_lights.toml").read_text().split("[background]")[0]
    (tmp_path / "good.toml").write_text(scene)
    (tmp_path / "nan-sky.toml").write_text(scene + '\n[background]\nkind = "environment"\nimage = "sky.exr"\n')
    spec = write_spec(tmp_path, BAD_ITEM_SPEC)
    out = tmp_path / "out"
    for resume in (False, True):
        code, stdout, err = run_cli(capsys, "synth", spec, "-o", out, *(["--resume"] if resume else []))
        assert code == 1, err
        assert "Traceback" not in err
        # said before any work, then once per sample skipped
        assert err.startswith("synth: warning: group g: 2 sample(s) will be skipped: ")
        assert "sky.exr has 1 pixel(s) with NaN or infinite values" in err.splitlines()[0]
        assert err.count("FAILED") == 2 and "g-0001 FAILED" in err and "g-0003 FAILED" in err
        assert "2 failed" in stdout and "2 of 4 complete" in stdout
        index = read_index(out)
        assert [s["id"] for s in index["samples"]] == ["g-0000", "g-0002"]
        assert index["pending"] == ["g-0001", "g-0003"]
        assert sorted(p.name for p in out.iterdir()) == [
            "g-0000.exr",
            "g-0000.json",
            "g-0002.exr",
            "g-0002.json",
            "index.json",
        ]
        if not resume:
            first = files_of(out)
    assert files_of(out) == first  # the resumed run changed nothing that was complete
