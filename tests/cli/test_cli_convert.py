"""``strauss-fit phong2strauss`` and ``strauss2phong`` end to end: both directions and every
output format, a batch with a broken material, and one-line errors."""

import csv
import io
import json
from pathlib import Path

import pytest

from strauss_fit.io.material_tables import read_phong_input
from strauss_fit.io.mtl import read_mtl
from strauss_fit_cli.main import main

SIZE = 24  # as the conversion's unit tests, so that compiled solvers are shared


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_commands_convert_both_ways_and_write_every_format(tmp_path, capsys):
    forward = tmp_path / "strauss.json"
    code, out, err = run(
        capsys,
        "phong2strauss",
        "kd=0.6",
        "ks=0.25",
        "n=8",
        "Cd=0.9,0.45,0.2",
        "name=clay",
        "-o",
        forward,
        "--size",
        SIZE,
    )
    assert code == 0, err
    document = json.loads(forward.read_text())
    assert document["format"] == "strauss-fit phong2strauss" and document["summary"]["converted"] == 1
    material = document["materials"][0]
    assert material["status"] == "ok" and set(material["strauss"]) == {
        "color",
        "smoothness",
        "metalness",
        "transparency",
        "ior",
    }
    assert {"rms", "delta_e2000_mean", "delta_e2000_p95"} <= set(material["residual"])
    assert "[1/1] clay: ok" in err and "clay" in out

    back_csv = tmp_path / "phong.csv"
    code, out, err = run(capsys, "strauss2phong", forward, "-o", back_csv, "--size", SIZE, "--quiet")
    assert code == 0, err
    rows = list(csv.DictReader(io.StringIO(back_csv.read_text())))
    assert rows[0]["name"] == "clay" and rows[0]["status"] == "ok" and float(rows[0]["exponent"]) > 1
    assert float(rows[0]["delta_e2000_mean"]) < 1.0
    # the CSV output is a valid Phong input
    again, _, _ = read_phong_input([str(back_csv)])
    assert again[0].error is None and float(again[0].material.kd) == pytest.approx(float(rows[0]["kd"]))

    back_mtl = tmp_path / "phong.mtl"
    code, out, err = run(capsys, "strauss2phong", forward, "-o", back_mtl, "--size", SIZE, "--quiet")
    assert code == 0, err
    library = read_mtl(back_mtl)
    assert [m.name for m in library.materials] == ["clay"] and library.materials[0].error is None


def test_mtl_batch_with_a_broken_material_exits_1_and_keeps_the_rest(tmp_path, capsys):
    library = tmp_path / "lib.mtl"
    library.write_text("newmtl good\nKd 0.6 0.3 0.2\nKs 0.3 0.3 0.3\nNs 10\n\nnewmtl steel\nKd 0.5 0.5\n")
    output = tmp_path / "out.csv"
    code, out, err = run(capsys, "phong2strauss", library, "-o", output, "--size", SIZE)
    assert code == 1
    rows = list(csv.DictReader(io.StringIO(output.read_text())))
    assert [r["status"] for r in rows] == ["ok", "error"]
    assert rows[1]["message"] == "material 'steel' line 7: Kd needs 3 numbers (or 1 for grey), got 'Kd 0.5 0.5'"
    assert "1 of 2 material(s) converted, 1 failed" in out


@pytest.mark.parametrize(
    "argv, message",
    [
        (["phong2strauss", "kd=0.5", "sparkle=1", "-o", "{tmp}/o.json"], "unknown Phong key 'sparkle'"),
        (["phong2strauss", "kd=2,1", "-o", "{tmp}/o.json"], "must be 1 number or 3"),
        (["phong2strauss", "{tmp}/missing.mtl", "-o", "{tmp}/o.json"], "input not found"),
        (["phong2strauss", "kd=0.5", "-o", "{tmp}/o.txt"], "unknown output format .txt"),
        (["phong2strauss", "kd=0.5", "-o", "{tmp}/o.mtl"], "expected .json or .csv"),
        (["strauss2phong", "s=1.5", "-o", "{tmp}/o.json"], "smoothness = 1.5 is outside its range"),
        (["strauss2phong", "s=0.5", "-o", "{tmp}/exists.json"], "exists; pass --force"),
        (["strauss2phong", "s=0.5", "--scene", "{tmp}/none.toml", "-o", "{tmp}/o.json"], "scene file not found"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, argv, message):
    (tmp_path / "exists.json").write_text("{}")
    code, out, err = run(capsys, *[a.replace("{tmp}", str(tmp_path)) for a in argv])
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("strauss-fit: error:") and message in lines[0]
    assert not (tmp_path / "o.json").exists()


# --- issue 14: exporters' libraries, names kept, black, presets, resume ---------------------------

DATA = Path(__file__).resolve().parent.parent / "data" / "mtl"
FAST = ["--size", SIZE]


def test_library_default_settings_are_the_command_lines_default(tmp_path, capsys):
    from strauss_fit.convert.converter import Settings
    from strauss_fit.fitting.options import DEFAULT_QUALITY, QUALITY_PRESETS

    assert Settings() == Settings.preset() == Settings.preset(DEFAULT_QUALITY)
    assert Settings().starts == QUALITY_PRESETS[DEFAULT_QUALITY]["starts"]
    out = tmp_path / "black.json"
    code, stdout, err = run(capsys, "strauss2phong", "C=0", "s=0", "m=1", "-o", out, "--size", SIZE)
    assert code == 0, err
    document = json.loads(out.read_text())
    assert document["settings"] == Settings().as_dict()
    # Strauss's darkest material (what phong2strauss gives for kd = ks = 0) is not fitted:
    # it renders below an 8-bit image's first step, and Phong black comes back at once
    result = document["materials"][0]
    assert result["solver"]["status"] == "not run" and "renders black" in " ".join(result["notes"])
    assert result["phong"]["kd"] == 0.0 and result["phong"]["ks"] == 0.0


def test_exporters_names_survive_a_round_trip_and_usemtl_still_matches(tmp_path, capsys):
    forward, back = tmp_path / "strauss.json", tmp_path / "phong.mtl"
    inputs = [DATA / "3dsmax.mtl", DATA / "assimp.mtl"]  # several files; names with spaces and '#'
    code, _, err = run(capsys, "phong2strauss", *inputs, "-o", forward, *FAST, "--quiet")
    assert code == 0, err
    code, _, err = run(capsys, "strauss2phong", forward, "-o", back, *FAST, "--quiet")
    assert code == 0, err
    assert "written as" not in err  # nothing renamed
    names = [m.name for m in read_mtl(back).materials]
    assert names == ["01 - Default", "02 - Brick Wall", "Glass", "DefaultMaterial", "Material #112", "Material #113"]
    obj = "mtllib phong.mtl\nusemtl 01 - Default\nf 1 2 3\nusemtl Material #112\nf 1 3 4\n"
    used = [line.split(None, 1)[1] for line in obj.splitlines() if line.startswith("usemtl")]
    assert set(used) <= set(names)
    glass = json.loads(forward.read_text())["materials"][2]
    assert glass["name"] == "Glass" and glass["strauss"]["transparency"] == pytest.approx(0.9)


def test_input_warnings_are_shown_even_when_quiet_and_kept_in_the_output(tmp_path, capsys):
    out = tmp_path / "blender.json"
    code, _, err = run(capsys, "phong2strauss", DATA / "blender.mtl", "-o", out, *FAST, "--quiet")
    assert code == 0, err
    assert err.startswith("phong2strauss: warning: Wood: line 21: d 0 makes the material fully transparent")
    wood = json.loads(out.read_text())["materials"][1]
    assert wood["notes"][0].startswith("warning: line 21: d 0")


# More materials than two conversion chunks (strauss_fit.convert.converter.CHUNK, 32): the
# results reach the progress file a chunk at a time, so a kill must land between chunks,
# before the last one (with a single chunk the run could finish between two polls).
LIBRARY_SIZE = 72
LIBRARY = "".join(
    f"newmtl m{i:02d}\nKd {0.1 + 0.8 * (i % 7) / 7:.3f} 0.3 0.2\nKs 0.2 0.2 0.2\nNs {5 + 3 * (i % 24)}\n"
    for i in range(LIBRARY_SIZE)
)


def without_wall_time(path):
    document = json.loads(path.read_text())
    document.pop("wall_time_s")
    return document


def test_a_killed_conversion_resumes_to_what_an_uninterrupted_run_writes(tmp_path, capsys):
    import signal
    import subprocess
    import sys
    import time

    library = tmp_path / "lib.mtl"
    library.write_text(LIBRARY)
    whole = tmp_path / "whole.json"
    assert run(capsys, "phong2strauss", library, "-o", whole, *FAST, "--quiet")[0] == 0

    out = tmp_path / "out.json"
    partial = tmp_path / "out.json.partial"
    command = Path(sys.executable).parent / "strauss-fit"
    process = subprocess.Popen(
        [str(command), "phong2strauss", str(library), "-o", str(out), *map(str, FAST), "--quiet"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and process.poll() is None:
        if partial.exists() and partial.read_bytes().count(b"\n") >= 6:  # header + 5 results
            break
        time.sleep(0.01)
    process.send_signal(signal.SIGKILL)
    process.wait()
    assert not out.exists() and partial.exists(), "the conversion finished before it could be killed"
    with open(partial, "ab") as handle:  # as if killed in the middle of an append
        handle.write(b'{"index": 99, "elapsed_s": 1.0, "result": {"name": "m')
    kept = partial.read_bytes().count(b"\n") - 1

    code, _, err = run(capsys, "phong2strauss", library, "-o", out, *FAST, "--quiet")
    assert code == 2 and "holds an interrupted conversion" in err and "--resume" in err
    code, _, err = run(capsys, "phong2strauss", library, "-o", out, *FAST, "--starts", "1", "--resume", "--quiet")
    assert code == 2 and "progress of another run" in err  # other settings
    code, _, err = run(capsys, "phong2strauss", library, "-o", out, *FAST, "--resume")
    assert code == 0, err
    assert f"resuming: {kept} of {LIBRARY_SIZE} material(s) done before" in err
    assert f"[{kept + 1}/{LIBRARY_SIZE}]" in err and f"[1/{LIBRARY_SIZE}]" not in err
    assert not partial.exists()
    assert without_wall_time(out) == without_wall_time(whole)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lib.mtl", "out.json", "whole.json"]


def test_control_characters_from_a_library_are_escaped_on_the_terminal(tmp_path, capsys):
    library = tmp_path / "esc.mtl"
    library.write_bytes(b"newmtl red\x1b[31m alert\nKd 0.5 0.5\nd 0\n")
    code, out, err = run(capsys, "phong2strauss", library, "-o", tmp_path / "o.json", "--size", SIZE)
    assert code == 1  # its one material is broken: reported, the output written
    assert "\x1b" not in out + err
    assert "red\\x1b[31m alert" in out and "red\\x1b[31m alert" in err
    # the output file keeps the name exactly (JSON escapes it)
    assert json.loads((tmp_path / "o.json").read_text())["materials"][0]["name"] == "red\x1b[31m alert"


def test_a_held_parameter_has_an_empty_deviation_in_the_csv(tmp_path, capsys):
    """A matte wall (Ks 0) holds metalness at 0: its deviation is null in JSON and an
    empty cell in CSV (not a crash on formatting None)."""
    output = tmp_path / "wall.csv"
    code, out, err = run(capsys, "phong2strauss", "kd=0.8", "ks=0", "name=wall", "-o", output, "--size", SIZE)
    assert code == 0, err
    row = next(csv.DictReader(io.StringIO(output.read_text())))
    assert row["metalness"] == "0" and row["sd_metalness"] == ""
    assert float(row["sd_color_r"]) > 0
    assert "metalness held at 0" in row["notes"]
    assert "(held: " in out and "metalness" in out.split("(held: ")[1]  # the console table says so too


def test_newlines_and_bidi_controls_in_a_name_stay_on_one_line(tmp_path, capsys):
    """A name with a newline (or a right-to-left override) once broke the progress line and
    the table over several lines (hostile-user pass): every material is one line of each."""
    materials = tmp_path / "s.json"
    name = "x\nnewmtl evil\u202eKd 1 0 0"
    materials.write_text(json.dumps([{"name": name, "color": "red", "smoothness": 0.5}]))
    code, out, err = run(capsys, "strauss2phong", materials, "-o", tmp_path / "o.mtl", "--size", SIZE)
    assert code == 1, err  # the one material is broken: reported, the output written
    assert "\u202e" not in out + err
    shown = "x\\nnewmtl evil\\u202eKd 1 0 0"
    assert [line for line in err.splitlines() if "newmtl evil" in line] == [
        line for line in err.splitlines() if shown in line
    ]
    assert sum(shown in line for line in out.splitlines()) == 1
    assert not any(line.startswith(("newmtl evil", "Kd 1 0 0")) for line in (out + err).splitlines())
