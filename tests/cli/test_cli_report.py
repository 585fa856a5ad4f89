"""``strauss-fit report`` end to end: a fit and a chain made by the commands, the report with
a chain (every section), from a fit alone (the fit's Gaussian intervals), and one-line errors."""

import json
import re

import numpy as np
import pytest

import strauss_fit as sf
from strauss_fit.inference.sampler import load_chain
from strauss_fit.inference.summaries import posterior_summary
from strauss_fit.io.images import write_image
from strauss_fit_cli.main import main
from support import SMALL_MATERIAL, key_and_fill_scene, key_and_fill_toml, noisy_target

TRUTH = dict(color=(0.7, 0.4, 0.2), smoothness=0.6, metalness=0.4)


def make_target(scene, material, noise=0.01, seed=0):
    return noisy_target(scene, material, noise, seed, path="synthetic.exr")


@pytest.fixture(scope="module")
def sampled(tmp_path_factory):
    """A fit and a short chain written by `strauss-fit sample`, files on disk."""
    folder = tmp_path_factory.mktemp("report")
    scene_path = folder / "scene.toml"
    scene_path.write_text(key_and_fill_toml(24, material=SMALL_MATERIAL))
    scene = key_and_fill_scene(24, material=SMALL_MATERIAL, source="opaque")
    write_image(folder / "target.exr", make_target(scene, sf.Material(**TRUTH), seed=7).pixels)
    assert (
        main(
            [
                "fit",
                str(folder / "target.exr"),
                "--scene",
                str(scene_path),
                "-o",
                str(folder / "fit.json"),
                "--free",
                "color,smoothness,metalness",
                "--quiet",
            ]
        )
        == 0
    )
    assert main(
        [
            "sample",
            str(folder / "target.exr"),
            "--scene",
            str(scene_path),
            "-o",
            str(folder / "chain.h5"),
            "--fit",
            str(folder / "fit.json"),
            "--max-steps",
            "400",
            "--quiet",
        ]
    ) in (0, 1)
    return folder


def check_self_contained(page: str) -> None:
    assert page.startswith("<!DOCTYPE html>")
    # nothing to fetch: no external URL, no script, every image inline
    assert not re.search(r"(src|href)\s*=\s*\"(?!data:)", page)
    assert "http://" not in page and "https://" not in page and "<script" not in page
    for image in re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', page):
        import base64

        assert base64.b64decode(image).startswith(b"\x89PNG\r\n\x1a\n")


def test_report_with_a_chain_has_every_section(sampled, capsys):
    folder = sampled
    out = folder / "report.html"
    code = main(["report", "--fit", str(folder / "fit.json"), "--chain", str(folder / "chain.h5"), "-o", str(out)])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    page = out.read_text()
    check_self_contained(page)
    assert page.count("data:image/png;base64,") == 4  # images, correlation, corner, trace
    for text in (
        "Warnings",
        "Target, fit and residual",
        "Parameters",
        "median",
        "16 %",
        "84 %",
        "2.5 %",
        "97.5 %",
        "against the posterior",
        "Correlations",
        "Corner plot",
        "Sampler diagnostics",
        "effective samples",
        "τ (steps)",
    ):
        assert text in page, text
    markdown = (folder / "report.md").read_text()
    for name in ("images.png", "correlation.png", "corner.png", "trace.png"):
        assert f"](report_files/{name})" in markdown
        assert (folder / "report_files" / name).read_bytes().startswith(b"\x89PNG")
    assert "| smoothness |" in markdown
    # the table's percentiles are the chain's
    chain = load_chain(folder / "chain.h5")
    summary = posterior_summary(chain.samples(chain.diagnostics().burn_in), chain.labels)
    assert f"{summary['parameters']['smoothness']['p97.5']:.4g}" in markdown
    # a 400-step chain is not 50 autocorrelation times long: the report says so first
    assert "The chain is not trustworthy yet" in page
    # no overwrite without --force, then with it
    code = main(["report", "--chain", str(folder / "chain.h5"), "-o", str(out)])
    assert code == 2 and "exists; pass --force" in capsys.readouterr().err
    assert main(["report", "--chain", str(folder / "chain.h5"), "-o", str(out), "--force"]) == 0


def test_report_from_a_fit_alone_uses_the_fits_gaussian_intervals(sampled, capsys):
    folder = sampled
    out = folder / "laplace.html"
    assert main(["report", "--fit", str(folder / "fit.json"), "-o", str(out)]) == 0
    page = out.read_text()
    check_self_contained(page)
    # the fit knew the target's noise (estimated from the image): its intervals are the noise sandwich
    data = json.loads((folder / "fit.json").read_text())
    name = "sandwich" if data["uncertainty_method"]["name"] == "noise sandwich" else "Laplace"
    assert f"16 % ({name})" in page and "No chain was given" in page
    assert "Sampler diagnostics" not in page
    assert "draws from the Gaussian N(x̂, Σ) of the" in page
    data = json.loads((folder / "fit.json").read_text())
    assert f"{data['smoothness'] - data['uncertainty']['smoothness']:.4g}" in page


@pytest.mark.parametrize(
    "case,pattern",
    [
        ("nothing", "give a fit result (--fit RESULT.json), a chain (--chain CHAIN.h5), or both"),
        ("not-html", "give -o a .html name"),
        ("corrupt-chain", "not an HDF5 file"),
        ("not-a-fit", "is not a strauss-fit fit result"),
        ("other-mask", "give the target (and --mask) the fit was made with"),
        # found by a hostile-user pass: these were KeyError and ValueError tracebacks
        ("frees-unknown", "frees '<b>x</b>', of which it records no value"),
        ("uncertainty-text", "the uncertainty of 'smoothness' is not a finite number"),
        ("ragged-correlation", "its correlation is not a square matrix"),
        # and --force overwrote the target where it lay in the report's own folder
        ("target-in-report-folder", "lies in"),
    ],
)
def test_report_bad_inputs_are_one_line_errors(sampled, capsys, tmp_path, case, pattern):
    folder = sampled
    out = tmp_path / "r.html"
    args = ["report", "-o", str(out)]
    if case == "nothing":
        pass
    elif case == "not-html":
        args = ["report", "--fit", str(folder / "fit.json"), "-o", str(tmp_path / "r.pdf")]
    elif case == "corrupt-chain":
        (tmp_path / "bad.h5").write_bytes(b"not a chain")
        args += ["--chain", str(tmp_path / "bad.h5")]
    elif case == "not-a-fit":
        (tmp_path / "x.json").write_text('{"hello": 1}')
        args += ["--fit", str(tmp_path / "x.json")]
    elif case == "other-mask":
        mask = np.ones((24, 24, 3))
        mask[:12] = 0
        write_image(tmp_path / "mask.png", mask)
        args += ["--fit", str(folder / "fit.json"), "--mask", str(tmp_path / "mask.png")]
    elif case in ("frees-unknown", "uncertainty-text", "ragged-correlation"):
        data = json.loads((folder / "fit.json").read_text())
        if case == "frees-unknown":
            data["free"] = ["<b>x</b>"]
        elif case == "uncertainty-text":
            data["uncertainty"]["smoothness"] = "abc"
        else:
            data["correlation"] = {"labels": ["x"], "matrix": [[1, 2], [3]]}
        (tmp_path / "bad.json").write_text(json.dumps(data))
        args += ["--fit", str(tmp_path / "bad.json")]
    elif case == "target-in-report-folder":
        (tmp_path / "r_files").mkdir()
        target = tmp_path / "r_files" / "images.exr"
        target.write_bytes((folder / "target.exr").read_bytes())
        before = target.read_bytes()
        args += ["--fit", str(folder / "fit.json"), "--target", str(target), "--force"]
    code = main(args)
    if case == "target-in-report-folder":
        assert target.read_bytes() == before
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.startswith("strauss-fit: error: ") and err.count("\n") == 1, err
    assert pattern in err
    assert not out.exists()


def damage(path, case):
    """Damage the chain file ``path`` in place, as a crash, a bug or a hand edit would."""
    import h5py

    with h5py.File(path, "a") as f:
        g = f["mcmc"]
        if case == "empty-metadata":
            f["strauss_fit"].attrs["metadata"] = "{}"
        elif case == "metadata-without-fit":
            meta = json.loads(f["strauss_fit"].attrs["metadata"])
            del meta["fit"]
            f["strauss_fit"].attrs["metadata"] = json.dumps(meta)
        elif case == "nan-in-chain":
            g["chain"][5, 3, 1] = np.nan
        elif case == "iteration-too-large":
            g.attrs["iteration"] = g["chain"].shape[0] + 50
        elif case == "accepted-wrong-shape":
            del g["accepted"]
            g.create_dataset("accepted", data=np.zeros(3))
        elif case == "no-random-state":
            for name in [k for k in g.attrs if k.startswith("random_state_")]:
                del g.attrs[name]


@pytest.mark.parametrize(
    "case,pattern,commands",
    [
        ("empty-metadata", "metadata is damaged ('labels' must be a list", ("report", "resume")),
        ("metadata-without-fit", "metadata is damaged (no 'fit'", ("report", "resume")),
        ("nan-in-chain", "1 of its sample values are NaN or infinite", ("report", "resume")),
        ("iteration-too-large", "steps but holds", ("report", "resume")),
        ("accepted-wrong-shape", "datasets' shapes disagree", ("report", "resume")),
        ("no-random-state", "its samples are damaged", ("resume",)),
    ],
)
def test_damaged_chains_are_one_line_errors_for_report_and_resume(sampled, capsys, tmp_path, case, pattern, commands):
    import shutil

    chain = tmp_path / "chain.h5"
    shutil.copy(sampled / "chain.h5", chain)
    damage(chain, case)
    before = chain.read_bytes()
    runs = {
        "report": ["report", "--chain", str(chain), "-o", str(tmp_path / "r.html")],
        "resume": ["sample", str(sampled / "target.exr"), "--scene", str(sampled / "scene.toml")]
        + ["-o", str(chain), "--resume", "--max-steps", "500", "--quiet"],
    }
    for command in commands:
        code = main(runs[command])
        err = capsys.readouterr().err
        assert code == 2, f"{command}: {err}"
        assert err.startswith("strauss-fit: error: ") and err.count("\n") == 1 and "Traceback" not in err, err
        assert pattern in err, f"{command}: {err}"
    assert chain.read_bytes() == before  # nothing was changed
    assert sorted(p.name for p in tmp_path.iterdir()) == ["chain.h5"]


def test_report_help_names_both_kinds_of_interval(capsys):
    # the fit's ± may be the noise sandwich: the help must not call it "Laplace ±"
    assert main(["report", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "noise sandwich or Laplace" in text
    assert "Laplace ±" not in text and "Laplace-versus-posterior" not in text


def test_text_quoted_from_the_fit_is_inert_in_the_markdown_and_one_line_on_the_terminal(sampled, capsys, tmp_path):
    """A warning, a note or a held parameter's reason holding markup, an escape sequence and a
    newline (hostile-user pass): the HTML escaped it already; the Markdown now keeps each on
    its line with the tag escaped, and stderr shows the warning on one line."""
    data = json.loads((sampled / "fit.json").read_text())
    evil = "<img src=x onerror=alert(1)>|**md**\x1b[31m\n# heading"
    data["warnings"].append({"code": "model-mismatch", "message": evil})
    data["notes"].append(evil)
    data["held"]["ior"]["reason"] = evil
    (tmp_path / "evil.json").write_text(json.dumps(data))
    out = tmp_path / "r.html"
    assert main(["report", "--fit", str(tmp_path / "evil.json"), "-o", str(out), "--title", "<script>x</script>"]) == 0
    err = capsys.readouterr().err
    markdown = out.with_suffix(".md").read_text()
    assert not re.search(r"(?<!\\)<(img|script)", markdown) and "\x1b" not in markdown
    assert "\n# heading" not in markdown and "\\<img src=x" in markdown
    ior_rows = [line for line in markdown.splitlines() if line.startswith("| ior |")]
    assert ior_rows and all(line.endswith("|") for line in ior_rows)
    assert "<img src=x" not in out.read_text()
    assert "\x1b" not in err and not any(line.startswith("# heading") for line in err.splitlines())


@pytest.mark.parametrize("how", ["given", "recorded"])
def test_the_library_refuses_to_overwrite_a_report_input_too(sampled, tmp_path, how):
    # report_from_files called directly, with force, and a target inside the report's
    # folder: given as an argument, or recorded in the fit result (known only once read)
    from strauss_fit import report_from_files
    from strauss_fit.errors import StraussFitError

    folder = sampled
    out = tmp_path / "r.html"
    (tmp_path / "r_files").mkdir()
    target = tmp_path / "r_files" / "images.exr"
    target.write_bytes((folder / "target.exr").read_bytes())
    before = target.read_bytes()
    fit = folder / "fit.json"
    if how == "recorded":
        data = json.loads(fit.read_text())
        data["target"] = str(target)
        fit = tmp_path / "fit.json"
        fit.write_text(json.dumps(data))
    given = {"target": str(target)} if how == "given" else {}
    with pytest.raises(StraussFitError, match="lies in"):
        report_from_files(out, fit=str(fit), force=True, **given)
    assert target.read_bytes() == before and not out.exists()
