"""Fitting at scale: targets per second, in one process, on two Dask workers, and one
process per target.

For each image size (default 64² and 256²) it renders random Strauss materials
(C ∈ [0.1, 0.9]³, s ∈ [0.1, 0.9], m ∈ [0, 1]) in ``key_light.toml`` at that size with
Gaussian noise σ = 0.005, and fits C, s and m (``--free color,smoothness,metalness``, the
noise estimated from each image) by:

- **in-process** :func:`strauss_fit.fit_many`, batched, for 1, 10, 100 and 1,000 targets.
  The first call in the process compiles (its time is given apart as "compile"); the rows
  are then warm: what a batch of a thousand targets costs per target once its programs
  exist.
- **Dask, 2 workers** (``--workers 2``): the same call on a local cluster of two worker
  processes, cluster start and the workers' own compilation (from the persistent cache)
  included.
- **one process per target**: ``strauss-fit fit TARGET --scene … -o …`` run once per
  target with a warm persistent compilation cache: what a shell loop costs.

A table is printed (targets/s, and the ratio to one process per target measured in the same
run) and ``--json`` (default ``benchmarks/results/batch.json``) keeps it all.

    .venv/bin/python benchmarks/batch.py [--sizes 64,256] [--counts 1,10,100,1000] [--workers 2]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

import numpy as np

import strauss_fit as sf
from strauss_fit.fit.batch import FitFailure, fit_many

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "data_synth" / "scenes"
FREE = ("color", "smoothness", "metalness")


def scene_at(size: int) -> tuple[sf.Scene, str]:
    data = tomllib.loads((SCENES / "key_light.toml").read_text())
    data["camera"].update(width=size, height=size)
    text = (SCENES / "key_light.toml").read_text()
    text = text.replace("width = 64", f"width = {size}").replace("height = 64", f"height = {size}")
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


def timed_batch(targets, scene, options, executor=None) -> dict:
    started = time.perf_counter()
    results = fit_many(targets, scene, options, executor=executor)
    seconds = time.perf_counter() - started
    failed = sum(isinstance(r, FitFailure) for r in results)
    return {"targets": len(targets), "seconds": seconds, "per_s": len(targets) / seconds, "failed": failed}


def one_process_per_target(targets, scene_text: str, count: int, cache: str) -> dict:
    """``strauss-fit fit`` once per target (warm cache: one untimed run first)."""
    command = str(Path(sys.executable).with_name("strauss-fit"))
    env = {**os.environ, "STRAUSS_FIT_CACHE_DIR": cache}
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        (folder / "scene.toml").write_text(scene_text)
        paths = []
        for i, target in enumerate(targets[: count + 1]):
            path = folder / f"t{i}.exr"
            sf.write_image(path, target.pixels)
            paths.append(path)
        options = ["--scene", str(folder / "scene.toml"), "--free", ",".join(FREE), "--quiet", "--force"]
        subprocess.run(
            [command, "fit", str(paths[0]), *options, "-o", str(folder / "warm.json")],
            env=env,
            check=True,
            capture_output=True,
        )
        started = time.perf_counter()
        for i, path in enumerate(paths[1:]):
            subprocess.run(
                [command, "fit", str(path), *options, "-o", str(folder / f"r{i}.json")],
                env=env,
                check=True,
                capture_output=True,
            )
        seconds = time.perf_counter() - started
    return {"targets": count, "seconds": seconds, "per_s": count / seconds}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="64,256")
    parser.add_argument("--counts", default="1,10,100,1000")
    parser.add_argument("--workers", type=int, default=2, help="Dask workers (0: skip)")
    parser.add_argument("--dask-count", type=int, default=200, help="targets of the Dask row")
    parser.add_argument("--baseline", type=int, default=3, help="targets fitted one process each")
    parser.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "batch.json")
    args = parser.parse_args()
    sizes = [int(v) for v in args.sizes.split(",")]
    counts = [int(v) for v in args.counts.split(",")]
    cache = tempfile.mkdtemp(prefix="strauss-fit-batch-cache-")
    os.environ["STRAUSS_FIT_CACHE_DIR"] = cache
    from strauss_fit.runtime import enable_compilation_cache

    enable_compilation_cache()
    options = sf.FitOptions(free=FREE)
    rows = []
    for size in sizes:
        scene, text = scene_at(size)
        targets = make_targets(scene, max(counts + [args.dask_count, args.baseline + 1]), seed=size)
        started = time.perf_counter()
        fit_many(targets[:1], scene, options)
        compile_s = time.perf_counter() - started
        fit_many(targets[:64], scene, options)  # compile the batch sizes too
        baseline = one_process_per_target(targets, text, args.baseline, cache)
        print(
            f"{size}²: compile {compile_s:.1f} s; one process per target {baseline['per_s']:.2f} targets/s", flush=True
        )
        rows.append({"size": size, "mode": "one process per target", **baseline, "ratio": 1.0})
        for count in counts:
            row = timed_batch(targets[:count], scene, options)
            row.update(size=size, mode="in-process", ratio=row["per_s"] / baseline["per_s"], compile_s=compile_s)
            rows.append(row)
            print(f"{size}²: in-process {count:5d} targets {row['per_s']:7.1f}/s ({row['ratio']:.0f}x)", flush=True)
        if args.workers:
            from strauss_fit.fit.executors import DaskExecutor

            row = timed_batch(targets[: args.dask_count], scene, options, DaskExecutor(workers=args.workers))
            row.update(size=size, mode=f"Dask, {args.workers} workers", ratio=row["per_s"] / baseline["per_s"])
            rows.append(row)
            print(f"{size}²: Dask {args.workers} workers {row['targets']} targets {row['per_s']:.1f}/s", flush=True)
    print()
    print("| size | mode | targets | seconds | targets/s | × one process per target |")
    print("|---:|---|---:|---:|---:|---:|")
    for row in rows:
        print(
            f"| {row['size']}² | {row['mode']} | {row['targets']} | {row['seconds']:.1f} | {row['per_s']:.1f} | "
            f"{row['ratio']:.0f} |"
        )
    args.json.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "benchmark": "batch",
        "date": time.strftime("%Y-%m-%d"),
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(), "python": platform.python_version()},
        "rows": rows,
    }
    args.json.write_text(json.dumps(payload, indent=1))
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
