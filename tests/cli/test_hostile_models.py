"""Hostile input to the reflectance-model commands: ``fit TARGET --scene S --model NAME``,
``fit --capture`` (--stability, --holdout), ``render --model --values``, ``compare``,
``report --fit`` / ``sample --fit`` of a capture's result, and a capture's chain.

Every row must end with exit status 2 and one line, ``strauss-fit: error: ...``, naming
the problem (no traceback), and write nothing: no output, no temporary, no input replaced.
Each one was a traceback, a partial or wrong output, or a silently ignored option before.
The inputs are tiny (a 24 × 24 scene, a 40 × 32 capture) and every error is found before
any fit or sampling. Each command runs in a process of its own, except the options refused
before any work (:func:`in_process`), so that the module runs in well under a minute.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import h5py
import numpy as np
import pytest

from strauss_fit.io.images import write_image

SCENES = Path(__file__).resolve().parents[2] / "data_synth" / "scenes"
SIDE = 24


def strauss_fit(*args, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "strauss_fit_cli.main", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=cwd,
    )


def in_process(*args, cwd: Path, capsys, monkeypatch) -> SimpleNamespace:
    """``strauss-fit ARGS`` by :func:`strauss_fit_cli.main.main` in this process: for the
    options refused before any work, where a process of its own would only cost time."""
    from strauss_fit_cli.main import main

    monkeypatch.chdir(cwd)
    capsys.readouterr()
    code = main([str(a) for a in args])
    return SimpleNamespace(returncode=code, stderr=capsys.readouterr().err)


def assert_refused(run: subprocess.CompletedProcess | SimpleNamespace, *fragments: str) -> None:
    """Exit status 2 and one line naming the problem."""
    assert run.returncode == 2, (run.returncode, run.stderr[-2000:])
    assert "Traceback" not in run.stderr
    lines = run.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("strauss-fit: error: "), run.stderr
    for fragment in fragments:
        assert fragment in lines[0], lines[0]


@pytest.fixture
def folder(tmp_path):
    """A folder with a 24 × 24 scene (one directional light and ambient light), a grey
    target and a black one; every test checks that it is left as it was."""
    scene = (SCENES / "basic.toml").read_text()
    scene = scene.replace("width = 128", f"width = {SIDE}").replace("height = 128", f"height = {SIDE}")
    (tmp_path / "scene.toml").write_text(scene)
    write_image(tmp_path / "t.exr", np.full((SIDE, SIDE, 3), 0.3))
    write_image(tmp_path / "black.exr", np.zeros((SIDE, SIDE, 3)))
    return tmp_path


def listing(path: Path) -> dict[str, bytes]:
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    """A synthetic capture of 12 small images."""
    from data_synth.capture import example_capture_spec, write_capture

    folder = tmp_path_factory.mktemp("capture") / "cap"
    spec = example_capture_spec("plastic", frame=(40, 32), center_px=(20.3, 15.8), radius_px=10.0, supersample=1)
    write_capture(spec, folder)
    return folder


def scene_result(**changes) -> dict:
    """A capture's result of ``fit t.exr --scene scene.toml --model lambert`` (as written,
    relative paths), with ``changes``."""
    result = {
        "model": "lambert",
        "albedo": [0.5, 0.4, 0.3],
        "free": ["albedo"],
        "values": {"albedo": [0.5, 0.4, 0.3]},
        "uncertainty": {"albedo": [0.01, 0.01, 0.01]},
        "uncertainty_laplace": {"albedo": [0.001, 0.001, 0.001]},
        "correlation": {"labels": ["albedo_r", "albedo_g", "albedo_b"], "matrix": np.eye(3).tolist()},
        "residual": {"verdict": "undetermined", "relative_rms": 0.1},
        "circle": {},
        "camera": {"type": "orthographic"},
        "images": 1,
        "images_fitted": 1,
        "warnings": [],
        "notes": [],
        "settings": {"model": "lambert", "exposure": "fixed", "white_balance": False, "ambient": False},
        "target": "t.exr",
        "scene": "scene.toml",
        "mask": None,
        "encoding": "auto",
    }
    result.update(changes)
    return result


# --- fit --model, fit --capture --------------------------------------------------------------


def test_black_target_with_a_model_is_refused(folder):
    """Was: relative RMS 0/0 = NaN in the result, then a ValueError traceback writing it."""
    before = listing(folder)
    run = strauss_fit("fit", "black.exr", "--scene", "scene.toml", "--model", "lambert", "-o", "r.json", cwd=folder)
    assert_refused(run, "black.exr is black on every usable sphere pixel")
    assert listing(folder) == before


def test_model_fit_never_replaces_the_targets_sidecar(folder):
    """Was: -o t.json --force replaced the target's sidecar (its noise and truth)."""
    (folder / "t.json").write_text('{"noise": {"sigma": 0.01}}\n')
    before = listing(folder)
    run = strauss_fit(
        "fit", "t.exr", "--scene", "scene.toml", "--model", "lambert", "-o", "t.json", "--force", cwd=folder
    )
    assert_refused(run, "is the input TARGET's sidecar")
    assert listing(folder) == before


@pytest.mark.parametrize(
    "extra, fragment",
    [
        (["--stability"], "--stability is for captures"),  # was: ignored, a fit written
        (["--resume"], "--resume is for several targets fitted into a folder"),  # was: ignored
    ],
)
def test_model_fit_refuses_what_it_would_ignore(folder, extra, fragment, capsys, monkeypatch):
    before = listing(folder)
    args = ["fit", "t.exr", "--scene", "scene.toml", "--model", "lambert", *extra]
    run = in_process(*args, "-o", "r.json", cwd=folder, capsys=capsys, monkeypatch=monkeypatch)
    assert_refused(run, fragment)
    assert listing(folder) == before


@pytest.mark.parametrize(
    "extra, fragment",
    [
        # was: a misleading "no usable values" after fitting the one image left
        (["--stability", "--holdout", "1,2,3,4,5,6,7,8,9,10,11"], "--stability fits two halves"),
        # was: found only after every image was read (a progress line, then the error)
        (["--holdout", "13"], "--holdout 13: k must be between 2"),
        # was: ignored, the capture fitted without it
        (["--fix", "albedo=1"], "--fix is not available with --capture"),
    ],
)
def test_capture_fit_refuses_before_reading_the_images(capture, tmp_path, extra, fragment, capsys, monkeypatch):
    args = ["fit", "--capture", capture, "--model", "lambert", "-o", "r.json", *extra]
    run = in_process(*args, cwd=tmp_path, capsys=capsys, monkeypatch=monkeypatch)
    assert_refused(run, fragment)
    assert listing(tmp_path) == {}


def test_every_model_has_a_label_per_value_and_equivalence_ranges():
    """Was: ``fit --model cook-torrance --equivalence`` (or ``--capture``) a KeyError traceback,
    and Cook–Torrance's kd and f0 one label each for three values (the correlation warning
    named the wrong pairs, the report dropped the correlations). Checked on the tables
    themselves: the command takes seconds of compiling, more than this module can spend."""
    from strauss_fit.fitting.capture import MODELS, CaptureFitOptions, _labels, _offsets, _parameters
    from strauss_fit.fitting.capture_equivalence import MATERIAL

    for model in MODELS:
        params = _parameters(CaptureFitOptions(model=model, white_balance=True, ambient=True), images=4)
        assert len(_labels(params)) == _offsets(params)[-1], model
        assert model in MATERIAL and set(MATERIAL[model]) <= {p.name for p in params}, model


def test_capture_fit_never_replaces_the_captures_manifest(capture, tmp_path):
    """Was: -o FOLDER/capture.toml --force replaced the manifest of --capture FOLDER by the result."""
    shutil.copytree(capture, tmp_path / "cap")
    before = listing(tmp_path)
    run = strauss_fit("fit", "--capture", "cap", "-o", "cap/capture.toml", "--force", cwd=tmp_path)
    assert_refused(run, "is the input --capture's manifest")
    assert listing(tmp_path) == before


# --- render --model --values -----------------------------------------------------------------


@pytest.mark.parametrize(
    "text, fragment",
    [
        ("[" * 100_000 + "]" * 100_000, "nested too deeply"),  # was: RecursionError
        ('{"albedo": [' + "9" * 5000 + ", 0.5, 0.5]}", "cannot read --values"),  # was: ValueError (int digits)
        ('{"albedo": [1' + "0" * 400 + ", 0.5, 0.5]}", "is outside its range"),  # was: OverflowError
    ],
    ids=["deep", "digits", "overflow"],
)
def test_render_values_refused_in_one_line(folder, text, fragment):
    (folder / "v.json").write_text(text)
    before = listing(folder)
    run = strauss_fit("render", "scene.toml", "--model", "lambert", "--values", "v.json", "-o", "o.exr", cwd=folder)
    assert_refused(run, fragment)
    assert listing(folder) == before


def test_render_values_of_another_result(folder, capsys, monkeypatch):
    """Was: 'unknown lambert parameter(s)' listing every key of the file."""
    (folder / "v.json").write_text(json.dumps(scene_result() | {"values": None}))
    args = ["render", "scene.toml", "--model", "lambert", "--values", "v.json", "-o", "o.exr"]
    run = in_process(*args, cwd=folder, capsys=capsys, monkeypatch=monkeypatch)
    assert_refused(run, "is a result without a model's 'values'")


def test_render_output_is_never_its_values_file(folder):
    """Was: -o naming the --values file replaced it by the image (with --force)."""
    (folder / "v.exr").write_text('{"albedo": [0.5, 0.5, 0.5]}')
    before = listing(folder)
    run = strauss_fit(
        "render", "scene.toml", "--model", "lambert", "--values", "v.exr", "-o", "v.exr", "--force", cwd=folder
    )
    assert_refused(run, "-o v.exr is the input --values")
    assert listing(folder) == before


# --- compare ---------------------------------------------------------------------------------


def test_compare_output_that_is_a_folder(folder):
    """Was: ValueError ('/' has an empty name) from the figure's path."""
    run = strauss_fit("compare", "t.exr", "--scene", "scene.toml", "--models", "lambert", "-o", "/", cwd=folder)
    assert_refused(run, "-o / is a folder")


def test_compare_capture_noise_out_of_range(capture, tmp_path):
    """Was: χ² = inf, then a ValueError traceback writing the comparison."""
    run = strauss_fit(
        "compare", "--capture", capture, "--models", "lambert", "--noise", "1e-320", "-o", "c.json", cwd=tmp_path
    )
    assert_refused(run, "--noise must be from 1e-100")
    assert listing(tmp_path) == {}


# --- report and sample of a capture's result; a capture's chain ------------------------------


@pytest.mark.parametrize(
    "changes, fragment",
    [
        ({"capture": 5}, "its 'capture' is a whole number, not text or a list"),  # was: TypeError
        ({"values": {"albedo": "x"}}, "its values are not numbers"),  # was: ValueError
    ],
    ids=["capture-int", "values-text"],
)
def test_report_of_a_damaged_capture_result(folder, changes, fragment):
    (folder / "r.json").write_text(json.dumps(scene_result(**changes)))
    before = listing(folder)
    run = strauss_fit("report", "--fit", "r.json", "-o", "rep.html", cwd=folder)
    assert_refused(run, fragment)
    assert listing(folder) == before


def test_sample_of_a_capture_result_holding_nan(folder):
    """Was: sampled, then a ValueError traceback writing the chain's metadata (NaN is not JSON)."""
    (folder / "r.json").write_text(json.dumps(scene_result(uncertainty_circle={"albedo": [float("nan")] * 3})))
    before = listing(folder)
    run = strauss_fit("sample", "--fit", "r.json", "-o", "c.h5", "--max-steps", "20", "--quiet", cwd=folder)
    assert_refused(run, "holds NaN or infinity")
    assert listing(folder) == before


def test_sample_of_a_singular_sandwich_refused_before_sampling(folder):
    """One image's fit whose values trade off exactly (correlation 1, as a Lambert fit of one
    target gives): the affine adjustment cannot map to it. Was: the whole chain sampled, then
    the error, and CHAIN.h5 left behind without its summary."""
    result = scene_result(residual={"verdict": "mismatch", "relative_rms": 0.1})
    result["correlation"]["matrix"] = np.ones((3, 3)).tolist()
    (folder / "r.json").write_text(json.dumps(result))
    before = listing(folder)
    run = strauss_fit("sample", "--fit", "r.json", "-o", "c.h5", "--max-steps", "20", "--quiet", cwd=folder)
    assert_refused(run, "sandwich is singular", "--adjust temperature")
    assert listing(folder) == before


def test_report_of_a_capture_chain_with_damaged_metadata(folder):
    """Was: a ValueError traceback (x_hat not numbers) deep in the report."""
    labels = ["albedo_r", "albedo_g", "albedo_b"]
    meta = {
        "kind": "capture",
        "labels": labels,
        "fit": scene_result(),
        "sigma": 0.01,
        "prior": {label: [0.0, 10.0] for label in labels},
        "x_hat": "x",
    }
    with h5py.File(folder / "c.h5", "w") as f:
        g = f.create_group("mcmc")
        g.attrs.update(iteration=3, nwalkers=8, ndim=3, has_blobs=False)
        g.create_dataset("chain", data=np.full((3, 8, 3), 0.4))
        g.create_dataset("log_prob", data=np.zeros((3, 8)))
        g.create_dataset("accepted", data=np.zeros(8))
        m = f.create_group("strauss_fit")
        m.attrs.update(format="strauss-fit chain", format_version=1, metadata=json.dumps(meta))
    before = listing(folder)
    run = strauss_fit("report", "--chain", "c.h5", "-o", "rep.html", cwd=folder)
    assert_refused(run, "metadata is damaged ('x_hat'")
    assert listing(folder) == before


@pytest.mark.parametrize(
    "extra, fragment",
    [
        (["--loss", "huber"], "--loss is not available with --model lambert"),
        (["--solver", "bfgs"], "--solver is not available with --model lambert"),
        (["--edge-pixels", "include"], "--edge-pixels is not available with --model lambert"),
        (["--precision", "float32"], "--precision is not available with --model lambert"),
        (["--fit-exposure"], "--fit-exposure is not available with --model lambert: its scale is unbounded"),
    ],
)
def test_model_fit_refuses_defaulted_options_it_would_ignore(folder, extra, fragment, capsys, monkeypatch):
    # each was accepted and silently ignored: the fit written was the default one
    before = listing(folder)
    args = ["fit", "t.exr", "--scene", "scene.toml", "--model", "lambert", *extra, "-o", "r.json"]
    assert_refused(in_process(*args, cwd=folder, capsys=capsys, monkeypatch=monkeypatch), fragment)
    assert listing(folder) == before


def test_capture_fit_refuses_a_loss_it_would_ignore(capture, tmp_path, capsys, monkeypatch):
    args = ["fit", "--capture", capture, "--model", "lambert", "--loss", "cauchy", "-o", "r.json"]
    assert_refused(in_process(*args, cwd=tmp_path, capsys=capsys, monkeypatch=monkeypatch), "--loss is not available")
    assert listing(tmp_path) == {}
