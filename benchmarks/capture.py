"""Speed and held-out accuracy of a capture's fit, on a capture given by path (the DiLiGenT
``ballPNG`` folder as downloaded, for the figures in docs/benchmarks.md).

    python benchmarks/capture.py PATH/TO/ballPNG [--holdout 2] [--json OUT.json]

Prints and records:

- the whole capture fitted jointly: the wall time cold (a fresh process with the compilation
  cache off) and warm (the second fit in one process), and the peak resident memory of the
  cold process;
- the held-out validation (``--holdout``, default every 2nd image: fit on the odd images,
  predict the even ones): per model (Strauss, Lambert, Phong, Blinn–Phong) the held-out
  relative RMS and mean CIEDE2000, and its wall time: the first call in the process (it
  compiles the half-size problem and the three other models) and the second (warm, to set
  against the warm joint fit: the issue's "at most twice" compares like with like);
- every registered reflectance model fitted jointly to the whole capture, warm (its second
  fit in the process), with its relative RMS: the cost of another model against Strauss's.

The data stays where it is: the real photographs are for research use and never enter the
repository.
"""

from __future__ import annotations

import argparse
import datetime
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import bench_common

COLD = """
import sys, time, resource
t = time.perf_counter()
from strauss_fit.capture._manifest import read_capture
from strauss_fit.fitting.capture_result import fit_capture
fit_capture(read_capture(sys.argv[1]))
print(time.perf_counter() - t, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
"""


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("capture", type=Path, help="a capture folder or manifest (e.g. DiLiGenT ballPNG)")
    parser.add_argument("--holdout", default="2", help="held-out images: every K-th, or a list (default 2)")
    parser.add_argument("--json", type=Path, help="write the figures here")
    args = parser.parse_args(argv)
    machine = bench_common.machine()

    env = dict(os.environ, STRAUSS_FIT_CACHE_DIR="off")
    cold = subprocess.run([sys.executable, "-c", COLD, str(args.capture)], env=env, capture_output=True, text=True)
    if cold.returncode != 0:
        print(cold.stderr.strip().splitlines()[-1] if cold.stderr.strip() else "the cold run failed", file=sys.stderr)
        return 1
    cold_s, cold_rss_kb = (float(v) for v in cold.stdout.split())

    from strauss_fit.capture._manifest import read_capture
    from strauss_fit.fitting.capture_result import fit_capture

    capture = read_capture(args.capture)
    fit_capture(capture)  # compiles
    t = time.perf_counter()
    whole = fit_capture(capture)
    warm_s = time.perf_counter() - t
    t = time.perf_counter()
    fit_capture(capture, holdout=args.holdout)  # compiles the half-size problem and the other models
    holdout_first_s = time.perf_counter() - t
    t = time.perf_counter()
    held = fit_capture(capture, holdout=args.holdout)
    holdout_s = time.perf_counter() - t

    from strauss_fit.capture import load_samples
    from strauss_fit.fitting.capture import MODELS, CaptureFitOptions, fit_capture_samples, relative_rms

    samples = load_samples(capture)
    per_model = {}
    for model in MODELS:
        fit_capture_samples(samples, CaptureFitOptions(model=model))  # compiles
        t = time.perf_counter()
        fitted = fit_capture_samples(samples, CaptureFitOptions(model=model))
        per_model[model] = {
            "warm_s": time.perf_counter() - t,
            "relative_rms": relative_rms(fitted.predicted, samples.values, samples.usable),
        }

    figures = {
        "date": datetime.date.today().isoformat(),
        "machine": machine,
        "capture": str(args.capture),
        "images": whole["images"],
        "pixels": whole["pixels"],
        "values_used": whole["values_used"],
        "joint_fit": {
            "cold_s": cold_s,
            "cold_peak_rss_gb": cold_rss_kb / 1024**2,
            "warm_s": warm_s,
            "warm_process_peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2,
            "relative_rms": whole["residual"]["relative_rms"],
            "verdict": whole["residual"]["verdict"],
            "material": {k: whole[k] for k in ("color", "smoothness", "metalness", "exposure")},
        },
        "models_warm": per_model,
        "holdout": {
            "spec": args.holdout,
            "held_out_images": len(held["holdout"]["held_out"]),
            "wall_s": holdout_s,
            "first_call_s": holdout_first_s,
            "warm_ratio_to_warm_fit": holdout_s / warm_s,
            "models": {
                name: {"relative_rms": entry["relative_rms"], "delta_e2000_mean": entry["delta_e2000_mean"]}
                for name, entry in held["holdout"]["models"].items()
            },
        },
    }
    print(
        f"capture {args.capture}: {whole['images']} images, {whole['pixels']} sphere pixels, "
        f"{whole['values_used']} values"
    )
    jf = figures["joint_fit"]
    print(f"joint fit: cold {jf['cold_s']:.1f} s (peak {jf['cold_peak_rss_gb']:.2f} GB), warm {jf['warm_s']:.1f} s")
    print(
        f"held-out validation (--holdout {args.holdout}, {figures['holdout']['held_out_images']} images): "
        f"warm {holdout_s:.1f} s = {holdout_s / warm_s:.2f}x the warm joint fit (first call {holdout_first_s:.1f} s)"
    )
    print(f"{'model':<14}{'held-out rel. RMS':>18}{'mean CIEDE2000':>16}")
    for name, entry in figures["holdout"]["models"].items():
        print(f"{name:<14}{100 * entry['relative_rms']:>17.1f}%{entry['delta_e2000_mean']:>16.2f}")
    print(f"{'model (whole capture)':<22}{'warm fit':>10}{'x Strauss':>11}{'rel. RMS':>10}")
    for name, entry in per_model.items():
        ratio = entry["warm_s"] / per_model["strauss"]["warm_s"]
        print(f"{name:<22}{entry['warm_s']:>9.1f}s{ratio:>11.2f}{100 * entry['relative_rms']:>9.1f}%")
    if args.json:
        bench_common.write_json(args.json, figures)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
