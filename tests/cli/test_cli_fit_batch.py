"""``strauss-fit fit`` with several targets into a folder (issue 16): outputs, summary,
failures, resume, lists, manifests, a killed run, and bad input (a scene or mask every
target shares is checked before any work; existing results are counted without the
summary)."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import strauss_fit as sf
import support
from strauss_fit_cli.main import main

SIZE = 24


@pytest.fixture(scope="module")
def batch(tmp_path_factory):
    """A scene file and five noisy targets of it (EXR), plus a damaged one."""
    root = tmp_path_factory.mktemp("batch")
    scene_path = root / "scene.toml"
    scene_path.write_text(support.key_and_fill_toml(SIZE))
    scene = sf.load_scene(scene_path)
    rng = np.random.default_rng(4)
    targets = []
    for i in range(5):
        material = sf.Material(
            color=tuple(rng.uniform(0.2, 0.8, 3)), smoothness=float(rng.uniform(0.2, 0.8)), metalness=0.0
        )
        image, _ = sf.render(scene, material)
        noisy = np.asarray(image) + rng.normal(0, 0.005, np.shape(image))
        path = root / "images" / f"sphere{i}.exr"
        path.parent.mkdir(exist_ok=True)
        sf.write_image(path, noisy)
        targets.append(path)
    broken = root / "broken" / "sphere9.exr"
    broken.parent.mkdir()
    broken.write_bytes(b"not an image at all")
    return scene_path, targets, broken


def rows(folder: Path) -> list[dict]:
    with open(folder / "summary.csv", newline="") as handle:
        return list(csv.DictReader(handle))


def test_several_targets_write_a_result_each_and_a_summary(batch, tmp_path, capsys):
    scene, targets, _ = batch
    out = tmp_path / "out"
    code = main(["fit", *map(str, targets[:3]), "--scene", str(scene), "-o", str(out), "--compare", "--noise", "0.005"])
    assert code == 0, capsys.readouterr().err
    names = sorted(p.name for p in out.iterdir())
    assert names == sorted(
        [f"sphere{i}.json" for i in range(3)] + [f"sphere{i}.compare.png" for i in range(3)] + ["summary.csv"]
    )
    table = rows(out)
    assert [r["target"] for r in table] == [str(t) for t in targets[:3]]
    assert all(r["status"] == "ok" and r["verdict"] == "consistent" for r in table)
    # each result is the fit the single command gives
    single = tmp_path / "single.json"
    assert main(["fit", str(targets[1]), "--scene", str(scene), "-o", str(single), "--noise", "0.005"]) in (0, 1)
    one, many = json.loads(single.read_text()), json.loads((out / "sphere1.json").read_text())
    for key in ("color", "smoothness", "metalness", "free", "uncertainty", "warnings"):
        assert one[key] == many[key]
    assert float(table[1]["smoothness"]) == many["smoothness"]
    assert "3 fitted, 0 failed" in capsys.readouterr().out


def test_a_bad_target_fails_alone_and_resume_fits_only_what_is_missing(batch, tmp_path, capsys):
    scene, targets, broken = batch
    out = tmp_path / "out"
    listing = tmp_path / "list.txt"
    listing.write_text(f"# the targets\n{targets[0]}\n{broken}\n{targets[2]}\n")
    code = main(["fit", f"@{listing}", "--scene", str(scene), "-o", str(out), "--noise", "0.005"])
    assert code == 1
    table = rows(out)
    assert [r["status"] for r in table] == ["ok", "failed", "ok"]
    assert "sphere9" in table[1]["target"] and table[1]["error"]
    assert not (out / "sphere9.json").exists()
    # without --resume or --force existing results are refused before any work
    capsys.readouterr()
    assert main(["fit", f"@{listing}", "--scene", str(scene), "-o", str(out)]) == 2
    assert "--resume" in capsys.readouterr().err
    # --resume keeps the results (same bytes) and tries the failed one again
    before = (out / "sphere0.json").read_bytes()
    broken.write_bytes(targets[1].read_bytes())  # the damaged target is repaired meanwhile
    assert main(["fit", f"@{listing}", "--scene", str(scene), "-o", str(out), "--resume", "--noise", "0.005"]) == 0
    assert (out / "sphere0.json").read_bytes() == before
    assert [r["status"] for r in rows(out)] == ["ok", "ok", "ok"]
    assert "1 fitted, 0 failed, 2 kept from before" in capsys.readouterr().out


def test_folders_and_manifests_with_their_own_scenes(batch, tmp_path):
    scene, targets, _ = batch
    other = tmp_path / "other.toml"
    other.write_text(support.key_and_fill_toml(SIZE))
    manifest = tmp_path / "manifest.csv"
    manifest.write_text(f"target,scene,encoding\n{targets[3]},{other},linear\n{targets[4]},,auto\n")
    out = tmp_path / "out"
    assert main(["fit", "--manifest", str(manifest), "--scene", str(scene), "-o", str(out), "--noise", "0.005"]) == 0
    recorded = [json.loads((out / f"sphere{i}.json").read_text())["scene"] for i in (3, 4)]
    assert recorded == [str(other), str(scene)]
    folder_out = tmp_path / "folder_out"
    assert main(["fit", str(targets[0].parent), "--scene", str(scene), "-o", str(folder_out), "--noise", "0.005"]) == 0
    assert len(rows(folder_out)) == 5


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--render-fit", "x.png"], "--compare"),
        (["--resume", "--force"], "not both"),
        (["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "not both"),
        (["--workers", "0"], "from 1"),
    ],
)
def test_bad_batch_options_are_one_line_errors_before_any_work(batch, tmp_path, capsys, extra, message):
    scene, targets, _ = batch
    out = tmp_path / "out"
    code = main(["fit", str(targets[0]), str(targets[1]), "--scene", str(scene), "-o", str(out), *extra])
    err = capsys.readouterr().err
    assert code == 2 and message in err and "Traceback" not in err
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.parametrize(
    "case, message",
    [
        ("missing-scene", "scene file not found"),
        ("invalid-scene", "not valid TOML"),
        ("unreadable-scene", "cannot read scene file"),
        ("missing-mask", "image not found"),
        ("broken-mask", "mask.png"),
    ],
)
def test_a_bad_scene_or_mask_shared_by_every_target_is_refused_before_any_work(batch, tmp_path, capsys, case, message):
    # as with one target (exit 2, one line), not a failed row per target and exit 1
    scene, targets, _ = batch
    extra = []
    if case == "missing-scene":
        scene = tmp_path / "missing.toml"
    elif case == "invalid-scene":
        scene = tmp_path / "bad.toml"
        scene.write_text("garbage = [\n")
    elif case == "unreadable-scene":
        scene = tmp_path / "binary.toml"
        scene.write_bytes(b"\xff\xfe\x00 not text")
    elif case == "missing-mask":
        extra = ["--mask", str(tmp_path / "mask.png")]
    else:
        (tmp_path / "mask.png").write_bytes(b"not an image")
        extra = ["--mask", str(tmp_path / "mask.png")]
    out = tmp_path / "out"
    code = main(["fit", str(targets[0]), str(targets[1]), "--scene", str(scene), "-o", str(out), *extra])
    err = capsys.readouterr().err
    assert code == 2 and message in err, err
    assert err.startswith("strauss-fit: error: ") and err.count("\n") == 1 and "Traceback" not in err
    assert not out.exists()  # not even the folder


def test_existing_results_are_counted_without_the_summary(batch, tmp_path, capsys):
    scene, targets, _ = batch
    out = tmp_path / "out"
    out.mkdir()
    (out / "summary.csv").write_text("target,status\n")
    (out / "sphere0.json").write_text("{}")
    argv = ["fit", str(targets[0]), str(targets[1]), "--scene", str(scene), "-o", str(out)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "1 result(s) already in" in err and "sphere0.json" in err  # summary.csv is not a result
    (out / "sphere0.json").unlink()
    assert main(argv) == 2  # a summary alone would still be replaced: refused, and said so
    err = capsys.readouterr().err
    assert "result(s)" not in err and "already holds a summary.csv" in err and "--force" in err


def test_colliding_result_names_and_a_file_as_the_folder_are_refused(batch, tmp_path, capsys):
    scene, targets, broken = batch
    twin = tmp_path / "twin" / targets[0].name
    twin.parent.mkdir()
    twin.write_bytes(targets[0].read_bytes())
    code = main(["fit", str(targets[0]), str(twin), "--scene", str(scene), "-o", str(tmp_path / "o")])
    assert code == 2 and "same result" in capsys.readouterr().err
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    code = main(["fit", str(targets[0]), str(targets[1]), "--scene", str(scene), "-o", str(a_file)])
    assert code == 2 and "is a file" in capsys.readouterr().err
    single_only = ["fit", str(targets[0]), "--scene", str(scene), "-o", str(tmp_path / "r.json"), "--compare"]
    assert main(single_only) == 2 and "several targets" in capsys.readouterr().err


def test_a_killed_run_loses_only_the_targets_in_flight(batch, tmp_path):
    scene, targets, _ = batch
    out = tmp_path / "out"
    command = [sys.executable, "-m", "strauss_fit_cli.main", "fit", *map(str, targets)]
    command += ["--scene", str(scene), "-o", str(out), "--chunk-size", "1", "--noise", "0.005", "--quiet"]
    env = {**os.environ, "STRAUSS_FIT_CACHE_DIR": "off"}
    process = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and process.poll() is None:
        if (out / "sphere1.json").exists():
            break
        time.sleep(0.05)
    process.send_signal(signal.SIGKILL)
    process.wait()
    done = sorted(p.name for p in out.glob("*.json"))
    assert done and all(json.loads((out / name).read_text())["free"] for name in done)  # complete results only
    code = main(["fit", *map(str, targets), "--scene", str(scene), "-o", str(out), "--resume", "--noise", "0.005"])
    assert code == 0 and [r["status"] for r in rows(out)] == ["ok"] * 5
