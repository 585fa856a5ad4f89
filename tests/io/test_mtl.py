"""Wavefront .mtl parsing: mapping, comments, several materials, defaults, per-material errors."""

import numpy as np
import pytest

from strauss_fit.errors import StraussFitError
from strauss_fit.io.mtl import format_mtl, format_mtl_material, parse_mtl, read_mtl

LIBRARY = """\
# A library with comments, blank lines and three materials
# (the comment above and this one are skipped)

newmtl red_plastic
Ka 0.1 0.0 0.0
Kd 0.7 0.1 0.1   # a trailing comment
Ks 0.4 0.4 0.4
Ns 60
illum 2

newmtl gold
\tKd 0.2 0.15 0.02
Ks 0.9 0.7 0.2
Ns 200
map_Kd gold.png
d 0.8
Ni 1.45

newmtl glass
Kd 0.05
Ks 0.9
Ns 500
Tr 0.75
Ni 1.5
illum 7
"""


def by_name(library):
    return {m.name: m for m in library.materials}


def test_statements_map_to_phong_opacity_and_ior():
    library = parse_mtl(LIBRARY, "lib.mtl")
    assert [m.name for m in library.materials] == ["red_plastic", "gold", "glass"]
    assert all(m.error is None for m in library.materials)
    red = by_name(library)["red_plastic"].phong
    np.testing.assert_allclose(red.ka, [0.1, 0.0, 0.0])
    np.testing.assert_allclose(red.kd, [0.7, 0.1, 0.1])
    np.testing.assert_allclose(red.ks, [0.4, 0.4, 0.4])
    assert float(red.exponent) == 60.0
    np.testing.assert_allclose(red.diffuse_color, [1, 1, 1])
    np.testing.assert_allclose(red.specular_color, [1, 1, 1])
    gold = by_name(library)["gold"]
    assert gold.opacity == pytest.approx(0.8) and gold.ior == pytest.approx(1.45)
    glass = by_name(library)["glass"]
    np.testing.assert_allclose(glass.phong.kd, [0.05, 0.05, 0.05])  # one number means grey
    assert glass.opacity == pytest.approx(0.25)  # Tr = 1 - d
    assert by_name(library)["red_plastic"].line == 4 and glass.line == 19


def test_missing_fields_take_opengl_defaults_with_notes():
    library = parse_mtl("newmtl bare\nKd 0.5 0.5 0.5\n")
    bare = library.materials[0]
    assert bare.error is None
    np.testing.assert_allclose(bare.phong.ka, [0.2] * 3)
    np.testing.assert_allclose(bare.phong.ks, [0.0] * 3)
    assert float(bare.phong.exponent) == 0.0
    assert bare.opacity == 1.0 and bare.ior == 1.5
    text = " ".join(bare.notes)
    assert "Ka missing" in text and "Ks missing" in text and "Ns missing" in text and "Ni missing" in text
    assert "Kd missing" not in text


def test_ignored_and_unknown_statements_are_noted_not_fatal():
    library = parse_mtl(LIBRARY)
    gold = by_name(library)["gold"]
    assert any("'map_Kd' ignored" in n for n in gold.notes)
    library = parse_mtl("newmtl odd\nKd 1 1 1\nfrobnicate 3\n")
    assert library.materials[0].error is None
    assert any("unknown statement 'frobnicate'" in n for n in library.materials[0].notes)


def test_malformed_lines_fail_only_their_material():
    text = """newmtl good1
Kd 0.5 0.5 0.5
newmtl steel
Ks 0.5 0.5 0.5
Kd 0.5 0.5
newmtl good2
Kd 0.2 0.3 0.4
newmtl words
Ns shiny
newmtl range
Kd 0.1 0.1 0.1
d 1.5
newmtl spectral
Ka spectral file.rfl
newmtl huge
Ns 20000
"""
    library = parse_mtl(text, "lib.mtl")
    materials = by_name(library)
    assert materials["good1"].error is None and materials["good2"].error is None
    np.testing.assert_allclose(materials["good2"].phong.kd, [0.2, 0.3, 0.4])
    assert materials["steel"].error == "material 'steel' line 5: Kd needs 3 numbers (or 1 for grey), got 'Kd 0.5 0.5'"
    assert materials["steel"].phong is None
    assert materials["words"].error == "material 'words' line 9: Ns needs 1 number, got 'Ns shiny'"
    assert materials["range"].error == "material 'range' line 12: d = 1.5 is outside [0, 1]"
    assert "Ka spectral is not supported" in materials["spectral"].error
    assert materials["huge"].error == "material 'huge' line 16: Ns = 20000 is outside [0, 10000]"


def test_duplicate_names_and_statements_before_newmtl():
    library = parse_mtl("Kd 1 1 1\nnewmtl a\nKd 0.1 0.1 0.1\nnewmtl a\nKd 0.2 0.2 0.2\nnewmtl\n")
    assert library.notes[0] == "line 1: 'Kd' before any newmtl; ignored"
    first, second, unnamed = library.materials
    assert first.error is None
    assert second.error == "material 'a' line 4: duplicate material name (first defined on line 2)"
    assert unnamed.error is not None and "needs a name" in unnamed.error


def test_illum_one_removes_the_highlight_and_d_wins_over_tr():
    library = parse_mtl("newmtl m\nKd 0.5 0.5 0.5\nKs 0.8 0.8 0.8\nillum 1\nd 0.6\nTr 0.9\nNi 0.001\n")
    m = library.materials[0]
    np.testing.assert_allclose(m.phong.ks, [0, 0, 0])
    assert m.opacity == pytest.approx(0.6)
    assert m.ior == 1.0
    notes = " ".join(m.notes)
    assert "illum 1 has no highlight" in notes and "Tr ignored" in notes and "below 1; taken as 1" in notes


def test_negative_colour_and_bad_illum_are_errors():
    library = parse_mtl("newmtl neg\nKd -0.1 0 0\nnewmtl ill\nillum 2.5\n")
    assert "must not be negative" in library.materials[0].error
    assert "illum must be an integer" in library.materials[1].error


def test_written_library_reads_back_to_the_same_products(tmp_path):
    phong = {
        "ka": 0.3,
        "kd": 0.8,
        "ks": 0.5,
        "exponent": 42.0,
        "diffuse_color": [1.0, 0.5, 0.25],
        "specular_color": [1.0, 1.0, 0.5],
    }
    text = format_mtl([format_mtl_material("copper", phong, opacity=0.9, ior=1.2, comment="a test")], "header")
    path = tmp_path / "out.mtl"
    path.write_text(text)
    library = read_mtl(path)
    m = library.materials[0]
    assert m.name == "copper" and m.error is None and m.notes == []
    np.testing.assert_allclose(m.phong.kd, [0.8, 0.4, 0.2], atol=1e-6)
    np.testing.assert_allclose(m.phong.ka, [0.3, 0.15, 0.075], atol=1e-6)
    np.testing.assert_allclose(m.phong.ks, [0.5, 0.5, 0.25], atol=1e-6)
    assert float(m.phong.exponent) == pytest.approx(42.0)
    assert m.opacity == pytest.approx(0.9) and m.ior == pytest.approx(1.2)


def test_missing_file_is_a_one_line_error(tmp_path):
    with pytest.raises(StraussFitError, match="material library not found"):
        read_mtl(tmp_path / "nope.mtl")
