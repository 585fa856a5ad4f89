"""``strauss-fit phong2strauss`` and ``strauss2phong`` end to end: both directions and every
output format, a batch with a broken material, and one-line errors."""

import csv
import io
import json

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
