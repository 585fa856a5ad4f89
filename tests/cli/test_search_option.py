"""`strauss-fit fit --search`: passed to the fit, recorded in its result, refused in one line
where it is not a choice or would be ignored."""

import json

import pytest

from strauss_fit_cli.main import main

SCENE = """
[camera]
width = 20
height = 20
[material]
color = [0.7, 0.3, 0.2]
smoothness = 0.6
metalness = 0.3
[[light]]
kind = "directional"
direction = [0.3, 0.5, 1.0]
intensity = 1.0
[[light]]
kind = "ambient"
intensity = 0.1
"""


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """A 20 × 20 scene and a target rendered from its own material (an opaque plastic)."""
    path = tmp_path_factory.mktemp("search")
    (path / "scene.toml").write_text(SCENE)
    assert main(["render", str(path / "scene.toml"), "-o", str(path / "t.exr")]) == 0
    return path


def run(capsys, *argv):
    capsys.readouterr()
    code = main([str(a) for a in argv])
    return code, capsys.readouterr().err


@pytest.mark.parametrize("search, sources", [("starts", {"guess", "fixed"}), ("grid", {"grid"})])
def test_search_reaches_the_fit_and_its_result(folder, capsys, search, sources):
    """The result's settings record the choice, and its starts say they came from it: the
    grid's minima, or the closed-form guess and the fixed points of the multi-start."""
    out = folder / f"{search}.json"
    code, err = run(capsys, "fit", folder / "t.exr", "--scene", folder / "scene.toml", "--search", search, "-o", out)
    assert code == 0, err
    result = json.loads(out.read_text())
    assert result["settings"]["search"] == search
    assert {start["source"] for start in result["starts"]} == sources
    assert result["smoothness"] == pytest.approx(0.6, abs=1e-3)


def test_an_unknown_search_is_one_line(folder, capsys):
    code, err = run(capsys, "fit", folder / "t.exr", "--scene", folder / "scene.toml", "--search", "global", "-o", "x")
    assert code == 2
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("strauss-fit: error: ") and "invalid choice: 'global'" in lines[0]
    assert not (folder / "x").exists()


def test_another_model_refuses_a_search_it_would_ignore(folder, capsys):
    """Another model's fitter has no grid search: --search other than auto is refused, not
    silently dropped (the result would record a search that never ran)."""
    out = folder / "lambert.json"
    args = ["fit", folder / "t.exr", "--scene", folder / "scene.toml", "--model", "lambert", "-o", out]
    code, err = run(capsys, *args, "--search", "grid")
    assert (
        code == 2
        and err.splitlines() == ["strauss-fit: error: --search is not available with --model lambert"]
        and not out.exists()
    )
