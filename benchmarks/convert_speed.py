"""Conversion speed: materials per second of ``phong2strauss`` and ``strauss2phong``.

    .venv/bin/python benchmarks/convert_speed.py [--sizes 100 1000] [--quality balanced]
                                                 [--directions phong2strauss strauss2phong]
                                                 [--json PATH]

What is timed: :func:`strauss_fit.convert.converter.convert_files`, the whole command's
work without the process start — reading a JSON file of generated materials, converting
them on the default conversion scene (64 × 64, three lights) with the ``--quality``
preset's settings, the progress file, writing the JSON output.

Each (direction, size) runs in a fresh Python process (no compilation cache: the library
keeps none of its own): the first call is **cold** (it traces and compiles every program
it needs), the second, on the same materials into another output, is **warm**. The
materials are generated from a fixed seed (:func:`phong_materials`,
:func:`strauss_materials`): Phong sources with and without a highlight (a fifth with
Ks = 0, a matte wall), white or tinted highlights, exponents from 1 to 1000; Strauss
sources over the whole unit cube of (s, m), a tenth at m = 0 and a tenth at m = 1.

Besides the speed, the results are summarised (mean and 95th percentile of the CIEDE2000
residual, the mean linear RMS, how many materials hold metalness, how many failed), so
that a faster conversion can be checked to convert as well.

Results: a table on stdout and JSON (default ``benchmarks/results/convert_speed.json``).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DIRECTIONS = ("phong2strauss", "strauss2phong")


def phong_materials(count: int, seed: int = 0) -> list[dict]:
    """``count`` Phong materials as JSON objects (see the module docstring)."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(count):
        kd = float(rng.uniform(0.05, 1.0))
        diffuse = rng.uniform(0.05, 1.0, 3)
        kind = rng.uniform()
        if kind < 0.2:  # a matte surface: no highlight at all
            ks, specular = 0.0, np.ones(3)
        elif kind < 0.4:  # a tinted highlight (a metal's or a lacquer's)
            ks, specular = float(rng.uniform(0.3, 1.0)), rng.uniform(0.2, 1.0, 3)
            specular = specular / specular.max()
        else:  # a white highlight (a plastic's)
            ks, specular = float(rng.uniform(0.05, 0.9)), np.ones(3)
        exponent = float(np.exp(rng.uniform(0.0, np.log(1000.0))))
        out.append(
            {
                "name": f"phong-{k:05d}",
                "ka": 0.0,
                "kd": round(kd, 4),
                "ks": round(ks, 4),
                "exponent": round(exponent, 3),
                "diffuse_color": [round(float(c), 4) for c in diffuse],
                "specular_color": [round(float(c), 4) for c in specular],
            }
        )
    return out


def strauss_materials(count: int, seed: int = 1) -> list[dict]:
    """``count`` opaque Strauss materials as JSON objects (see the module docstring)."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(count):
        kind = rng.uniform()
        metalness = 0.0 if kind < 0.1 else 1.0 if kind < 0.2 else float(rng.uniform())
        out.append(
            {
                "name": f"strauss-{k:05d}",
                "color": [round(float(c), 4) for c in rng.uniform(0.02, 1.0, 3)],
                "smoothness": round(float(rng.uniform(0.0, 0.98)), 4),
                "metalness": round(metalness, 4),
                "transparency": 0.0,
                "ior": 1.5,
            }
        )
    return out


def quality_summary(document: dict) -> dict:
    """Mean and 95th percentile of ΔE2000, mean RMS, held metalness and failures."""
    ok = [m for m in document["materials"] if m["status"] == "ok"]
    delta_e = np.array([m["residual"]["delta_e2000_mean"] for m in ok]) if ok else np.zeros(1)
    rms = np.array([m["residual"]["rms"] for m in ok]) if ok else np.zeros(1)
    held = sum(1 for m in ok if "metalness" in (m.get("held") or {}))
    return {
        "converted": len(ok),
        "errors": len(document["materials"]) - len(ok),
        "delta_e2000_mean": float(delta_e.mean()),
        "delta_e2000_p95": float(np.percentile(delta_e, 95)),
        "delta_e2000_max": float(delta_e.max()),
        "rms_mean": float(rms.mean()),
        "metalness_held": held,
    }


def worker(direction: str, size: int, quality: str) -> dict:
    """One (direction, size) in this process: a cold call, then a warm one."""
    from strauss_fit.convert.converter import Settings, convert_files

    materials = phong_materials(size) if direction == "phong2strauss" else strauss_materials(size)
    settings = Settings.preset(quality)
    out: dict = {"direction": direction, "materials": size, "quality": quality, "settings": settings.as_dict()}
    with tempfile.TemporaryDirectory() as tmp:
        source = Path(tmp) / "materials.json"
        source.write_text(json.dumps(materials))
        for run in ("cold", "warm"):
            started = time.perf_counter()
            document = convert_files(direction, [str(source)], Path(tmp) / f"{run}.json", settings=settings)
            seconds = time.perf_counter() - started
            out[run] = {
                "seconds": seconds,
                "materials_per_s": size / seconds,
                **quality_summary(document),
            }
    return out


def commit() -> str | None:
    try:
        return subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True, check=True
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=[100, 1000])
    parser.add_argument("--directions", nargs="+", choices=DIRECTIONS, default=list(DIRECTIONS))
    parser.add_argument("--quality", default="balanced", choices=("fast", "balanced", "accurate"))
    parser.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "convert_speed.json")
    parser.add_argument("--worker", nargs=2, metavar=("DIRECTION", "SIZE"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        print(json.dumps(worker(args.worker[0], int(args.worker[1]), args.quality)))
        return
    import bench_common  # in the parent only: the workers' processes stay as lean as the command's

    machine = bench_common.machine()
    rows = []
    for direction in args.directions:
        for size in args.sizes:
            done = subprocess.run(
                [sys.executable, __file__, "--worker", direction, str(size), "--quality", args.quality],
                capture_output=True,
                text=True,
                check=False,
            )
            if done.returncode != 0:
                sys.exit(f"{direction} × {size} failed:\n{done.stderr[-3000:]}")
            row = json.loads(done.stdout.strip().splitlines()[-1])
            rows.append(row)
            cold, warm = row["cold"], row["warm"]
            print(
                f"{direction:14s} {size:6d}  cold {cold['seconds']:8.1f} s {cold['materials_per_s']:7.1f}/s"
                f"   warm {warm['seconds']:8.1f} s {warm['materials_per_s']:7.1f}/s"
                f"   ΔE mean {row['warm']['delta_e2000_mean']:.3f} p95 {row['warm']['delta_e2000_p95']:.3f}"
                f"   m held {row['warm']['metalness_held']}  errors {row['warm']['errors']}",
                flush=True,
            )
    print()
    print(
        "| direction | materials | cold s | cold materials/s | warm s | warm materials/s | ΔE2000 mean | ΔE2000 p95 |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for row in rows:
        print(
            f"| {row['direction']} | {row['materials']} | {row['cold']['seconds']:.1f} | "
            f"{row['cold']['materials_per_s']:.1f} | {row['warm']['seconds']:.1f} | "
            f"{row['warm']['materials_per_s']:.1f} | "
            f"{row['warm']['delta_e2000_mean']:.3f} | {row['warm']['delta_e2000_p95']:.3f} |"
        )
    result = {
        "date": time.strftime("%Y-%m-%d"),
        "commit": commit(),
        "quality": args.quality,
        "machine": machine,
        "runs": rows,
    }
    print()
    bench_common.write_json(args.json, result)


if __name__ == "__main__":
    main()
