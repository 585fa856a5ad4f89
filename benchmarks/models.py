"""Every registered reflectance model against Strauss: a render and a single-target fit.

Run from the repository root::

    .venv/bin/python benchmarks/models.py [--size 256] [--repeats 9] [--json PATH]

What it measures (all in one process, on the ``key_and_fill`` scene: two directional
lights and an ambient light, orthographic, ``size`` × ``size`` pixels):

1. **Render.** A warm whole call per model: Strauss's own renderer
   (:func:`strauss_fit.render`, the exact evaluator in float64, its plan reducing the
   opaque scene to the local model) and every model through
   :func:`strauss_fit.rendering.reflectance.render_model` (``strauss`` among them, the same
   local reflection through the registry), ``block_until_ready`` included.
2. **Fit of one target.** One Strauss-rendered plastic target (C = (0.7, 0.35, 0.2),
   s = 0.6, m = 0.1, Gaussian noise of 0.005), fitted as ``strauss-fit fit TARGET
   --scene S --model NAME`` fits it: the scene's pixels
   (:func:`strauss_fit.fitting.scene_samples.samples_from_scene`) and the capture fitter
   (:func:`strauss_fit.fitting.capture.fit_capture_samples`), exposure fixed. Every model,
   Strauss included, so the ratios compare like with like; the Strauss engine's own fit
   (:func:`strauss_fit.fit`, ``balanced`` preset) is given beside it for reference.

Timing: every configuration is called once (compiling), then the warm calls are
interleaved: each of ``--repeats`` rounds calls every configuration once, and a row
reports the median over rounds (and the fastest), so that load from other processes
spreads over all rows. Ratios are to the ``strauss`` row of the same table and the same
run. The table is printed and written as JSON (default ``benchmarks/results/models.json``)
with the date and the machine.
"""

from __future__ import annotations

import argparse
import datetime
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))


def _parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=int, default=256, help="image width and height in pixels (default 256)")
    parser.add_argument("--repeats", type=int, default=9, help="interleaved warm rounds (default 9)")
    parser.add_argument(
        "--json", type=Path, default=HERE / "results" / "models.json", help="where to write the figures"
    )
    return parser.parse_args(argv)


def _interleaved(calls: dict[str, Callable[[], object]], repeats: int) -> dict[str, dict[str, float]]:
    """Compile each call, then time ``repeats`` interleaved rounds: median and fastest, seconds."""
    first = {}
    for name, call in calls.items():
        t = time.perf_counter()
        call()
        first[name] = time.perf_counter() - t
    times: dict[str, list[float]] = {name: [] for name in calls}
    for _ in range(repeats):
        for name, call in calls.items():
            t = time.perf_counter()
            call()
            times[name].append(time.perf_counter() - t)
    return {
        name: {"first_s": first[name], "median_s": statistics.median(ts), "min_s": min(ts)}
        for name, ts in times.items()
    }


def main(argv: list[str] | None = None) -> int:
    args = _parse_args(argv)
    import importlib

    import jax
    import numpy as np
    from bench_common import key_and_fill_scene, machine, write_json

    import strauss_fit as sf
    from strauss_fit.io.images import write_image
    from strauss_fit.io.targets import load_target
    from strauss_fit.models.reflectance import REFLECTANCE_MODELS
    from strauss_fit.rendering.reflectance import render_model

    info = machine()
    capture = importlib.import_module("strauss_fit.fitting.capture")
    scene_samples = importlib.import_module("strauss_fit.fitting.scene_samples")

    truth = {"color": [0.7, 0.35, 0.2], "smoothness": 0.6, "metalness": 0.1}
    scene = key_and_fill_scene(args.size, material={**truth, "transparency": 0.0, "ior": 1.5})

    def block(result):
        return jax.block_until_ready(result)

    renders = {"strauss (renderer)": lambda: block(sf.render(scene))}
    for name in REFLECTANCE_MODELS:
        renders[name] = lambda name=name: block(render_model(scene, name))
    render_rows = _interleaved(renders, args.repeats)

    image, _ = sf.render(scene)
    noisy = np.asarray(image) + np.random.default_rng(0).normal(0.0, 0.005, np.shape(image))
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "plastic.exr"
        write_image(path, np.clip(noisy, 0.0, None).astype(np.float32))
        target = load_target(path)
        samples = scene_samples.samples_from_scene(scene, target)
        fits = {"strauss (engine)": lambda: sf.fit(scene, target)}
        relative = {}
        for name in REFLECTANCE_MODELS:

            def fit_model(name=name):
                fitted = capture.fit_capture_samples(samples, capture.CaptureFitOptions(model=name, exposure="fixed"))
                relative[name] = capture.relative_rms(fitted.predicted, samples.values, samples.usable)

            fits[name] = fit_model
        fit_rows = _interleaved(fits, args.repeats)

    figures = {
        "date": datetime.date.today().isoformat(),
        "machine": info,
        "size": args.size,
        "repeats": args.repeats,
        "render": render_rows,
        "fit": {name: {**row, "relative_rms": relative.get(name)} for name, row in fit_rows.items()},
    }
    print(f"models on key_and_fill, {args.size}x{args.size}, {args.repeats} interleaved rounds ({figures['date']})")
    for title, rows in (("render", render_rows), ("fit one target", figures["fit"])):
        base = rows["strauss"]["median_s"]
        print(f"\n{title:<22}{'median ms':>11}{'min ms':>9}{'first s':>9}{'x strauss':>11}")
        for name, row in rows.items():
            print(
                f"{name:<22}{row['median_s'] * 1e3:>11.1f}{row['min_s'] * 1e3:>9.1f}"
                f"{row['first_s']:>9.2f}{row['median_s'] / base:>11.2f}"
            )
    print()
    write_json(args.json, figures)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
