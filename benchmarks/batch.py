"""Fitting at scale: targets per second of many fits — consistent and mismatched targets,
cold (a first run, nothing compiled) and warm — in one process, on two Dask workers, and
one process per target.

For each image size (default 64² and 256²) it renders random Strauss materials
(C ∈ [0.1, 0.9]³, s ∈ [0.1, 0.9], m ∈ [0, 1]) with Gaussian noise σ = 0.005 and fits C, s
and m (``--free color,smoothness,metalness``, the noise estimated from each image) in
``key_light.toml`` at that size. Two kinds of target (``--kinds``):

- **consistent**: rendered in the scene they are fitted with;
- **mismatched**: rendered with the key light 22° away from where the scene puts it
  (direction (0.1, 0.7, 1) against (0.4, 0.5, 1)): the model cannot reproduce them, the
  verdict is "mismatch" and the default ``--loss auto`` fits them again with the Huber
  loss — twice the solves, and a loss a consistent batch never compiles.

Rows, per size and kind:

- **CLI, cold**: ``strauss-fit fit T1 … TN --scene … -o FOLDER/`` (``--cold-count``
  targets, default 40) in a new process with an empty compilation cache
  (``STRAUSS_FIT_CACHE_DIR``, one per kind): what a user's first batch costs.
- **CLI, cached**: the same command on other targets of the kind, in a new process with
  the cache the cold row filled — and again with ``--other-count`` targets (default 13), a
  batch size the cold run did not have. "programs" counts the XLA programs a row compiled
  (the files it added to the cache): 0 when everything was reused.
- **in-process**: :func:`strauss_fit.fit_many` in this process (its own cache) for 1, 10,
  100 and 1,000 targets (``--counts``), after warm-up calls (whose time is given as
  "compile"): what a batch costs per target once its programs exist.
- **Dask, 2 workers** (``--workers 2``, consistent targets): the in-process call on a
  local cluster of two worker processes, cluster start and the workers' loading of the
  compiled programs from the persistent cache included.
- **one process per target** (consistent targets): ``strauss-fit fit TARGET --scene … -o …``
  run once per target with a warm persistent compilation cache: what a shell loop costs.

A table is printed (targets/s, seconds per target, programs compiled, the ratio to one
process per target), then the ratios the issue asks about (a first CLI batch against a
cached one; mismatched against consistent targets, per target), with the date and the
load averages before and after; ``--json`` (default ``benchmarks/results/batch.json``)
keeps it all.

    .venv/bin/python benchmarks/batch.py [--sizes 64,256] [--kinds consistent,mismatched]
        [--counts 1,10,100,1000] [--cold-count 40] [--other-count 13] [--workers 2]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

import bench_common
import numpy as np

import strauss_fit as sf
from strauss_fit.fitting.batch import FitFailure, fit_many

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "data_synth" / "scenes"
FREE = ("color", "smoothness", "metalness")
#: Where the mismatched targets' key light comes from (the scene's: (0.4, 0.5, 1), 22° away).
MISMATCHED_KEY = (0.1, 0.7, 1.0)
KINDS = ("consistent", "mismatched")


def scene_at(size: int, key: tuple[float, ...] | None = None) -> tuple[sf.Scene, str]:
    """``key_light.toml`` at ``size``² (its key light from ``key`` when given): the scene
    and its text."""
    text = (SCENES / "key_light.toml").read_text()
    text = text.replace("width = 64", f"width = {size}").replace("height = 64", f"height = {size}")
    if key is not None:
        text = text.replace("direction = [0.4, 0.5, 1.0]", f"direction = [{', '.join(map(str, key))}]")
    data = tomllib.loads(text)
    assert data["camera"]["width"] == size and (key is None or tuple(data["light"][0]["direction"]) == key)
    return sf.parse_scene(data, base_dir=SCENES), text


def make_targets(scene: sf.Scene, count: int, seed: int) -> list[sf.Target]:
    rng = np.random.default_rng(seed)
    out = []
    for i in range(count):
        material = sf.Material(
            color=tuple(rng.uniform(0.1, 0.9, 3)),
            smoothness=float(rng.uniform(0.1, 0.9)),
            metalness=float(rng.uniform(0.0, 1.0)),
        )
        image, _ = sf.render(scene, material)
        image = np.asarray(image) + rng.normal(0.0, 0.005, np.shape(image))
        out.append(sf.Target(image, np.ones(image.shape[:2], dtype=bool), f"target{i:04d}.exr", "linear", 0, 0))
    return out


def cached_programs(cache: str | Path) -> int:
    """The XLA programs in a persistent compilation cache folder (one file each)."""
    folder = Path(cache)
    return sum(1 for path in folder.iterdir() if path.name.endswith("-cache")) if folder.is_dir() else 0


def timed_batch(targets, scene, options, cache: str, executor=None) -> dict:
    before = cached_programs(cache)
    started = time.perf_counter()
    results = fit_many(targets, scene, options, executor=executor)
    seconds = time.perf_counter() - started
    fitted = [r for r in results if not isinstance(r, FitFailure)]
    losses = [r.solver["loss"] for r in fitted]
    return _row(len(targets), seconds, len(results) - len(fitted), losses, cached_programs(cache) - before)


def _row(count: int, seconds: float, failed: int, losses: list[str], programs: int) -> dict:
    """One row of the table: ``count`` targets fitted in ``seconds``, the ``losses`` of the
    fits that succeeded, the programs the run added to the cache."""
    return {
        "targets": count,
        "seconds": seconds,
        "per_s": count / seconds,
        "s_per_target": seconds / count,
        "failed": failed,
        "huber": sum(loss == "huber" for loss in losses),
        "programs": programs,
    }


def _strauss_fit() -> str:
    return str(Path(sys.executable).with_name("strauss-fit"))


def _write_targets(targets, folder: Path) -> list[Path]:
    paths = []
    for i, target in enumerate(targets):
        path = folder / f"t{i:04d}.exr"
        sf.write_image(path, target.pixels)
        paths.append(path)
    return paths


def cli_batch(targets, scene_text: str, cache: str) -> dict:
    """``strauss-fit fit`` on every target at once, into a folder, in a new process with the
    compilation cache ``cache``."""
    env = {**os.environ, "STRAUSS_FIT_CACHE_DIR": cache}
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        (folder / "scene.toml").write_text(scene_text)
        paths = _write_targets(targets, folder)
        command = [_strauss_fit(), "fit", *map(str, paths), "--scene", str(folder / "scene.toml")]
        command += ["--free", ",".join(FREE), "--quiet", "--force", "-o", str(folder / "out") + "/"]
        before = cached_programs(cache)
        started = time.perf_counter()
        subprocess.run(command, env=env, check=True, capture_output=True)
        seconds = time.perf_counter() - started
        results = [json.loads(p.read_text()) for p in sorted((folder / "out").glob("t*.json"))]
    losses = [r["solver"]["loss"] for r in results]
    return _row(len(targets), seconds, len(targets) - len(results), losses, cached_programs(cache) - before)


def one_process_per_target(targets, scene_text: str, count: int, cache: str) -> dict:
    """``strauss-fit fit`` once per target (warm cache: one untimed run first)."""
    env = {**os.environ, "STRAUSS_FIT_CACHE_DIR": cache}
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        (folder / "scene.toml").write_text(scene_text)
        paths = _write_targets(targets[: count + 1], folder)
        options = ["--scene", str(folder / "scene.toml"), "--free", ",".join(FREE), "--quiet", "--force"]
        subprocess.run(
            [_strauss_fit(), "fit", str(paths[0]), *options, "-o", str(folder / "warm.json")],
            env=env,
            check=True,
            capture_output=True,
        )
        started = time.perf_counter()
        for i, path in enumerate(paths[1:]):
            subprocess.run(
                [_strauss_fit(), "fit", str(path), *options, "-o", str(folder / f"r{i}.json")],
                env=env,
                check=True,
                capture_output=True,
            )
        seconds = time.perf_counter() - started
    return {"targets": count, "seconds": seconds, "per_s": count / seconds, "s_per_target": seconds / count}


def load() -> str:
    return " ".join(f"{value:.2f}" for value in os.getloadavg())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="64,256")
    parser.add_argument("--kinds", default=",".join(KINDS), help="consistent, mismatched or both")
    parser.add_argument("--counts", default="1,10,100,1000", help="targets of the in-process rows")
    parser.add_argument("--cold-count", type=int, default=40, help="targets of the CLI rows (0: skip them)")
    parser.add_argument("--other-count", type=int, default=13, help="targets of the second cached CLI row (0: skip)")
    parser.add_argument("--workers", type=int, default=2, help="Dask workers (0: skip)")
    parser.add_argument("--dask-count", type=int, default=200, help="targets of the Dask row")
    parser.add_argument("--baseline", type=int, default=3, help="targets fitted one process each (0: skip)")
    parser.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "batch.json")
    args = parser.parse_args()
    sizes = [int(v) for v in args.sizes.split(",")]
    kinds = [k.strip() for k in args.kinds.split(",") if k.strip()]
    if any(kind not in KINDS for kind in kinds):
        parser.error(f"--kinds: each of {', '.join(KINDS)}")
    counts = [int(v) for v in args.counts.split(",") if v.strip()]
    machine = bench_common.machine()
    date, load_before = time.strftime("%Y-%m-%d %H:%M"), load()
    print(f"batch.py, {date}; load average {load_before}", flush=True)
    caches = Path(tempfile.mkdtemp(prefix="strauss-fit-batch-cache-"))
    cache = str(caches / "in-process")
    os.environ["STRAUSS_FIT_CACHE_DIR"] = cache
    from strauss_fit.runtime import enable_compilation_cache

    enable_compilation_cache()
    options = sf.FitOptions(free=FREE)
    rows = []

    def add(row: dict) -> None:
        rows.append(row)
        print(
            f"{row['size']}² {row['kind']:10s} {row['mode']:24s} {row['targets']:5d} targets "
            f"{row['seconds']:7.1f} s {row['per_s']:6.2f}/s"
            + (f", {row['programs']} programs compiled" if "programs" in row else ""),
            flush=True,
        )

    for size in sizes:
        scene, text = scene_at(size)
        seeds = iter(range(size * 100, size * 100 + 100))
        baseline = None
        if args.baseline:
            targets = make_targets(scene, args.baseline + 1, next(seeds))
            baseline = one_process_per_target(targets, text, args.baseline, str(caches / f"{size}-baseline"))
            add({"size": size, "kind": "consistent", "mode": "one process per target", **baseline})
        for kind in kinds:
            render_scene = scene if kind == "consistent" else scene_at(size, MISMATCHED_KEY)[0]
            if args.cold_count:  # each kind starts from an empty cache of its own
                kind_cache = str(caches / f"{size}-{kind}")
                for mode, count in (
                    ("CLI, cold", args.cold_count),
                    ("CLI, cached", args.cold_count),
                    ("CLI, cached, other count", args.other_count),
                ):
                    if count:
                        row = cli_batch(make_targets(render_scene, count, next(seeds)), text, kind_cache)
                        add({"size": size, "kind": kind, "mode": mode, **row})
            targets = make_targets(render_scene, max(counts + [64]), next(seeds))
            started = time.perf_counter()
            fit_many(targets[:1], scene, options)
            compile_s = time.perf_counter() - started
            fit_many(make_targets(render_scene, 64, next(seeds)), scene, options)  # every batch size
            for count in counts:
                row = timed_batch(targets[:count], scene, options, cache)
                add({"size": size, "kind": kind, "mode": "in-process", "compile_s": compile_s, **row})
            if args.workers and kind == "consistent":
                from strauss_fit.fitting.executors import DaskExecutor

                dask_targets = make_targets(render_scene, args.dask_count, next(seeds))
                row = timed_batch(dask_targets, scene, options, cache, DaskExecutor(workers=args.workers))
                add({"size": size, "kind": kind, "mode": f"Dask, {args.workers} workers", **row})
        for row in rows:
            if row["size"] == size and baseline is not None:
                row["ratio"] = row["per_s"] / baseline["per_s"]
    load_after = load()
    print()
    # Timed again at the end: a calibration that moved says the machine's load changed during the run.
    machine_after = bench_common.machine(print_it=False)
    print(f"calibration at the end: {bench_common.describe(machine_after)}")
    print(f"{date}; load average {load_before} before, {load_after} after")
    print()
    print("| size | targets | mode | count | seconds | targets/s | s/target | programs compiled | × one process each |")
    print("|---:|---|---|---:|---:|---:|---:|---:|---:|")
    for row in rows:
        programs = row.get("programs", "")
        ratio = f"{row['ratio']:.0f}" if "ratio" in row else ""
        print(
            f"| {row['size']}² | {row['kind']} | {row['mode']} | {row['targets']} | {row['seconds']:.1f} | "
            f"{row['per_s']:.2f} | {row['s_per_target']:.3f} | {programs} | {ratio} |"
        )
    print()

    def per_target(size: int, kind: str, mode: str) -> float | None:
        """Seconds per target of the largest row of that size, kind and mode."""
        found = [r for r in rows if r["size"] == size and r["kind"] == kind and r["mode"] == mode]
        return max(found, key=lambda r: r["targets"])["s_per_target"] if found else None

    for size in sizes:
        for kind in kinds:
            cold, cached = per_target(size, kind, "CLI, cold"), per_target(size, kind, "CLI, cached")
            if cold and cached:
                print(f"{size}² {kind}: a first CLI batch costs {cold / cached:.2f}x a cached one per target")
        for mode in ("CLI, cold", "CLI, cached", "in-process"):
            consistent, mismatched = per_target(size, "consistent", mode), per_target(size, "mismatched", mode)
            if consistent and mismatched:
                print(f"{size}² {mode}: a mismatched target costs {mismatched / consistent:.2f}x a consistent one")
    payload = {
        "benchmark": "batch",
        "date": date,
        "load_average": {"before": load_before, "after": load_after},
        "machine": machine,
        "calibration_after": machine_after["calibration"],
        "rows": rows,
    }
    bench_common.write_json(args.json, payload)


if __name__ == "__main__":
    main()
