"""Speed of a warm fit of (C, s, m) against scipy.optimize.least_squares on NumPy.

    .venv/bin/python benchmarks/fit_speed.py [--size 256] [--repeats 5] [--json PATH]

Both fit the same 256×256 HDR target (an opaque sphere under one directional light and an
ambient light, 1 % Gaussian noise) for colour, smoothness and metalness from the same
starting point:

- **strauss-fit**: :func:`strauss_fit.fitting.api.fit` with ``free=(color, smoothness, metalness)``
  and the tolerances of ``bench_common.LEGACY_FIT`` — the whole call (geometry precomputed
  once, Levenberg–Marquardt from 1 start and from 4, bound polish, Laplace errors, CIEDE2000,
  the full fitted image) and the
  solver alone (``timing.solve_s``). Warm: a first call compiles (reported separately).
- **SciPy**: ``least_squares(method="trf", bounds=[0, 1])`` with its default 2-point
  finite-difference Jacobian on :func:`numpy_reference.shade_numpy` over the sphere's
  pixels (normals computed once), the way a NumPy user would write it.

The ratio is of medians measured in the same run. Results: a table on stdout and JSON.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import scipy  # noqa: E402
from bench_common import legacy_options, machine, write_json  # noqa: E402
from numpy_reference import shade_numpy, sphere_normals  # noqa: E402
from scipy.optimize import least_squares  # noqa: E402

import strauss_fit as sf  # noqa: E402
from strauss_fit import Target, fit, parse_scene  # noqa: E402

TRUTH = dict(color=(0.7, 0.4, 0.2), smoothness=0.6, metalness=0.3)
START = dict(color=(0.5, 0.5, 0.5), smoothness=0.4, metalness=0.5)
DIRECTION = np.array([0.3, 0.5, 1.0]) / np.linalg.norm([0.3, 0.5, 1.0])


def make_scene(size: int) -> sf.Scene:
    import tomllib

    text = f"""
[camera]
width = {size}
height = {size}
[material]
color = {list(START["color"])}
smoothness = {START["smoothness"]}
metalness = {START["metalness"]}
[[light]]
kind = "directional"
direction = {DIRECTION.tolist()}
intensity = 1.0
[[light]]
kind = "ambient"
intensity = 0.1
"""
    return parse_scene(tomllib.loads(text), source="benchmark")


def scipy_fit(size: int, target: np.ndarray) -> tuple[np.ndarray, int]:
    normals, mask = sphere_normals(size, size)
    observed = target[mask]

    def residual(p):
        radiance = shade_numpy(
            normals, p[:3], p[3], p[4], 0.0, DIRECTION[None, :], np.array([1.0]), np.ones((1, 3)), 0.1
        )
        return (radiance - observed).ravel()

    x0 = np.array([*START["color"], START["smoothness"], START["metalness"]])
    result = least_squares(residual, x0, bounds=(0.0, 1.0), method="trf")
    return result.x, result.nfev


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--json", default=str(Path(__file__).resolve().parent / "results" / "fit_speed.json"))
    args = parser.parse_args()
    info = machine()

    scene = make_scene(args.size)
    clean, _ = sf.render(scene, sf.Material(**TRUTH))
    pixels = np.asarray(clean) + 0.01 * np.random.default_rng(0).normal(size=clean.shape)
    target = Target(pixels, np.ones(pixels.shape[:2], bool), "benchmark", "linear", 0, 0)
    free = ("color", "smoothness", "metalness")
    rows = []

    for starts in (1, 4):
        options = legacy_options(free=free, starts=starts)
        first = time.perf_counter()
        result = fit(scene, target, options)
        compile_s = time.perf_counter() - first
        totals, solves = [], []
        for _ in range(args.repeats):
            started = time.perf_counter()
            result = fit(scene, target, options)
            totals.append(time.perf_counter() - started)
            solves.append(result.compile_and_solve["solve_s"])
        error = max(
            abs(float(result.material.smoothness) - TRUTH["smoothness"]),
            float(np.max(np.abs(np.asarray(result.material.color) - TRUTH["color"]))),
        )
        rows.append(
            dict(
                method=f"strauss-fit fit(), {starts} start(s)",
                total_s=statistics.median(totals),
                solve_s=statistics.median(solves),
                first_call_s=compile_s,
                steps=result.solver["steps"],
                max_param_error=error,
            )
        )

    times = []
    for _ in range(args.repeats):
        started = time.perf_counter()
        x, nfev = scipy_fit(args.size, pixels)
        times.append(time.perf_counter() - started)
    error = max(abs(x[3] - TRUTH["smoothness"]), float(np.max(np.abs(x[:3] - TRUTH["color"]))))
    scipy_row = dict(
        method="scipy least_squares (trf, 2-point FD) on NumPy",
        total_s=statistics.median(times),
        solve_s=statistics.median(times),
        first_call_s=None,
        steps=int(nfev),
        max_param_error=error,
    )
    rows.append(scipy_row)

    print(f"warm fit of (C, s, m) on a {args.size}x{args.size} HDR target, median of {args.repeats}")
    print(
        f"{'method':48s} {'total s':>9s} {'solve s':>9s} {'1st call s':>10s} {'steps/nfev':>10s} "
        f"{'max err':>9s} {'x SciPy':>8s}"
    )
    for row in rows:
        ratio = scipy_row["total_s"] / row["total_s"]
        first_call = f"{row['first_call_s']:.2f}" if row["first_call_s"] is not None else "-"
        print(
            f"{row['method']:48s} {row['total_s']:9.3f} {row['solve_s']:9.3f} {first_call:>10s} "
            f"{row['steps']:10d} {row['max_param_error']:9.1e} {ratio:8.1f}"
        )
        row["speedup_vs_scipy"] = ratio
    info.update(scipy=scipy.__version__, size=args.size, repeats=args.repeats)
    write_json(args.json, dict(machine=info, rows=rows))


if __name__ == "__main__":
    with sf.float64():  # all of it in float64 (importing strauss_fit no longer switches it on)
        main()
