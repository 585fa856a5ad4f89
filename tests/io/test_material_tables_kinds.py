"""Material tables: one table per kind of material (:data:`~strauss_fit.io.material_tables.KINDS`),
the Strauss keys and CSV columns from :data:`strauss_fit.models.material.PARAMETER_NAMES`,
and the same outputs and messages, byte for byte, as the two-way switches they replace (the
expected texts were recorded from that code)."""

import json
import re
from pathlib import Path

import pytest

from strauss_fit import Material, PhongMaterial
from strauss_fit.errors import MaterialError, StraussFitError
from strauss_fit.io import material_tables as tables
from strauss_fit.io.material_tables import KINDS, csv_columns, format_csv, read_phong_input, read_strauss_input
from strauss_fit.models.material import PARAMETER_NAMES

MTL = Path(__file__).resolve().parent.parent / "data" / "mtl" / "blender.mtl"
PHONG_KEYS_TEXT = "ka, kd, ks, exponent, diffuse_color, specular_color, blinn, opacity, ior"


def test_one_table_per_kind_and_the_strauss_keys_from_the_material():
    assert list(KINDS) == ["phong", "strauss"]
    assert tables.STRAUSS_KEYS is PARAMETER_NAMES and KINDS["strauss"].keys is PARAMETER_NAMES
    assert tables.STRAUSS_CSV_INPUT == ("name", *PARAMETER_NAMES)
    assert KINDS["phong"].inputs == (*tables.PHONG_KEYS, "opacity", "ior")
    for name, kind, material in (("phong", KINDS["phong"], PhongMaterial), ("strauss", KINDS["strauss"], Material)):
        assert kind.name == name and kind.material is material
        entry = kind.entry({}, "x", "here")
        assert entry.kind == name and entry.values == {} and isinstance(entry.material, material)
        entry.release()
        assert entry._material is None and isinstance(entry.build(), material)


def test_csv_columns_and_rows_are_as_before():
    assert (
        csv_columns("phong2strauss")
        == (
            "name source status message color_r color_g color_b smoothness metalness transparency ior sd_color_r "
            "sd_color_g sd_color_b sd_smoothness sd_metalness rms max_abs delta_e2000_mean delta_e2000_p95 "
            "solver_status notes"
        ).split()
    )
    residual = {"rms": 0.01, "max_abs": 0.02, "delta_e2000_mean": 0.3, "delta_e2000_p95": 0.5}
    ok = {
        "name": "a",
        "status": "ok",
        "source": "x",
        "residual": residual,
        "solver": {"status": "converged"},
        "strauss": {"color": [0.1, 0.2, 0.3], "smoothness": 0.5, "metalness": 0.1, "transparency": 0.2, "ior": 1.5},
        "uncertainty": {"color": [0.01, None, 0.02], "smoothness": 0.1, "metalness": None},
        "notes": ["n1", "n2"],
    }
    failed = {"name": "b", "status": "error", "message": "m"}
    assert format_csv([ok, failed, dict(ok, uncertainty=None)], "phong2strauss") == (
        "name,source,status,message,color_r,color_g,color_b,smoothness,metalness,transparency,ior,sd_color_r,"
        "sd_color_g,sd_color_b,sd_smoothness,sd_metalness,rms,max_abs,delta_e2000_mean,delta_e2000_p95,"
        "solver_status,notes\n"
        "a,x,ok,,0.1,0.2,0.3,0.5,0.1,0.2,1.5,0.01,,0.02,0.1,,0.01,0.02,0.3,0.5,converged,n1 | n2\n"
        "b,,error,m,,,,,,,,,,,,,,,,,,\n"
        "a,x,ok,,0.1,0.2,0.3,0.5,0.1,0.2,1.5,,,,,,0.01,0.02,0.3,0.5,converged,n1 | n2\n"
    )
    phong = {
        "ka": 1.0,
        "kd": 0.5,
        "ks": 0.3,
        "exponent": 20.0,
        "diffuse_color": [0.1, 0.2, 0.3],
        "specular_color": [1.0, 1.0, 1.0],
        "blinn": True,
    }
    uncertainty = {"diffuse": [0.1, 0.2, 0.3], "specular": [None, None, None], "exponent": 2.0}
    converted = {
        "name": "c",
        "status": "ok",
        "residual": residual,
        "solver": {"status": "x"},
        "phong": phong,
        "opacity": 0.5,
        "ior": 1.4,
        "uncertainty": uncertainty,
    }
    assert format_csv([converted, failed], "strauss2phong") == (
        "name,source,status,message,ka,kd,ks,exponent,diffuse_color_r,diffuse_color_g,diffuse_color_b,"
        "specular_color_r,specular_color_g,specular_color_b,blinn,opacity,ior,sd_diffuse_r,sd_diffuse_g,"
        "sd_diffuse_b,sd_specular_r,sd_specular_g,sd_specular_b,sd_exponent,rms,max_abs,delta_e2000_mean,"
        "delta_e2000_p95,solver_status,notes\n"
        "c,,ok,,1,0.5,0.3,20,0.1,0.2,0.3,1,1,1,true,0.5,1.4,0.1,0.2,0.3,,,,2,0.01,0.02,0.3,0.5,x,\n"
        "b,,error,m,,,,,,,,,,,,,,,,,,,,,,,,,,\n"
    )


def test_unknown_keys_and_formats_say_what_each_kind_reads(tmp_path):
    with pytest.raises(MaterialError) as caught:
        read_strauss_input(["q=1"])
    assert str(caught.value) == (
        "unknown Strauss key 'q'; expected color, smoothness, metalness, transparency, ior (aliases: C, s, m, t, n)"
    )
    with pytest.raises(MaterialError) as caught:
        read_phong_input(["zz=1"])
    assert str(caught.value) == (
        f"unknown Phong key 'zz'; expected {PHONG_KEYS_TEXT} (aliases: n/Ns for exponent, Cd, Cs, d for opacity, "
        "Ni for ior)"
    )
    missing = tmp_path / "nope.json"
    with pytest.raises(StraussFitError) as caught:
        read_phong_input([str(missing)])
    assert str(caught.value) == f"input not found: {missing} (give a .json, .csv, .mtl file or KEY=VALUE pairs)"
    with pytest.raises(StraussFitError) as caught:
        read_strauss_input([str(missing)])
    assert str(caught.value) == f"input not found: {missing} (give a .json, .csv file or KEY=VALUE pairs)"
    text = tmp_path / "s.txt"
    text.write_text("x")
    with pytest.raises(StraussFitError, match=r"unknown input format \.txt; expected \.json, \.csv or \.mtl$"):
        read_phong_input([str(text)])
    with pytest.raises(StraussFitError, match=r"unknown input format \.txt; expected \.json or \.csv$"):
        read_strauss_input([str(text)])
    with pytest.raises(StraussFitError, match=r"unknown input format \.mtl; expected \.json or \.csv$"):
        read_strauss_input([str(MTL)])
    entries, notes, _ = read_phong_input([str(MTL)])  # a .mtl library is Phong
    assert entries[0].kind == "phong" and isinstance(entries[0].material, PhongMaterial) and notes == []
    bad = tmp_path / "bad.csv"
    bad.write_text("name,shininess\nx,3\n")
    with pytest.raises(StraussFitError) as caught:
        read_strauss_input([str(bad)])
    assert str(caught.value) == (
        f"{bad}: unknown column 'shininess'; expected name, color, smoothness, metalness, transparency, ior "
        "(RGB values as NAME_r, NAME_g, NAME_b or one column 'r g b')"
    )


@pytest.mark.parametrize(
    "values",
    [
        {"smoothness": 1.5},
        {"color": [0.1, 1.2, 0.3]},
        {"color": [-0.5, 0.2, 0.3], "smoothness": 2.0},
        {"ior": 0.5, "metalness": -1.0},  # the first bad value in parameter order, not in input order
        {"transparency": 1.0 + 1e-12},
        {"ior": 0.9},
    ],
)
def test_strauss_range_errors_are_the_materials_own(values):
    """The tables check Strauss values without building a JAX material, with its messages."""
    with pytest.raises(MaterialError) as expected:
        Material(**values)
    with pytest.raises(MaterialError) as caught:
        read_strauss_input([json.dumps(values)])
    assert str(caught.value) == str(expected.value)


def test_json_inputs_per_kind(tmp_path):
    both = tmp_path / "both.json"
    both.write_text(
        json.dumps(
            [
                {"name": "p", "phong": {"kd": 0.5, "exponent": 20}, "opacity": 0.5, "ior": 1.4},
                {"name": "s", "strauss": {"color": [0.3, 0.3, 0.3], "t": 0.4, "n": 1.3}, "opacity": 0.2},
            ]
        )
    )
    phong, _, _ = read_phong_input([str(both)])
    assert phong[0].values == {"kd": 0.5, "exponent": 20.0} and (phong[0].opacity, phong[0].ior) == (0.5, 1.4)
    assert phong[1].error.startswith("unknown Phong key 'strauss'")
    strauss, _, _ = read_strauss_input([str(both)])
    assert strauss[0].error.startswith("unknown Strauss key 'phong'")
    assert strauss[1].values == {"color": [0.3, 0.3, 0.3], "transparency": 0.4, "ior": 1.3}
    assert (strauss[1].opacity, strauss[1].ior) == (0.6, 1.3)  # 1 − t: a Strauss entry's own "opacity" is not read

    fit = {"free": [], "held": {}, "residual": {}, "color": [0.2, 0.3, 0.4], "smoothness": 0.3, "extra": 3}
    result = tmp_path / "fit.json"
    result.write_text(json.dumps(fit))
    entries, _, _ = read_strauss_input([str(result)])
    assert entries[0].error is None and entries[0].values == {"color": [0.2, 0.3, 0.4], "smoothness": 0.3}
    entries, _, _ = read_phong_input([str(result)])  # a fit result is a Strauss material only
    assert entries[0].error.startswith("unknown Phong key 'free'")


def test_csv_inputs_per_kind(tmp_path):
    table = tmp_path / "s.csv"
    table.write_text(
        "name,color_r,color_g,color_b,s,m,t,n,status,rms\n"
        "x,0.1,0.2,0.3,0.5,0.1,0,1.5,ok,0.1\n"
        "y,,,,0.2,,,,,\n"
        "v,0.5,0.5,0.5,3,,,,,\n"
    )
    entries, _, _ = read_strauss_input([str(table)])
    assert entries[0].values == {
        "color": [0.1, 0.2, 0.3],
        "smoothness": 0.5,
        "metalness": 0.1,
        "transparency": 0.0,
        "ior": 1.5,
    }
    assert entries[1].values == {"smoothness": 0.2} and isinstance(entries[1].material, Material)
    assert entries[2].error == "line 4: material smoothness = 3.0 is outside its range [0, 1]"
    table = tmp_path / "p.csv"
    table.write_text("name,ka,kd_r,kd_g,kd_b,n,cd,blinn,d,ni\na,0.1,0.5,0.4,0.3,30,0.8 0.2 0.1,true,0.5,1.3\n")
    (entry,), _, _ = read_phong_input([str(table)])
    assert entry.values == {
        "ka": 0.1,
        "kd": [0.5, 0.4, 0.3],
        "exponent": 30.0,
        "diffuse_color": [0.8, 0.2, 0.1],
        "blinn": True,
    }
    assert (entry.opacity, entry.ior) == (0.5, 1.3) and isinstance(entry.material, PhongMaterial)


def test_every_format_the_tables_name_has_a_reader_or_writer_and_the_help_derives_from_them():
    """The extension tables (:mod:`strauss_fit.io.table_formats`) are the one home of the
    formats: each input extension of a kind has a reader, each output format a writer, and
    the command line's help and errors list exactly the extensions a direction can write."""
    import argparse

    from strauss_fit.io import material_tables, table_formats
    from strauss_fit_cli import phong2strauss_cmd

    for kind in material_tables.KINDS.values():
        assert set(kind.suffixes) <= set(material_tables.INPUT_READERS)
        assert kind.suffixes == table_formats.INPUT_SUFFIXES_BY_KIND[kind.name]
    assert set(table_formats.INPUT_SUFFIXES) == set(material_tables.INPUT_READERS)
    assert {name for name, _ in table_formats.OUTPUT_FORMATS.values()} == set(material_tables.OUTPUT_WRITERS)
    assert table_formats.output_suffixes("phong2strauss") == [".json", ".csv"]
    assert table_formats.output_suffixes("strauss2phong") == [".json", ".csv", ".mtl"]
    subparsers = argparse.ArgumentParser().add_subparsers()
    phong2strauss_cmd.add_parser(subparsers)
    for direction, parser in subparsers.choices.items():
        output = next(a for a in parser._actions if "--output" in a.option_strings)
        assert table_formats.describe_suffixes(table_formats.output_suffixes(direction)) in output.help
        with pytest.raises(StraussFitError, match="expected " + re.escape(output.help.split(": ")[1].split(" (")[0])):
            material_tables.output_format("out.txt", direction)
