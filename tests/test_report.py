"""The uncertainty report: Laplace-against-posterior comparison rules, degeneracy warnings,
the self-contained HTML and Markdown, and `strauss-fit report` end to end."""

import json
import re
import tomllib

import numpy as np
import pytest

import strauss_fit as sf
from strauss_fit.fit import FitOptions, fit
from strauss_fit.io import write_image
from strauss_fit.posterior import LogPosterior, default_prior, laplace_covariance
from strauss_fit.report import build_report, render_fit
from strauss_fit.sample import SampleSettings, initial_walkers, load_chain, run_sampler
from strauss_fit.scene import parse_scene
from strauss_fit.target import Target
from strauss_fit.uncertainty import Laplace, compare, degeneracy_warnings, posterior_summary
from strauss_fit_cli.main import main

SCENE = """
[camera]
width = 24
height = 24
[material]
color = [0.5, 0.5, 0.5]
smoothness = 0.5
metalness = 0.2
[[light]]
kind = "directional"
direction = [0.3, 0.5, 1.0]
intensity = 1.0
[[light]]
kind = "directional"
direction = [-0.6, -0.2, 0.8]
intensity = 0.5
[[light]]
kind = "ambient"
intensity = 0.1
"""
TRUTH = dict(color=(0.7, 0.4, 0.2), smoothness=0.6, metalness=0.4)


def make_target(scene, material, noise=0.01, seed=0):
    image, mask = sf.render(scene, material)
    pixels = np.asarray(image) + noise * np.random.default_rng(seed).normal(size=np.shape(image))
    return Target(pixels, np.ones(mask.shape, bool), "synthetic.exr", "linear", 0, 0)


# --- the comparison rules on synthetic samples ------------------------------------------------

def laplace_of(x_hat, sd, at_bound=()):
    labels = [f"p{i}" for i in range(len(x_hat))]
    return Laplace(labels, np.asarray(x_hat, float), np.asarray(sd, float), np.eye(len(x_hat)), list(at_bound))


def compare_samples(laplace, samples, lower=0.0, upper=1.0):
    k = samples.shape[1]
    summary = posterior_summary(samples, laplace.labels)
    return compare(laplace, summary, samples, np.full(k, lower), np.full(k, upper))


def test_gaussian_posterior_matching_laplace_raises_no_note():
    rng = np.random.default_rng(0)
    samples = rng.normal([0.5, 0.3], [0.02, 0.01], size=(40000, 2))
    rows, notes = compare_samples(laplace_of([0.5, 0.3], [0.02, 0.01]), samples)
    assert notes == [] and all(r.issues == [] for r in rows)
    assert rows[0].width_ratio == pytest.approx(1.0, abs=0.03)


def test_wider_posterior_shift_and_skew_are_named():
    rng = np.random.default_rng(1)
    wide = rng.normal(0.5, 0.04, size=(40000, 1))
    rows, notes = compare_samples(laplace_of([0.5], [0.02]), wide)
    assert rows[0].issues == ["width"] and re.search(r"the posterior is 1\.9\d times as wide as", notes[0])
    shifted = rng.normal(0.52, 0.02, size=(40000, 1))
    rows, notes = compare_samples(laplace_of([0.5], [0.02]), shifted)
    assert "shift" in rows[0].issues and "1.0 posterior standard deviations" in " ".join(notes)
    skewed = 0.4 + rng.lognormal(np.log(0.05), 0.6, size=(40000, 1))
    rows, notes = compare_samples(laplace_of([0.45], [0.03]), skewed)
    assert "skew" in rows[0].issues and "upper tail" in " ".join(notes)


def test_a_posterior_cut_by_a_bound_gets_a_one_sided_limit():
    rng = np.random.default_rng(2)
    pinned = np.abs(rng.normal(0.0, 0.02, size=(40000, 1)))  # the fit put m on 0
    rows, notes = compare_samples(laplace_of([0.0], [0.0], at_bound=["p0"]), pinned)
    assert rows[0].issues == ["bound"]
    assert "one-sided with a 95 % upper limit of 0.04" in notes[0]
    near = rng.normal(0.99, 0.01, size=(80000, 1))
    near = near[near <= 1.0][:, None]  # truncated at the upper bound 1
    rows, notes = compare_samples(laplace_of([0.99], [0.01]), near)
    assert "bound" in rows[0].issues and "runs into the bound 1" in notes[0] and "lower limit" in notes[0]


def test_a_width_due_to_a_pinned_partner_is_blamed_on_it():
    # the fit pinned p0 on 0; p1 moves with p0 in the posterior, so the Laplace deviation of
    # p1 (p0 held fixed) is too small, and not because of any non-linearity
    rng = np.random.default_rng(6)
    p0 = np.abs(rng.normal(0.0, 0.02, 40000))
    p1 = 0.5 + p0 + rng.normal(0, 0.005, 40000)
    rows, notes = compare_samples(laplace_of([0.0, 0.5], [0.0, 0.005], at_bound=["p0"]), np.column_stack([p0, p1]))
    assert "width" in rows[1].issues
    width_note = next(n for n in notes if n.startswith("p1: the posterior is"))
    assert "the Laplace estimate holds p0 fixed on its bound" in width_note and "not linear" not in width_note


def test_a_banana_shaped_posterior_is_named():
    rng = np.random.default_rng(3)
    a = rng.normal(0.5, 0.05, 40000)
    b = 0.3 + 20 * (a - 0.5) ** 2 + rng.normal(0, 0.005, 40000)
    rows, notes = compare_samples(laplace_of([0.5, 0.35], [0.05, 0.05]), np.column_stack([a, b]))
    assert any("banana-shaped" in n and "p0" in n and "p1" in n for n in notes)


# --- degeneracy warnings ------------------------------------------------------------------------

def test_transparency_trading_with_the_brightness_of_c_is_said_in_words():
    # t moves with the overall brightness of C; no single channel pair is the story
    rng = np.random.default_rng(4)
    brightness = rng.normal(0, 1, 20000)
    channels = [brightness + 0.2 * rng.normal(size=20000) for _ in range(3)]
    t = brightness + 0.1 * rng.normal(size=20000)
    s = rng.normal(size=20000)
    samples = np.column_stack(channels + [s, t]) * 0.1 + 0.5  # deviations 0.1: loose
    labels = ["color_r", "color_g", "color_b", "smoothness", "transparency"]
    held = {"ior": {"value": 1.5, "reason": "no refraction is traced"},
            "metalness": {"value": 0.0, "reason": "fixed by the user (--fix)"}}
    warnings = degeneracy_warnings(labels, np.cov(samples, rowvar=False), held)
    assert warnings[0].startswith("t (transparency) and the brightness of C trade off")
    assert "this scene cannot separate them" in warnings[0]
    # channel-against-channel and channel-against-t pairs are explained by the first warning
    assert not any("channel of C" in w for w in warnings)
    assert any(w.startswith("n (index of refraction) was not fitted: no refraction is traced") for w in warnings)
    assert not any("m (metalness)" in w for w in warnings)  # the user's own choice is not a warning
    independent = np.random.default_rng(5).normal(size=(20000, 5))
    assert degeneracy_warnings(labels, np.cov(independent, rowvar=False)) == []


@pytest.fixture(scope="module")
def degenerate_fit():
    """The local model (depth 1) with t freed by force: t only dims the surface, which the
    colour's brightness mimics (the fit would hold t on its own for that reason)."""
    scene = parse_scene(tomllib.loads(SCENE + "\n[render]\ndepth = 1\n"), source="degenerate")
    truth = sf.Material(**TRUTH, transparency=0.3)
    target = make_target(scene, truth)
    result = fit(scene, target, FitOptions(free=("color", "smoothness", "metalness", "transparency")))
    return scene, target, result


def test_a_degenerate_scene_is_flagged_from_laplace_and_from_the_posterior(degenerate_fit):
    scene, target, result = degenerate_fit
    payload = result.to_json()
    fitted, used = render_fit(scene, target, payload)
    report = build_report(payload, target.pixels, fitted, used)
    flagged = [w for w in report.data["warnings"] if "t (transparency) and the brightness of C trade off" in w]
    assert flagged and "cannot separate them" in flagged[0] and "Laplace estimate" in flagged[0]
    assert "t (transparency) and the brightness of C trade off" in report.html
    # and from a (short) chain
    problem, x = result.problem, np.asarray(result.x)
    prior = default_prior(problem.layout, x)
    lp = LogPosterior(problem, prior, 0.01)
    start = initial_walkers(x, laplace_covariance(problem, x, 0.01), prior, 32, np.random.default_rng(0), lp)
    run = run_sampler(lp, None, start=start, settings=SampleSettings(max_steps=300))
    samples = run.chain[100:].reshape(-1, x.size)
    warnings = degeneracy_warnings(problem.layout.labels(), np.cov(samples, rowvar=False), values=x)
    # a short chain along a ridge this long (tau ~ 250 steps) has not spread over it yet, so
    # the wording may be the milder one; the pair is named either way
    assert any(w.startswith("t (transparency) and the brightness of C") and "posterior" in w for w in warnings)


def test_a_tight_correlation_is_reported_without_overstating_it():
    # two lights: m is pinned to about +-0.02 by the highlight's colour, though it still
    # correlates strongly with the brightness of C (both scale the diffuse term)
    scene = parse_scene(tomllib.loads(SCENE), source="opaque")
    result = fit(scene, make_target(scene, sf.Material(**TRUTH), seed=3), FitOptions(free=("color", "smoothness", "metalness")))
    lap = Laplace.from_fit(result.to_json())
    warnings = degeneracy_warnings(lap.labels, lap.covariance, values=lap.x_hat)
    assert warnings and all("strongly correlated" in w and "cannot separate" not in w for w in warnings)
    assert any(w.startswith("m (metalness) and the brightness of C are strongly correlated") for w in warnings)


# --- the report itself ------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def sampled(tmp_path_factory):
    """A fit and a short chain written by `strauss-fit sample`, files on disk."""
    folder = tmp_path_factory.mktemp("report")
    scene_path = folder / "scene.toml"
    scene_path.write_text(SCENE)
    scene = parse_scene(tomllib.loads(SCENE), source="opaque")
    write_image(folder / "target.exr", make_target(scene, sf.Material(**TRUTH), seed=7).pixels)
    assert main(["fit", str(folder / "target.exr"), "--scene", str(scene_path), "-o", str(folder / "fit.json"),
                 "--free", "color,smoothness,metalness", "--quiet"]) == 0
    assert main(["sample", str(folder / "target.exr"), "--scene", str(scene_path), "-o", str(folder / "chain.h5"),
                 "--fit", str(folder / "fit.json"), "--max-steps", "400", "--quiet"]) in (0, 1)
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
    for text in ("Warnings", "Target, fit and residual", "Parameters", "median", "16 %", "84 %", "2.5 %", "97.5 %",
                 "Laplace estimate against the posterior", "Correlations", "Corner plot", "Sampler diagnostics",
                 "effective samples", "τ (steps)"):
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


def test_report_from_a_fit_alone_uses_laplace_intervals(sampled, capsys):
    folder = sampled
    out = folder / "laplace.html"
    assert main(["report", "--fit", str(folder / "fit.json"), "-o", str(out)]) == 0
    page = out.read_text()
    check_self_contained(page)
    assert "16 % (Laplace)" in page and "No chain was given" in page
    assert "Sampler diagnostics" not in page
    assert "draws from the Laplace approximation" in page
    data = json.loads((folder / "fit.json").read_text())
    assert f"{data['smoothness'] - data['uncertainty']['smoothness']:.4g}" in page


@pytest.mark.parametrize("case,pattern", [
    ("nothing", "give a fit result (--fit RESULT.json), a chain (--chain CHAIN.h5), or both"),
    ("not-html", "give -o a .html name"),
    ("corrupt-chain", "not an HDF5 file"),
    ("not-a-fit", "is not a strauss-fit fit result"),
    ("other-mask", "give the target (and --mask) the fit was made with"),
])
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
    code = main(args)
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.startswith("strauss-fit: error: ") and err.count("\n") == 1, err
    assert pattern in err
    assert not out.exists()
