"""A sidecar that is there but gives no noise (`strauss_fit.stats.noise.describe_noise`):
a file that is not JSON, or a strauss-fit sample description whose noise entry is damaged,
is said — in the noise model's notes and in the fit's — and the noise comes from the image,
as without a sidecar. A JSON file of the user's own beside the image is not a sidecar and
says nothing."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

import strauss_fit as sf
from strauss_fit.stats.noise import describe_noise, sidecar_path
from strauss_fit_cli.main import main

BUNDLED = Path(__file__).resolve().parents[2] / "data_synth" / "bundled"
NAME = "strauss-noisy-0000"


@pytest.fixture
def target_copy(tmp_path):
    """The bundled noisy target, copied without its sidecar, and its sidecar's text."""
    copy = tmp_path / f"{NAME}.exr"
    shutil.copy(BUNDLED / f"{NAME}.exr", copy)
    return copy, (BUNDLED / f"{NAME}.json").read_text()


def noise_of(path: Path):
    target = sf.load_target(path)
    return describe_noise(target.pixels, target.usable, path=str(path))


def damaged_noise_entry(text: str) -> str:
    data = json.loads(text)
    assert data["format"] == "strauss-fit synth sample" and "sensor" in data
    data["sensor"] = {"gain": "fast", "read_noise": -1}
    return json.dumps(data)


def noise_entry_of_another_type(text: str) -> str:
    data = json.loads(text)
    data["noise"] = "abc"  # not a table: crashed the fit (AttributeError) before 2026-12-04
    del data["sensor"]
    return json.dumps(data)


CASES = {
    "not JSON": lambda text: text[: len(text) // 2],  # cut short
    "nested too deeply": lambda text: "[" * 100000 + "]" * 100000,  # RecursionError in the parser
    "damaged noise entry": damaged_noise_entry,
    "noise entry of another type": noise_entry_of_another_type,
}


@pytest.mark.parametrize("case", CASES)
def test_a_sidecar_that_gives_no_noise_is_said_and_the_image_gives_it(target_copy, case):
    copy, text = target_copy
    without = noise_of(copy)
    assert without.source == "image" and without.sidecar_problem is None
    sidecar_path(copy).write_text(CASES[case](text))
    described = noise_of(copy)
    assert described.source == "image"
    np.testing.assert_array_equal(described.b, without.b)  # the same estimate as without a sidecar
    assert described.sidecar_problem is not None and f"{NAME}.json" in described.sidecar_problem
    assert described.notes[0] == described.sidecar_problem
    assert ("not readable JSON" in described.sidecar_problem) == (case in ("not JSON", "nested too deeply"))


def test_the_intact_sidecar_and_a_json_of_the_users_own_say_nothing(target_copy):
    copy, text = target_copy
    sidecar_path(copy).write_text(text)
    assert noise_of(copy).source == "sensor" and noise_of(copy).sidecar_problem is None
    sidecar_path(copy).write_text(json.dumps({"camera": "my own notes", "iso": 100}))
    mine = noise_of(copy)
    assert mine.source == "image" and mine.sidecar_problem is None
    assert not any("sidecar" in note for note in mine.notes)


def test_the_fit_says_it_on_the_command_line_and_in_its_result(target_copy, tmp_path, capsys):
    copy, text = target_copy
    sidecar_path(copy).write_text(CASES["not JSON"](text))
    out = tmp_path / "fit.json"
    scene = BUNDLED.parent / "scenes" / "two_lights.toml"
    code = main(["fit", str(copy), "--scene", str(scene), "-o", str(out), "--quality", "fast"])
    printed = capsys.readouterr()
    assert code in (0, 1), printed.err
    line = f"note: the sidecar {NAME}.json beside the target was not read (not readable JSON)"
    assert any(row.startswith(line) for row in printed.out.splitlines()), printed.out
    result = json.loads(out.read_text())
    assert any(note.startswith(f"the sidecar {NAME}.json") for note in result["notes"])


def test_a_file_name_with_a_line_break_stays_on_one_line(tmp_path, capsys):
    copy = tmp_path / "two\nlines.exr"
    shutil.copy(BUNDLED / f"{NAME}.exr", copy)
    sidecar_path(copy).write_text("{ not json")
    described = noise_of(copy)
    assert "\n" not in described.sidecar_problem and "two\\nlines.json" in described.sidecar_problem


def test_compare_says_why_the_sidecar_gave_no_noise(target_copy, tmp_path, capsys):
    copy, text = target_copy
    scene = BUNDLED.parent / "scenes" / "two_lights.toml"
    for case, expected in (("not JSON", "not readable JSON"), ("damaged noise entry", "holds no valid noise level")):
        sidecar_path(copy).write_text(CASES[case](text))
        out = tmp_path / f"compare-{case.replace(' ', '-')}.json"
        code = main(["compare", str(copy), "--scene", str(scene), "-o", str(out), "--models", "strauss"])
        printed = capsys.readouterr()
        assert code in (0, 1), printed.err
        assert expected in out.read_text(), case
