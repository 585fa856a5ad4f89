"""Issue 24's hostile-input pass over folder fits: outputs never replace inputs, FIFOs and
symbolic-link loops are named, each target is fitted once, ``--resume`` keeps only results
of the same run (and refits incomplete ones), and a cluster that cannot start leaves
nothing behind. Each test fails on the code before the fix (noted per test)."""

from __future__ import annotations

import csv
import hashlib
import json
import os
import socket
from pathlib import Path

import numpy as np
import pytest

import strauss_fit as sf
import support
from strauss_fit.fitting.batch import FitJob
from strauss_fit.fitting.folder import provenance
from strauss_fit.fitting.options import FitOptions
from strauss_fit_cli.main import main

SIZE = 24
FAST = ["--quality", "fast", "--noise", "0.005", "--free", "color,smoothness"]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """A folder as `strauss-fit synth` leaves it: two targets, each with its sidecar."""
    root = tmp_path_factory.mktemp("safety")
    scene_path = root / "scene.toml"
    scene_path.write_text(support.key_and_fill_toml(SIZE))
    scene = sf.load_scene(scene_path)
    rng = np.random.default_rng(24)
    folder = root / "data"
    folder.mkdir()
    for i in range(2):
        material = sf.Material(color=(0.6, 0.3, 0.2), smoothness=0.3 + 0.3 * i, metalness=0.0)
        image, _ = sf.render(scene, material)
        sf.write_image(folder / f"t{i}.exr", np.asarray(image) + rng.normal(0, 0.005, np.shape(image)))
        sidecar = {"format": "strauss-fit synth sample", "noise": {"per_channel": [0.005] * 3}}
        (folder / f"t{i}.json").write_text(json.dumps(sidecar))
    return scene_path, folder


def digests(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.md5(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir()) if p.is_file()}


def rows(folder: Path) -> list[dict]:
    with open(folder / "summary.csv", newline="") as handle:
        return list(csv.DictReader(handle))


@pytest.mark.parametrize("flag", [[], ["--force"], ["--resume"]])
def test_a_folder_fitted_into_itself_never_overwrites_its_sidecars(dataset, capsys, flag):
    # before: "2 result(s) already in ... pass --resume ... or --force", and either flag
    # replaced the sidecars with fit results
    scene, folder = dataset
    before = digests(folder)
    code = main(["fit", str(folder), "--scene", str(scene), "-o", f"{folder}/", *flag])
    err = capsys.readouterr().err
    assert code == 2 and "sidecar" in err and "--force" not in err and err.count("\n") == 1, err
    assert digests(folder) == before


def test_a_single_fit_onto_the_targets_sidecar_is_refused(dataset, capsys):
    scene, folder = dataset
    before = digests(folder)
    code = main(["fit", str(folder / "t0.exr"), "--scene", str(scene), "-o", str(folder / "t0.json"), "--force"])
    err = capsys.readouterr().err
    assert code == 2 and "sidecar" in err, err
    assert digests(folder) == before


def test_photos_fit_into_their_own_folder_and_resume_there(dataset, tmp_path, capsys):
    # without sidecars a target's folder is a fine place for its results, and a result
    # there is not mistaken for a sidecar when resuming
    scene, folder = dataset
    photos = tmp_path / "photos"
    photos.mkdir()
    for i in range(2):
        (photos / f"t{i}.exr").write_bytes((folder / f"t{i}.exr").read_bytes())
    argv = ["fit", str(photos), "--scene", str(scene), "-o", f"{photos}/", *FAST]
    assert main(argv) == 0, capsys.readouterr().err
    kept = (photos / "t0.json").read_bytes()
    capsys.readouterr()
    assert main([*argv, "--resume"]) == 0
    assert "0 fitted, 0 failed, 2 kept from before" in capsys.readouterr().out
    assert (photos / "t0.json").read_bytes() == kept


def test_outputs_never_name_a_manifest_or_a_list(dataset, tmp_path, capsys):
    scene, folder = dataset
    out = tmp_path / "out"
    out.mkdir()
    manifest = out / "summary.csv"  # the run's own summary would replace it
    manifest.write_text(f"target\n{folder / 't0.exr'}\n{folder / 't1.exr'}\n")
    code = main(["fit", "--manifest", str(manifest), "--scene", str(scene), "-o", str(out), "--force"])
    err = capsys.readouterr().err
    assert code == 2 and "would overwrite the input" in err and "summary.csv" in err, err


def test_the_same_target_twice_is_refused(dataset, tmp_path, capsys):
    # before: fitted twice, one JSON, two summary rows, exit 0
    scene, folder = dataset
    target = folder / "t0.exr"
    link = tmp_path / "t0.exr"
    link.symlink_to(target)
    for twice in ([target, target], [target, link]):
        code = main(["fit", *map(str, twice), "--scene", str(scene), "-o", str(tmp_path / "out")])
        err = capsys.readouterr().err
        assert code == 2 and "given twice" in err, err
    assert not (tmp_path / "out").exists()


def test_a_fifo_fails_its_own_target_and_the_others_are_fitted(dataset, tmp_path, capsys):
    # before: blocked for ever in open(), deaf to Ctrl-C, the good target never fitted
    scene, folder = dataset
    fifo = tmp_path / "fifo.exr"
    os.mkfifo(fifo)
    out = tmp_path / "out"
    code = main(["fit", str(fifo), str(folder / "t1.exr"), "--scene", str(scene), "-o", str(out), *FAST])
    assert code == 1
    table = rows(out)
    assert [r["status"] for r in table] == ["failed", "ok"]
    assert "not a regular file (a FIFO)" in table[0]["error"]
    capsys.readouterr()
    code = main(["fit", str(fifo), "--scene", str(scene), "-o", str(tmp_path / "r.json")])
    err = capsys.readouterr().err
    assert code == 2 and err.strip() == f"strauss-fit: error: image {fifo} is not a regular file (a FIFO)"
    for argv in (["fit", f"@{fifo}", "-o", str(out)], ["fit", "--manifest", str(fifo), "-o", str(out)]):
        assert main([*argv, "--scene", str(scene)]) == 2
        assert "is not a regular file (a FIFO)" in capsys.readouterr().err
    fifo_scene = tmp_path / "fifo.toml"
    os.mkfifo(fifo_scene)
    assert main(["fit", str(folder / "t1.exr"), "--scene", str(fifo_scene), "-o", str(tmp_path / "s.json")]) == 2
    assert f"scene file {fifo_scene} is not a regular file (a FIFO)" in capsys.readouterr().err


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda p: p.symlink_to(p), "is a symbolic link loop"),
        (lambda p: p.symlink_to(p.parent / "gone.exr"), "is a broken symbolic link (to "),
        (lambda p: None, "image not found"),
    ],
)
def test_a_target_that_is_not_a_file_is_named_for_what_it_is(dataset, tmp_path, capsys, make, message):
    # before: a symbolic-link loop was "image not found"
    scene, _ = dataset
    target = tmp_path / "target.exr"
    make(target)
    code = main(["fit", str(target), "--scene", str(scene), "-o", str(tmp_path / "r.json")])
    err = capsys.readouterr().err
    assert code == 2 and message in err and err.count("\n") == 1, err


def test_provenance_changes_with_every_input_and_the_version(dataset, tmp_path, monkeypatch):
    scene, folder = dataset
    job = FitJob(str(folder / "t0.exr"), str(scene), FitOptions())
    base = provenance(job)
    assert base is not None and base == provenance(FitJob(str(folder / "t0.exr"), str(scene), FitOptions()))
    other_scene = tmp_path / "other.toml"
    other_scene.write_text(scene.read_text().replace("intensity = 0.5", "intensity = 0.6"))
    variants = {
        "target_sha256": FitJob(str(folder / "t1.exr"), str(scene), FitOptions()),
        "scene_sha256": FitJob(str(folder / "t0.exr"), str(other_scene), FitOptions()),
        "mask_sha256": FitJob(str(folder / "t0.exr"), str(scene), FitOptions(), mask=str(folder / "t1.exr")),
        "settings_sha256": FitJob(str(folder / "t0.exr"), str(scene), FitOptions(loss="huber")),
    }
    for changed, variant in variants.items():
        record = provenance(variant)
        assert record["key"] != base["key"], changed
        assert [k for k in base if base[k] != record[k]] == [changed, "key"], changed
    monkeypatch.setattr("strauss_fit._version.__version__", "99.0")
    assert provenance(job)["key"] != base["key"]
    assert provenance(FitJob(str(tmp_path / "missing.exr"), str(scene), FitOptions())) is None


def test_resume_refuses_results_of_another_configuration(dataset, tmp_path, capsys):
    # before: "0 fitted ... 2 kept from before", exit 0, every JSON still the old fit
    scene, folder = dataset
    out = tmp_path / "out"
    argv = ["fit", str(folder / "t0.exr"), str(folder / "t1.exr"), "--scene", str(scene), "-o", str(out), *FAST]
    assert main(argv) == 0
    before = digests(out)
    other_scene = tmp_path / "other.toml"
    other_scene.write_text(scene.read_text().replace("intensity = 0.5", "intensity = 0.6"))
    for change, named in (
        (["--fix", "metalness=0.5"], "different: the settings"),
        (["--loss", "huber"], "different: the settings"),
        (["--scene", str(other_scene)], "different: the scene"),
    ):
        capsys.readouterr()
        assert main([*argv, "--resume", *change]) == 2
        err = capsys.readouterr().err
        assert "not a result of this run" in err and named in err and "--force" in err, err
        assert digests(out) == before
    # a result without provenance (an older strauss-fit) is not silently kept either
    data = json.loads((out / "t0.json").read_text())
    del data["provenance"]
    (out / "t0.json").write_text(json.dumps(data))
    assert main([*argv, "--resume"]) == 2
    assert "records no provenance" in capsys.readouterr().err


def test_resume_refits_a_result_missing_its_core_keys(dataset, tmp_path, capsys):
    # before: kept, and its summary row said "ok" with an empty verdict, chi2 and RMS
    scene, folder = dataset
    out = tmp_path / "out"
    argv = ["fit", str(folder / "t0.exr"), str(folder / "t1.exr"), "--scene", str(scene), "-o", str(out), *FAST]
    assert main(argv) == 0
    complete = json.loads((out / "t1.json").read_text())
    for edit in (
        lambda d: d.pop("residual"),
        lambda d: d.update(uncertainty={}),  # no ± for the free parameters
        lambda d: d["residual"].update(rms="x"),
    ):
        data = json.loads(json.dumps(complete))
        edit(data)
        (out / "t1.json").write_text(json.dumps(data))
        capsys.readouterr()
        assert main([*argv, "--resume"]) == 0
        captured = capsys.readouterr()
        assert "1 fitted, 0 failed, 1 kept from before" in captured.out
        assert "1 incomplete result(s)" in captured.err
        assert json.loads((out / "t1.json").read_text())["residual"]["rms"] == complete["residual"]["rms"]
        assert all(r["verdict"] and r["rms"] and r["sd_smoothness"] for r in rows(out))
    # --compare on a folder fitted without it: the kept results get their images (fitted again)
    assert main([*argv, "--resume", "--compare"]) == 0
    assert "2 kept result(s) have no comparison image" in capsys.readouterr().err
    assert sorted(p.name for p in out.glob("*.compare.png")) == ["t0.compare.png", "t1.compare.png"]


def test_an_unreachable_scheduler_fails_at_once_and_leaves_no_folder(dataset, tmp_path, capsys):
    # before: 23.5 s of Dask retries, then the error, and an empty output folder
    pytest.importorskip("dask.distributed")
    scene, folder = dataset
    with socket.socket() as probe:  # a port nothing listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    out = tmp_path / "out"
    argv = ["fit", str(folder / "t0.exr"), str(folder / "t1.exr"), "--scene", str(scene), "-o", str(out)]
    assert main([*argv, "--scheduler", f"tcp://127.0.0.1:{port}"]) == 2
    err = capsys.readouterr().err
    assert "cannot reach the Dask scheduler" in err and "refused" in err.lower() and err.count("\n") == 1, err
    assert not out.exists()


def test_a_local_cluster_that_cannot_start_is_one_line_and_no_folder(dataset, tmp_path, capsys, monkeypatch):
    # before: --workers 1000 accepted; under a process limit hundreds of tracebacks, a hang
    distributed = pytest.importorskip("dask.distributed")
    scene, folder = dataset
    out = tmp_path / "out"
    argv = ["fit", str(folder / "t0.exr"), str(folder / "t1.exr"), "--scene", str(scene), "-o", str(out)]
    assert main([*argv, "--workers", "1000"]) == 2
    assert "--workers: expected an integer from 1 to" in capsys.readouterr().err

    def no_threads(*args, **kwargs):
        raise RuntimeError("can't start new thread")

    monkeypatch.setattr(distributed, "LocalCluster", no_threads)
    assert main([*argv, "--workers", "1"]) == 2
    err = capsys.readouterr().err
    assert err.strip() == (
        "strauss-fit: error: cannot start a local Dask cluster of 1 worker(s): can't start new thread "
        "(try fewer --workers)"
    )
    assert not out.exists()


def test_an_equivalence_threshold_asks_for_the_ranges(dataset, capsys):
    # before: --equivalence-de 2 without --equivalence was silently ignored
    from strauss_fit_cli.fit_cmd import fit_options, parse_fixed
    from strauss_fit_cli.main import build_parser

    scene, folder = dataset
    base = ["fit", str(folder / "t0.exr"), "--scene", str(scene), "-o", "r.json"]
    args = build_parser().parse_args([*base, "--equivalence-de", "2"])
    options = fit_options(args, parse_fixed(args.fix))
    assert options.equivalence and options.equivalence_de == 2.0
    args = build_parser().parse_args(base)
    assert not fit_options(args, ()).equivalence and fit_options(args, ()).equivalence_de == 1.0
    code = main([*base, "--no-equivalence", "--equivalence-de", "2"])
    assert code == 2 and "--no-equivalence" in capsys.readouterr().err


def test_outputs_where_no_file_may_go_are_refused_before_any_work(dataset, tmp_path, capsys):
    # before: --force replaced a FIFO or a device at -o by a regular file (as root,
    # "-o /dev/null --force" would replace /dev/null); a folder named like summary.csv failed
    # only after every target was fitted; -o "" fitted into the current folder
    scene, folder = dataset
    target = str(folder / "t0.exr")
    fifo = tmp_path / "out.json"
    os.mkfifo(fifo)
    broken = tmp_path / "broken.json"
    broken.symlink_to(tmp_path / "nowhere.json")
    for output, message in ((fifo, "is a FIFO, not a regular file"), (broken, "is a broken symbolic link")):
        assert main(["fit", target, "--scene", str(scene), "-o", str(output), "--force"]) == 2
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1, err
    assert fifo.is_fifo() and broken.is_symlink()
    assert main(["render", str(scene), "-o", str(fifo), "--force"]) == 2
    assert "is a FIFO, not a regular file" in capsys.readouterr().err
    out = tmp_path / "out"
    (out / "summary.csv").mkdir(parents=True)
    argv = ["fit", target, str(folder / "t1.exr"), "--scene", str(scene), "-o", str(out), "--force", *FAST]
    assert main(argv) == 2
    assert "output path is a directory" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["summary.csv"]  # nothing fitted, nothing written
    assert main(["fit", target, "--scene", str(scene), "-o", ""]) == 2
    assert "-o is empty" in capsys.readouterr().err


def test_a_peer_that_is_not_a_dask_scheduler_is_one_line(tmp_path):
    # before: a port answering another protocol gave a traceback (Dask's decoder asked for
    # exabytes); one that accepted and said nothing hung the command for good
    pytest.importorskip("dask.distributed")
    import threading
    import time

    from strauss_fit.errors import StraussFitError
    from strauss_fit.fitting.executors import connect

    def server(reply: bytes) -> tuple[socket.socket, int]:
        listener = socket.socket()
        listener.bind(("127.0.0.1", 0))
        listener.listen(4)

        def serve():
            try:
                while True:
                    peer, _ = listener.accept()
                    if reply:
                        peer.sendall(reply)
                    threading.Thread(target=lambda p=peer: (time.sleep(30), p.close()), daemon=True).start()
            except OSError:
                return

        threading.Thread(target=serve, daemon=True).start()
        return listener, listener.getsockname()[1]

    talking, talking_port = server(b"HTTP/1.0 400 Bad Request\r\nContent-Type: text/html\r\n\r\n" + b"x" * 200)
    silent, silent_port = server(b"")
    try:
        with pytest.raises(StraussFitError, match="did not answer as a Dask scheduler") as info:
            connect(f"tcp://127.0.0.1:{talking_port}", timeout=20)
        assert "\n" not in str(info.value)
        with pytest.raises(StraussFitError, match="did not answer within 2 s"):
            connect(f"tcp://127.0.0.1:{silent_port}", timeout=2)
    finally:
        talking.close()
        silent.close()
