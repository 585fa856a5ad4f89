"""Material lists for the conversions: inline KEY=VALUE tokens, CSV and JSON inputs (a fit
result read as one Strauss material), with one-line errors per material."""

import json

import numpy as np
import pytest

from strauss_fit.errors import MaterialError, StraussFitError
from strauss_fit.io.material_tables import read_phong_input, read_strauss_input


def test_inline_and_csv_and_json_inputs(tmp_path):
    entries, _, where = read_phong_input(["kd=0.6", "ks=0.3", "n=40", "Cd=0.8,0.2,0.1", "d=0.5", "name=red"])
    assert where == "command line" and entries[0].name == "red" and entries[0].opacity == 0.5
    assert float(entries[0].material.exponent) == 40.0
    with pytest.raises(MaterialError, match="unknown Phong key 'shine'"):
        read_phong_input(["kd=0.5", "shine=3"])
    with pytest.raises(MaterialError, match="outside its range"):
        read_phong_input(["kd=-1"])

    table = tmp_path / "batch.csv"
    table.write_text(
        "name,kd,ks,exponent,diffuse_color_r,diffuse_color_g,diffuse_color_b,specular_color\n"
        "a,0.5,0.2,10,1,0.5,0.25,1 1 0.5\n"
        "b,0.5,,,,,,\n"
        "c,lots,0.2,10,,,,\n"
        "d,0.5,0.2,10,1,0.5,,\n"
    )
    entries, _, _ = read_phong_input([str(table)])
    assert [e.name for e in entries] == ["a", "b", "c", "d"]
    np.testing.assert_allclose(entries[0].material.diffuse_color, [1, 0.5, 0.25])
    np.testing.assert_allclose(entries[0].material.specular_color, [1, 1, 0.5])
    assert float(entries[1].material.ks) == 0.3  # empty cells keep the defaults
    assert entries[2].error == "line 4: phong kd must be a number, got 'lots'"
    assert "needs all of diffuse_color_r" in entries[3].error
    bad = tmp_path / "bad.csv"
    bad.write_text("name,kd,sparkle\nx,1,2\n")
    with pytest.raises(StraussFitError, match="unknown column 'sparkle'"):
        read_phong_input([str(bad)])

    fit_result = tmp_path / "fit.json"
    fit_result.write_text(
        json.dumps(
            {
                "color": [0.5, 0.4, 0.3],
                "smoothness": 0.6,
                "metalness": 0.1,
                "transparency": 0.0,
                "ior": 1.5,
                "free": [],
                "held": {},
                "residual": {},
            }
        )
    )
    entries, _, _ = read_strauss_input([str(fit_result)])
    assert entries[0].error is None and float(entries[0].material.smoothness) == 0.6
    listing = tmp_path / "list.json"
    listing.write_text(
        json.dumps({"materials": [{"name": "m", "color": [1, 0, 0], "s": 0.3}, 5, {"name": "z", "smoothness": 2}]})
    )
    entries, _, _ = read_strauss_input([str(listing)])
    assert entries[0].error is None and entries[1].error == "entry 2 is not a JSON object"
    assert "outside its range" in entries[2].error
