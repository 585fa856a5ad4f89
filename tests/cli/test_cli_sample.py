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


def test_sample_takes_the_target_and_scene_a_fit_result_records(files, capsys, tmp_path):
    """``sample --fit`` reads TARGET, --scene, --mask and --encoding from the fit result, as
    ``report`` does (issue 24): the same chain as with them given; a recorded file that is
    gone is a one-line error naming it, and an explicit one wins."""
    target = tmp_path / "target.exr"
    target.write_bytes((files / "target.exr").read_bytes())
    fit_json = tmp_path / "fit.json"
    free = ["--free", "color,smoothness,metalness"]
    code, _, err = run_cli(capsys, "fit", target, "--scene", files / "scene.toml", "-o", fit_json, *free)
    assert code == 0, err
    short = ["--fit", fit_json, "--max-steps", "20", "--walkers", "20", "--quiet"]
    code, _, err = run_cli(capsys, "sample", "-o", tmp_path / "recorded.h5", *short)
    assert code == 1, err  # ran (20 steps: not trustworthy)
    code, _, err = run_cli(
        capsys, "sample", target, "--scene", files / "scene.toml", "-o", tmp_path / "given.h5", *short
    )
    assert code == 1, err
    recorded, given = load_chain(tmp_path / "recorded.h5"), load_chain(tmp_path / "given.h5")
    np.testing.assert_array_equal(recorded.chain, given.chain)
    for key in ("target", "scene", "mask", "encoding", "sigma", "x_hat"):
        assert recorded.meta[key] == given.meta[key], key
    # the recorded target is gone: sample and report say which, and what to give instead
    moved = tmp_path / "moved.exr"
    target.rename(moved)
    code, _, err = run_cli(capsys, "sample", "-o", tmp_path / "gone.h5", *short)
    assert code == 2 and err.count("\n") == 1, err
    assert f"records the target {target}, which no longer exists" in err and "give TARGET explicitly" in err
    code, _, err = run_cli(capsys, "report", "--fit", fit_json, "-o", tmp_path / "gone.html")
    assert code == 2 and err.count("\n") == 1 and "give --target explicitly" in err, err
    assert not (tmp_path / "gone.h5").exists() and not (tmp_path / "gone.html").exists()
    # an explicit TARGET wins (the scene still comes from the fit result)
    code, _, err = run_cli(capsys, "sample", moved, "-o", tmp_path / "moved.h5", *short)
    assert code == 1, err
    np.testing.assert_array_equal(load_chain(tmp_path / "moved.h5").chain, recorded.chain)
    # without --fit, TARGET and --scene are required, in one line
    code, _, err = run_cli(capsys, "sample", "-o", tmp_path / "none.h5")
    assert code == 2 and "give TARGET and --scene (or --fit RESULT.json" in err, err


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


# --- the summary table and the progress line ---------------------------------------------------


def summary_payload(samples, labels, x_hat):
    """A summary as :func:`strauss_fit.inference.summaries.summarise_chain` writes it, for
    ``format_summary``: the posterior of ``samples``, the fit's ``x_hat`` and made-up
    diagnostics."""
    from strauss_fit.inference.summaries import posterior_summary

    n = len(labels)
    diagnostics = dict(
        trustworthy=True, tau=[10.0] * n, ess=[1000.0] * n, steps=1000, walkers=32, tau_multiple=100.0,
        min_tau_multiple=50.0, burn_in=20, acceptance_mean=0.4, reasons=[],
    )  # fmt: skip
    return {
        "diagnostics": diagnostics,
        "uncertainty_method": "noise sandwich",
        "labels": labels,
        "laplace": {"x_hat": list(x_hat), "sd": list(samples.std(axis=0))},
        "posterior": posterior_summary(samples, labels),
        "sigma": 0.01,
        "adjustment": {"method": "none"},
        "comparison": {"notes": []},
        "warnings": [],
    }


def test_the_summary_separates_the_percentiles_of_a_narrow_posterior():
    from strauss_fit_cli.sample_cmd import format_summary

    # the green plastic's colour: 0.2311 ± 4e-5, which four digits print as 0.2311 in every
    # column; next to it a wide parameter, which keeps four digits
    rng = np.random.default_rng(5)
    samples = np.column_stack([rng.normal(0.23112, 4e-5, 20000), rng.normal(0.5, 0.05, 20000)])
    text = format_summary(summary_payload(samples, ["color_g", "smoothness"], [0.23112, 0.5]))
    lines = text.splitlines()
    table = lines[:4]
    assert table[0].split()[:8] == ["parameter", "fit", "sandwich", "±", "median", "16", "%", "84"]
    narrow, wide = table[2].split(), table[3].split()
    median, p16, p84 = narrow[3:6]  # label, fit, ±, median, 16 %, 84 %, ...
    assert len({p16, median, p84}) == 3, narrow
    assert float(p16) < float(median) < float(p84)
    for text_value, key in ((median, "median"), (p16, "p16"), (p84, "p84")):  # the values, rounded
        true = np.percentile(samples[:, 0], {"median": 50, "p16": 16, "p84": 84}[key])
        assert abs(float(text_value) - true) < 4e-5 / 2
    assert len(wide[3].replace("0.", "")) <= 4  # a wide posterior keeps four digits
    assert len({len(line) for line in table if line and not line.startswith("-")}) == 1  # still aligned


def test_the_summary_says_when_tempering_left_the_chain_as_it_was():
    from strauss_fit_cli.sample_cmd import format_summary

    samples = np.random.default_rng(6).normal(0.5, 0.05, (4000, 1))
    payload = summary_payload(samples, ["smoothness"], [0.5])
    payload["adjustment"] = {"method": "temperature", "temperature": 1.0}
    assert "T = 1, the chain as sampled is already at least as wide" in format_summary(payload)
    payload["adjustment"] = {"method": "temperature", "temperature": 2.5}
    assert "sampled with sigma x sqrt(T), T = 2.5" in format_summary(payload)


def progress_line(steps, needed, max_steps=2000):
    import io

    from strauss_fit.inference.sampler import Progress
    from strauss_fit_cli.sample_cmd import ProgressBar

    stream = io.StringIO()
    ProgressBar(False, stream)(Progress(steps, max_steps, steps, needed / 10, needed, 0.4, 300.0))
    return stream.getvalue()


def test_the_progress_line_is_not_full_while_sampling_goes_on():
    # before the chain is K tau long, the goal is that length
    assert "100/130 steps |" in progress_line(100, 130)
    # once it is, sampling goes on until tau settles: the goal is the cap, not the steps done
    # (which showed 800/800 and a full bar on every line)
    line = progress_line(800, 768)
    assert "800/2000 steps (needed 768: waiting for tau to settle)" in line
    assert "[" + "#" * 30 + "]" not in line
    assert "2000/2000 steps |" in progress_line(2000, 768) and "#" * 30 in progress_line(2000, 768)


def test_without_a_terminal_the_progress_line_comes_every_few_seconds():
    import io

    from strauss_fit.inference.sampler import Progress
    from strauss_fit_cli.sample_cmd import ProgressBar

    stream = io.StringIO()
    bar = ProgressBar(False, stream)
    for steps in (800, 900, 1000):  # long enough, tau not settled: checks seconds apart
        bar(Progress(steps, 2000, steps, 76.8, 768, 0.4, 300.0))
    assert len(stream.getvalue().splitlines()) == 1


def test_on_a_terminal_a_shorter_line_covers_the_longer_one_before_it():
    import io

    from strauss_fit.inference.sampler import Progress
    from strauss_fit_cli.sample_cmd import ProgressBar

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    stream = Terminal()
    bar = ProgressBar(False, stream)
    bar(Progress(1900, 2000, 1900, 76.8, 768, 0.4, 300.0))  # waiting for tau: the long line
    bar(Progress(2000, 2000, 2000, 76.8, 768, 0.4, 300.0))  # at the cap: a shorter one
    long, short = stream.getvalue().split("\r")[1:]
    assert "waiting" in long and "waiting" not in short and len(short) >= len(long)


def test_sample_help_says_where_sigma_comes_from(capsys):
    assert main(["sample", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "the target's noise as the fit found it when the fit knew it" in text
    assert "--loss linear" in text
