"""``.mtl`` files as real exporters write them (tests/data/mtl: Blender, 3ds Max, Assimp,
Maya, SketchUp) and their broken variants: names kept exactly, encodings, glass, quirks."""

from pathlib import Path

import numpy as np
import pytest

from strauss_fit.errors import StraussFitError
from strauss_fit.io.material_tables import format_results_mtl, read_phong_input
from strauss_fit.io.mtl import parse_mtl, read_mtl

DATA = Path(__file__).resolve().parent.parent / "data" / "mtl"


def materials(name):
    return {m.name: m for m in read_mtl(DATA / name).materials}


@pytest.mark.parametrize(
    "file,names",
    [
        ("blender.mtl", ["Material", "Wood", "Metal.001"]),
        ("3dsmax.mtl", ["01 - Default", "02 - Brick Wall", "Glass"]),
        ("assimp.mtl", ["DefaultMaterial", "Material #112", "Material #113"]),
        ("maya.mtl", ["initialShadingGroup", "phong1SG", "lambert2SG"]),
        ("sketchup.mtl", ["[Color_M08]", "Brick_Antique", "Translucent_Glass_Blue"]),
    ],
)
def test_every_exporter_file_reads_with_its_names_exactly(file, names):
    library = read_mtl(DATA / file)
    assert [m.name for m in library.materials] == names  # a BOM, CRLF, tabs, '#' and spaces in names
    assert library.notes == [] and all(m.error is None for m in library.materials)


def test_values_survive_crlf_tabs_and_trailing_spaces():
    brick = materials("3dsmax.mtl")["02 - Brick Wall"]
    assert brick.values["kd"] == [0.5882, 0.2, 0.15] and brick.values["exponent"] == 30.0
    assert any("'map_Kd' ignored (texture maps" in n for n in brick.notes)
    assert any("Tf ignored (illum 2 has no refraction)" in n for n in brick.notes)  # 3ds Max's Tf 1 1 1


def test_a_refracting_glass_takes_its_transparency_from_tf():
    glass = materials("3dsmax.mtl")["Glass"]  # illum 7, Tf 0.9, d 1
    assert glass.opacity == pytest.approx(0.1) and glass.ior == pytest.approx(1.52)
    assert any("transparency t = mean(Tf) = 0.9" in n for n in glass.notes)
    maya = materials("maya.mtl")
    assert maya["phong1SG"].opacity == pytest.approx(0.1) and maya["initialShadingGroup"].opacity == 1.0
    tinted = parse_mtl("newmtl g\nillum 6\nTf 0.2 0.4 0.9\n").materials[0]
    assert tinted.opacity == pytest.approx(0.5) and any("tint" in n for n in tinted.notes)


def test_pbr_statements_are_named_as_such_not_as_textures():
    metal = materials("blender.mtl")["Metal.001"]
    assert any("'Pm' ignored (the PBR extension" in n for n in metal.notes)
    assert any("'map_Pr' ignored (texture maps" in n for n in metal.notes)


def test_quirks_are_warnings():
    wood = materials("blender.mtl")["Wood"]
    assert wood.opacity == 0.0 and len(wood.warnings) == 1
    assert "d 0 makes the material fully transparent" in wood.warnings[0] and "exporter quirk" in wood.warnings[0]
    odd = parse_mtl("newmtl odd\nKd 1.5 0.2 0.2\nNi 42\n").materials[0]
    assert odd.error is None
    assert any("Kd = [1.5, 0.2, 0.2] exceeds 1" in w for w in odd.warnings)
    assert any("Ni = 42 is far above" in w for w in odd.warnings)
    assert parse_mtl("newmtl fine\nKd 0.5 0.5 0.5\nNi 1.5\nd 1\n").materials[0].warnings == []


@pytest.mark.parametrize(
    "text,error",
    [
        ("newmtl a\nKd nan nan nan\n", "Kd values must be finite numbers, got 'Kd nan nan nan'"),
        ("newmtl a\nNs inf\n", "Ns values must be finite numbers"),
        ("newmtl a\nTf 1.5 1 1\nillum 7\n", "Tf = [1.5, 1.0, 1.0] must not exceed 1"),
    ],
)
def test_broken_values_fail_their_material(text, error):
    assert error in parse_mtl(text).materials[0].error


def test_a_byte_order_mark_keeps_the_first_material(tmp_path):
    path = tmp_path / "bom.mtl"
    path.write_bytes(b"\xef\xbb\xbfnewmtl first\nKd 0.5 0.5 0.5\nnewmtl second\nKd 0.1 0.1 0.1\n")
    library = read_mtl(path)
    assert [m.name for m in library.materials] == ["first", "second"] and library.notes == []


@pytest.mark.parametrize(
    "data,message",
    [
        ("newmtl a\nKd 0.5 0.5 0.5\n".encode("utf-16"), "is UTF-16 text, not UTF-8: save it as UTF-8"),
        ("newmtl a\nKd 0.5 0.5 0.5\n".encode("utf-16-le"), "is UTF-16 text, not UTF-8"),
        ("newmtl Stahl gebürstet\nKd 0.5 0.5 0.5\n".encode("latin-1"), "is not UTF-8 text (byte 0xfc on line 1)"),
    ],
)
def test_other_encodings_are_one_line_errors(tmp_path, data, message):
    path = tmp_path / "lib.mtl"
    path.write_bytes(data)
    with pytest.raises(StraussFitError, match=message.replace("(", r"\(").replace(")", r"\)")):
        read_mtl(path)


def test_several_files_are_read_in_turn():
    entries, notes, description = read_phong_input([str(DATA / "assimp.mtl"), str(DATA / "sketchup.mtl")])
    assert [e.name for e in entries][2:4] == ["Material #113", "[Color_M08]"]
    assert description == f"{DATA / 'assimp.mtl'}, {DATA / 'sketchup.mtl'}"
    assert entries[0].warnings == [] and read_phong_input([str(DATA / "blender.mtl")])[0][1].warnings


def test_reading_builds_no_material_until_one_is_used():
    entries, _, _ = read_phong_input([str(DATA / "3dsmax.mtl")])
    assert all(e._material is None for e in entries)  # plain values only
    np.testing.assert_allclose(entries[1].material.kd, [0.5882, 0.2, 0.15])
    entries[1].release()
    assert entries[1]._material is None


def fake_result(name):
    return {
        "name": name,
        "status": "ok",
        "input": {"strauss": {"color": [0.5, 0.5, 0.5]}},
        "residual": {"rms": 0.01, "delta_e2000_mean": 0.5},
        "phong": {
            "ka": 0.1,
            "kd": 0.5,
            "ks": 0.2,
            "exponent": 20.0,
            "diffuse_color": [1.0, 1.0, 1.0],
            "specular_color": [1.0, 1.0, 1.0],
        },
        "opacity": 1.0,
        "ior": 1.5,
    }


def test_written_names_are_the_names_so_usemtl_lines_still_match(tmp_path):
    names = ["01 - Default", "Material #112", "[Color_M08]", "Glass"]
    text, renamed = format_results_mtl([fake_result(n) for n in names])
    assert renamed == []
    path = tmp_path / "out.mtl"
    path.write_text(text)
    assert [m.name for m in read_mtl(path).materials] == names  # what `usemtl 01 - Default` looks up


def test_names_the_format_cannot_hold_are_renamed_loudly():
    text, renamed = format_results_mtl([fake_result(n) for n in ["a", "a", "bad\x1bname", " padded "]])
    names = [m.name for m in parse_mtl(text).materials]
    assert names == ["a", "a_2", "bad_name", "padded"]
    assert len(renamed) == 3 and "same name" in renamed[0] and "control characters" in renamed[1]
    assert "\x1b" not in text


def test_text_quoted_into_a_written_library_is_escaped_as_everywhere_else():
    """A name or message with a right-to-left override (which would print the rest of its
    line reversed) or a line break is renamed or escaped, as the command line escapes it
    (`strauss_fit._escaping.escape`): every comment stays one line."""
    failed = {"name": "evil\u202eliam\nnewmtl fake", "status": "failed", "message": "bad\nvalue \u202e"}
    text, renamed = format_results_mtl([fake_result("ok\u202ename"), failed])
    assert "\u202e" not in text and [m.name for m in parse_mtl(text).materials] == ["ok_name"]
    assert "control characters" in renamed[0]
    comment = [line for line in text.splitlines() if "not converted" in line]
    assert comment == ["# evil\\u202eliam\\nnewmtl fake: not converted: bad\\nvalue \\u202e"]
