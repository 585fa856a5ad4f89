"""``strauss-fit sample`` end to end: chain and summary written and resumed, a fit result
reused, one-line errors for bad inputs, a chain of another target refused, and Ctrl-C."""

import json
import os
import signal

import h5py
import numpy as np
import pytest

import strauss_fit as sf
from strauss_fit.inference.sampler import load_chain
from strauss_fit.io.images import write_image
from strauss_fit_cli.main import main
from support import SMALL_MATERIAL, key_and_fill_toml, noisy_target

TRUTH = dict(color=(0.7, 0.4, 0.2), smoothness=0.6, metalness=0.4)
NOISE = 0.01


def make_target(scene, material, noise=NOISE, seed=0):
    return noisy_target(scene, material, noise, seed)


def run_cli(capsys, *argv):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.fixture(scope="module")
def files(tmp_path_factory, small_key_and_fill):
    folder = tmp_path_factory.mktemp("cli")
    (folder / "scene.toml").write_text(key_and_fill_toml(24, material=SMALL_MATERIAL))
    write_image(folder / "target.exr", make_target(small_key_and_fill, sf.Material(**TRUTH), seed=21).pixels)
    return folder


def test_sample_command_writes_chain_and_summary_and_resumes(files, capsys):
    chain, summary = files / "chain.h5", files / "chain.json"
    code, out, err = run_cli(
        capsys,
        "sample",
        files / "target.exr",
        "--scene",
        files / "scene.toml",
        "-o",
        chain,
        "--free",
        "color,smoothness,metalness",
        "--max-steps",
        "150",
        "--check-every",
        "50",
    )
    assert code == 1, err  # 150 steps are far from 50 autocorrelation times: ran, but not trustworthy
    assert "NOT trustworthy" in out and "autocorrelation times long" in out
    assert "sample [" in err  # the progress bar
    data = json.loads(summary.read_text())
    assert data["steps"] == 150 and data["labels"] == ["color_r", "color_g", "color_b", "smoothness", "metalness"]
    assert data["sigma"] == pytest.approx(NOISE, rel=0.1) and "estimated" in data["sigma_source"]
    for key in ("p2.5", "p16", "median", "p84", "p97.5"):
        assert key in data["posterior"]["parameters"]["smoothness"]
    assert set(data["diagnostics"]) >= {"tau", "ess", "acceptance_mean", "trustworthy", "reasons"}
    # a second run refuses to overwrite
    code, _, err = run_cli(capsys, "sample", files / "target.exr", "--scene", files / "scene.toml", "-o", chain)
    assert code == 2 and "exists; pass --force" in err
    # resume to 250 steps: the first 150 are kept as they were
    before = load_chain(chain).chain
    code, out, err = run_cli(
        capsys,
        "sample",
        files / "target.exr",
        "--scene",
        files / "scene.toml",
        "-o",
        chain,
        "--resume",
        "--max-steps",
        "250",
        "--check-every",
        "50",
    )
    assert code in (0, 1), err
    after = load_chain(chain).chain
    assert after.shape[0] == 250
    np.testing.assert_array_equal(after[:150], before)
    assert json.loads(summary.read_text())["steps"] == 250


def test_sample_reuses_a_fit_result(files, capsys, tmp_path):
    fit_json = tmp_path / "fit.json"
    code, _, err = run_cli(
        capsys,
        "fit",
        files / "target.exr",
        "--scene",
        files / "scene.toml",
        "-o",
        fit_json,
        "--free",
        "color,smoothness,metalness",
    )
    assert code == 0, err
    chain = tmp_path / "c.h5"
    code, out, err = run_cli(
        capsys,
        "sample",
        files / "target.exr",
        "--scene",
        files / "scene.toml",
        "-o",
        chain,
        "--fit",
        fit_json,
        "--sigma",
        "0.01",
        "--max-steps",
        "60",
        "--walkers",
        "20",
        "--quiet",
    )
    assert code == 1, err
    assert err == ""  # --quiet
    loaded = load_chain(chain)
    assert loaded.chain.shape == (60, 20, 5)
    assert loaded.meta["sigma"] == 0.01 and loaded.meta["sigma_source"] == "given (--sigma)"
    np.testing.assert_allclose(loaded.meta["x_hat"][3], json.loads(fit_json.read_text())["smoothness"])


@pytest.mark.parametrize(
    "case,pattern",
    [
        ("sigma-zero", "argument --sigma: expected a number > 0, got 0"),
        ("sigma-negative", "argument --sigma: expected a number > 0, got -0.5"),
        ("corrupt-chain", "not an HDF5 file"),
        ("foreign-chain", "not a strauss-fit chain"),
        ("resume-missing", "chain file not found"),
        ("no-usable-pixels", "no usable sphere pixels"),
        ("resume-and-force", "give one of them"),
        ("odd-walkers", "--walkers must be even"),
        ("bad-prior", "--prior expects NAME=LOW,HIGH"),
        ("resume-sigma", "cannot change when resuming"),
        ("fit-and-free", "applies only when sample fits first"),
    ],
)
def test_sample_bad_inputs_are_one_line_errors(files, capsys, tmp_path, case, pattern):
    chain = tmp_path / "c.h5"
    target = files / "target.exr"
    extra = []
    if case == "sigma-zero":
        extra = ["--sigma", "0"]
    elif case == "sigma-negative":
        extra = ["--sigma", "-0.5"]
    elif case == "corrupt-chain":
        chain.write_bytes(b"garbage" * 20)
        extra = ["--resume"]
    elif case == "foreign-chain":
        with h5py.File(chain, "w") as f:
            f.create_group("mcmc")
        extra = ["--resume"]
    elif case == "resume-missing":
        extra = ["--resume"]
    elif case == "no-usable-pixels":
        target = tmp_path / "white.png"
        write_image(target, np.ones((24, 24, 3)))  # every pixel clipped
    elif case == "resume-and-force":
        extra = ["--resume", "--force"]
    elif case == "odd-walkers":
        extra = ["--walkers", "33"]
    elif case == "bad-prior":
        extra = ["--prior", "smoothness=0.2"]
    elif case == "resume-sigma":
        extra = ["--resume", "--sigma", "0.1"]
    elif case == "fit-and-free":
        extra = ["--fit", tmp_path / "fit.json", "--free", "color"]
    before = chain.read_bytes() if chain.is_file() else None
    code, _, err = run_cli(capsys, "sample", target, "--scene", files / "scene.toml", "-o", chain, *extra)
    assert code == 2, err
    assert err.startswith("strauss-fit: error: ") and err.count("\n") == 1, err
    assert pattern in err
    assert (chain.read_bytes() if chain.is_file() else None) == before  # nothing written or damaged
    assert not (tmp_path / "c.json").exists()


def test_resume_refuses_a_chain_of_another_target(files, capsys, tmp_path, small_key_and_fill):
    scene = small_key_and_fill
    chain = tmp_path / "c.h5"
    code, _, err = run_cli(
        capsys,
        "sample",
        files / "target.exr",
        "--scene",
        files / "scene.toml",
        "-o",
        chain,
        "--free",
        "color,smoothness,metalness",
        "--max-steps",
        "20",
        "--quiet",
    )
    assert code == 1, err
    other = tmp_path / "other.exr"
    write_image(other, make_target(scene, sf.Material(**TRUTH), seed=99).pixels)
    code, _, err = run_cli(capsys, "sample", other, "--scene", files / "scene.toml", "-o", chain, "--resume")
    assert code == 2 and "was sampled for another target" in err


def test_ctrl_c_during_sample_exits_130_and_keeps_the_steps(files, capsys, tmp_path, monkeypatch):
    from strauss_fit_cli import sample_cmd

    def press_ctrl_c(self, progress):
        os.kill(os.getpid(), signal.SIGINT)  # at the first check (step 20)

    monkeypatch.setattr(sample_cmd.ProgressBar, "__call__", press_ctrl_c)
    chain = tmp_path / "c.h5"
    code, _, err = run_cli(
        capsys,
        "sample",
        files / "target.exr",
        "--scene",
        files / "scene.toml",
        "-o",
        chain,
        "--free",
        "color,smoothness,metalness",
        "--check-every",
        "20",
        "--walkers",
        "16",
    )
    assert code == 130
    assert f"{chain} keeps all 21 steps sampled so far (continue with --resume)" in err
    assert load_chain(chain).chain.shape == (21, 16, 5)
