"""``strauss-fit fit T1 T2 … --scene S --model NAME -o OUTDIR/``: several targets fitted with
another reflectance model than Strauss into a folder, under the Strauss batch's contract (one
result per target, exactly the single ``--model`` fit's; ``summary.csv`` with the model's
columns; failures one line each; ``--resume``; options the capture fitter does not take
refused before any work, the folder not even created).

The targets are 24 × 24 Lambertian spheres under ``key_and_fill.toml`` with known albedos:
one compiled program serves them all, so after the first fit each takes a fraction of a
second."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

import strauss_fit as sf
import support
from strauss_fit.rendering.reflectance import render_model
from strauss_fit_cli.main import main

SIZE = 24
ALBEDOS = ((0.6, 0.35, 0.2), (0.25, 0.5, 0.7), (0.8, 0.75, 0.3))
#: What differs between two runs of the same fit (times), and what only a folder records.
NOT_COMPARED = {"timing", "wall_time_s", "provenance"}


@pytest.fixture(scope="module")
def batch(tmp_path_factory):
    """A scene file, three slightly noisy Lambertian targets of it (EXR) and a damaged one."""
    root = tmp_path_factory.mktemp("model_batch")
    scene_path = root / "scene.toml"
    scene_path.write_text(support.key_and_fill_toml(SIZE))
    scene = sf.load_scene(scene_path)
    rng = np.random.default_rng(7)
    targets = []
    for i, albedo in enumerate(ALBEDOS):
        image, _ = render_model(scene, "lambert", {"albedo": list(albedo)})
        path = root / "images" / f"ball{i}.exr"
        path.parent.mkdir(exist_ok=True)
        sf.write_image(path, np.asarray(image) + rng.normal(0, 0.002, np.shape(image)))
        targets.append(path)
    broken = root / "broken" / "ball9.exr"
    broken.parent.mkdir()
    broken.write_bytes(b"not an image at all")
    return scene_path, targets, broken


def rows(folder: Path) -> list[dict]:
    with open(folder / "summary.csv", newline="") as handle:
        return list(csv.DictReader(handle))


def fit(*args) -> int:
    return main(["fit", *map(str, args)])


def listing(path: Path) -> dict[str, bytes]:
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


def test_three_targets_recover_their_albedos_as_the_single_fit_does(batch, tmp_path, capsys):
    scene, targets, _ = batch
    out = tmp_path / "out"
    assert fit(*targets, "--scene", scene, "--model", "lambert", "-o", f"{out}/") == 0, capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["ball0.json", "ball1.json", "ball2.json", "summary.csv"]
    assert "3 fitted, 0 failed, 0 kept from before" in capsys.readouterr().out
    table = rows(out)
    assert list(table[0])[:5] == ["target", "status", "error", "model", "verdict"]
    assert [r["target"] for r in table] == [str(t) for t in targets]
    for row, albedo in zip(table, ALBEDOS):
        result = json.loads((out / row["result"]).read_text())
        assert row["status"] == "ok" and row["model"] == "lambert" and result["model"] == "lambert"
        assert np.allclose(result["albedo"], albedo, atol=2e-3)
        # the summary holds the result's figures in full
        assert [float(row[f"albedo_{c}"]) for c in "rgb"] == result["values"]["albedo"]
        assert [float(row[f"sd_albedo_{c}"]) for c in "rgb"] == result["uncertainty"]["albedo"]
        assert float(row["relative_rms"]) == result["residual"]["relative_rms"]
        assert row["verdict"] == result["residual"]["verdict"] and row["solver_status"] == "successful"
    # each result is what the single --model fit writes for that target
    single = tmp_path / "single.json"
    assert fit(targets[1], "--scene", scene, "--model", "lambert", "-o", single, "--quiet") == 0
    one, many = json.loads(single.read_text()), json.loads((out / "ball1.json").read_text())
    assert {k: v for k, v in one.items() if k not in NOT_COMPARED} == {
        k: v for k, v in many.items() if k not in NOT_COMPARED
    }
    assert [float(table[1][f"albedo_{c}"]) for c in "rgb"] == one["values"]["albedo"]


def test_a_corrupt_target_fails_alone_in_one_line(batch, tmp_path, capsys):
    scene, targets, broken = batch
    out = tmp_path / "out"
    listing_file = tmp_path / "list.txt"
    listing_file.write_text(f"# the targets\n{targets[0]}\n{broken}\n{targets[2]}\n")
    assert fit(f"@{listing_file}", "--scene", scene, "--model", "lambert", "-o", out) == 1
    captured = capsys.readouterr()
    failures = [line for line in captured.err.splitlines() if line.startswith("fit: failed:")]
    assert len(failures) == 1 and str(broken) in failures[0] and "Traceback" not in captured.err
    assert "2 fitted, 1 failed" in captured.out
    table = rows(out)
    assert [r["status"] for r in table] == ["ok", "failed", "ok"]
    assert table[1]["error"] and "\n" not in table[1]["error"] and table[1]["model"] == "lambert"
    assert sorted(p.name for p in out.iterdir()) == ["ball0.json", "ball2.json", "summary.csv"]


def test_resume_keeps_finished_results_and_fits_the_missing_one(batch, tmp_path, capsys):
    scene, targets, _ = batch
    out = tmp_path / "out"
    argv = [*targets, "--scene", scene, "--model", "lambert", "-o", out]
    assert fit(*argv) == 0
    kept = {name: (out / name).read_bytes() for name in ("ball0.json", "ball2.json")}
    (out / "ball1.json").unlink()  # a run killed before this target's result
    capsys.readouterr()
    assert fit(*argv) == 2  # without --resume or --force: refused before any work
    assert "--resume" in capsys.readouterr().err
    assert fit(*argv, "--resume") == 0
    assert "1 fitted, 0 failed, 2 kept from before" in capsys.readouterr().out
    assert all((out / name).read_bytes() == data for name, data in kept.items())
    assert [r["status"] for r in rows(out)] == ["ok", "ok", "ok"]
    assert np.allclose(json.loads((out / "ball1.json").read_text())["albedo"], ALBEDOS[1], atol=2e-3)
    # results of another model are another configuration: refused, not mixed
    before = listing(out)
    assert fit(*targets, "--scene", scene, "--model", "phong", "-o", out, "--resume") == 2
    err = capsys.readouterr().err
    assert "different: the settings" in err and err.count("\n") == 1
    assert listing(out) == before
    # --force fits everything again
    assert fit(*argv, "--force", "--quiet") == 0
    assert "3 fitted, 0 failed, 0 kept from before" in capsys.readouterr().out


def test_a_folder_fitted_into_itself_resumes_and_a_manifest_gives_each_target_its_scene(batch, tmp_path, capsys):
    scene, targets, _ = batch
    images = tmp_path / "images"
    images.mkdir()
    for target in targets[:2]:
        (images / target.name).write_bytes(target.read_bytes())
    assert fit(images, "--scene", scene, "--model", "lambert", "-o", images) == 0
    # its results beside the images are results, not the targets' sidecars
    assert fit(images, "--scene", scene, "--model", "lambert", "-o", images, "--resume") == 0
    assert "0 fitted, 0 failed, 2 kept from before" in capsys.readouterr().out
    other = tmp_path / "other.toml"
    other.write_text(scene.read_text())
    manifest = tmp_path / "targets.csv"
    manifest.write_text(f"target,scene\n{targets[0]},{other}\n{targets[2]},\n")
    out = tmp_path / "out"
    assert fit("--manifest", manifest, "--scene", scene, "--model", "lambert", "-o", out) == 0
    recorded = [json.loads((out / f"ball{i}.json").read_text())["scene"] for i in (0, 2)]
    assert recorded == [str(other), str(scene)]


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--workers", "2"], "--workers is not available with --model lambert"),
        (["--compare"], "--compare is not available with --model lambert"),
        (["--fix", "albedo=0.5"], "--fix is not available with --model lambert"),
        (["--chunk-size", "8"], "--chunk-size is not available with --model lambert"),
        (["--render-fit", "fit.exr"], "--render-fit is not available with --model lambert"),
        (["--stability"], "--stability is for captures"),
        (["--scene", "missing.toml"], "scene file not found"),
    ],
)
def test_refused_options_write_nothing_not_even_the_folder(batch, tmp_path, capsys, monkeypatch, extra, message):
    scene, targets, _ = batch
    monkeypatch.chdir(tmp_path)
    scene_args = [] if "--scene" in extra else ["--scene", scene]
    code = fit(*targets[:2], *scene_args, "--model", "lambert", "-o", "out/", *extra)
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.startswith("strauss-fit: error: ") and err.count("\n") == 1 and message in err, err
    assert listing(tmp_path) == {} and not (tmp_path / "out").exists()


def test_one_target_into_a_folder_is_a_batch_and_resume_needs_a_folder(batch, tmp_path, capsys, monkeypatch):
    scene, targets, _ = batch
    monkeypatch.chdir(tmp_path)
    assert fit(targets[0], "--scene", scene, "--model", "lambert", "-o", "out/", "--quiet") == 0
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["ball0.json", "summary.csv"]
    capsys.readouterr()
    assert fit(targets[0], "--scene", scene, "--model", "lambert", "-o", "r.json", "--resume") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--resume is for several targets fitted into a folder" in err
    assert not (tmp_path / "r.json").exists()
