"""Rendering speed of ``strauss_fit.render`` against a plain NumPy float64 reference.

Run from the repository root::

    .venv/bin/python benchmarks/render_speed.py [--size 512] [--repeats 30] [--json PATH]

What it measures (all in one process):

1. A sanity check first: the NumPy reference (:mod:`numpy_reference`) must agree with
   ``strauss_fit.render`` in float64 to 1e-10, else nothing is timed.
2. The local model: a ``size`` x ``size`` orthographic sphere, one directional light, an
   opaque material over a black background (depth 4, the default; the renderer's plan
   reduces it to the local model), in every evaluator mode (exact, table, j-table) and in
   float32 and float64, beside the NumPy float64 reference. Each row gives the median
   wall time of a whole warm ``render(scene, mode=..., dtype=...)`` call (casting,
   dispatch and ``block_until_ready`` included), megapixels per second (of the whole
   image), the ratio to NumPy (> 1: faster than NumPy), the first call's time from empty
   compilation caches (trace + compile + one run) and the largest absolute error against
   exact float64. ``min ms`` is the fastest round: on a machine shared with other
   processes it is the better estimate of the uncontended cost.
3. The global model: the same opaque scene at depth 1 against depth 4 (same cost: the
   opaque path over black is the local model), and a transparent (t = 0.9) material over a
   checkerboard background at depth 4, for reference.
4. The fixed cost of one call: the same scene at 8 x 8 pixels (dispatch, argument
   handling, casting), which bounds the speed-up reachable at any size.
5. A precomputed plan: the opaque material over black and over a checkerboard, rendered
   without a plan (``render`` makes its own), with ``plan_render(scene)`` (made once
   without the material, as a caller rendering many materials would) and with
   ``plan_render(scene, material)``, passed as ``render(..., plan=plan)``. A plan is
   a shortcut, so a row with one must not be slower than the row without.

Timing: every configuration is first called from empty caches (its compile time), then
warmed, then the warm calls are *interleaved*: each of ``--repeats`` rounds calls every
configuration once, and a row reports the median over rounds, so that load from other
processes on a shared machine spreads over all rows rather than spoiling a few.

``--disable-ynn-fusion`` sets ``XLA_FLAGS=--xla_cpu_experimental_ynn_fusion_type=`` before
JAX is imported (a diagnostic: see benchmarks/README.md). Results are printed as a table
and written as JSON (default ``benchmarks/results/render_speed.json``) with the machine.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def _parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=int, default=512, help="image width and height in pixels (default 512)")
    parser.add_argument(
        "--repeats", type=int, default=30, help="timed warm calls per row (median reported; default 30)"
    )
    parser.add_argument(
        "--json",
        type=Path,
        default=HERE / "results" / "render_speed.json",
        help="where to write the results (default benchmarks/results/render_speed.json)",
    )
    parser.add_argument(
        "--disable-ynn-fusion",
        action="store_true",
        help="run with XLA_FLAGS=--xla_cpu_experimental_ynn_fusion_type= (diagnostic)",
    )
    return parser.parse_args(argv)


ARGS = _parse_args() if __name__ == "__main__" else None
if ARGS is not None and ARGS.disable_ynn_fusion:
    # Must happen before JAX initialises its CPU backend.
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_cpu_experimental_ynn_fusion_type=").strip()

import statistics  # noqa: E402
import time  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(HERE))
from bench_common import machine, write_json  # noqa: E402
from numpy_reference import arrays_from_scene, check_against_strauss_fit, render_numpy  # noqa: E402

import strauss_fit  # noqa: E402
from strauss_fit import Background, Camera, DirectionalLights, Lights, Material, Scene, plan_render, render  # noqa: E402
from strauss_fit.models.strauss import DEFAULT_TABLE_SIZE, MODES  # noqa: E402

DTYPES = (jnp.float32, jnp.float64)
LIGHT_DIRECTION = np.array([0.3, 0.5, 1.0]) / np.linalg.norm([0.3, 0.5, 1.0])
OPAQUE = dict(color=(0.8, 0.3, 0.2), smoothness=0.6, metalness=0.3, transparency=0.0, ior=1.5)
TRANSPARENT = dict(color=(0.8, 0.3, 0.2), smoothness=0.6, metalness=0.3, transparency=0.9, ior=1.5)


def make_scene(size: int, depth: int = 4, background: Background | None = None, material: dict = OPAQUE) -> Scene:
    """The benchmark scene: orthographic sphere, one white directional light."""
    lights = Lights(
        directional=DirectionalLights(
            direction=jnp.asarray(LIGHT_DIRECTION[None, :]),
            intensity=jnp.asarray([1.0]),
            color=jnp.ones((1, 3)),
        )
    )
    return Scene(
        camera=Camera("orthographic", size, size),
        lights=lights,
        background=background or Background(),
        material=Material(**material),
        depth=depth,
    )


def checkerboard() -> Background:
    return Background("checkerboard", jnp.zeros(3))


def first_call(call) -> float:
    """Seconds of a call made with JAX's compilation caches emptied: trace + compile + run."""
    jax.clear_caches()
    start = time.perf_counter()
    call()
    return time.perf_counter() - start


def time_interleaved(calls: dict, repeats: int) -> dict:
    """Median over ``repeats`` rounds; each round makes one warm call of every entry, so a
    slow spell of a shared machine hits all rows alike. Returns seconds per entry."""
    for call in calls.values():  # warm: compile (if not yet) and one untimed run
        call()
        call()
    times = {name: [] for name in calls}
    for _ in range(repeats):
        for name, call in calls.items():
            start = time.perf_counter()
            call()
            times[name].append(time.perf_counter() - start)
    return {
        name: {"median_s": statistics.median(t), "min_s": min(t), "max_s": max(t), "repeats": repeats}
        for name, t in times.items()
    }


def jax_call(scene: Scene, mode: str, dtype, plan=None):
    def call():
        image, mask = render(scene, mode=mode, dtype=dtype, plan=plan)
        return jax.block_until_ready((image, mask))

    return call


def machine_info() -> dict:
    """:func:`bench_common.machine` (printed) with what this benchmark adds: the library
    versions, the device and ``XLA_FLAGS`` (which ``--disable-ynn-fusion`` changes)."""
    device = jax.devices()[0]
    return {
        **machine(),
        "numpy": np.__version__,
        "jaxlib": getattr(__import__("jaxlib"), "__version__", None),
        "jax_device": str(device),
        "jax_device_kind": getattr(device, "device_kind", None),
        "XLA_FLAGS": os.environ.get("XLA_FLAGS", ""),
        "strauss_fit": strauss_fit.__version__,
        "load_average_before": os.getloadavg(),
    }


def row(
    label: str, mode: str, dtype: str, timing: dict, pixels: int, numpy_s: float | None, error: float | None, scene: str
) -> dict:
    first = timing.get("first_s")
    return {
        "scene": scene,
        "label": label,
        "mode": mode,
        "dtype": dtype,
        "ms_per_frame": timing["median_s"] * 1e3,
        "min_ms": timing["min_s"] * 1e3,
        "megapixels_per_s": pixels / timing["median_s"] / 1e6,
        "ratio_to_numpy": None if numpy_s is None else numpy_s / timing["median_s"],
        "first_call_ms": None if first is None else first * 1e3,
        "max_abs_error_vs_exact_float64": error,
        "repeats": timing["repeats"],
    }


def print_table(title: str, rows: list[dict]) -> None:
    print(f"\n{title}")
    header = (
        f"{'case':<38} {'mode':<8} {'dtype':<8} {'ms/frame':>9} {'MP/s':>8} {'x NumPy':>8} "
        f"{'min ms':>8} {'1st call ms':>11} {'max |err|':>10}"
    )
    print(header)
    print("-" * len(header))
    for r in rows:
        ratio = "" if r["ratio_to_numpy"] is None else f"{r['ratio_to_numpy']:.2f}"
        error = "" if r["max_abs_error_vs_exact_float64"] is None else f"{r['max_abs_error_vs_exact_float64']:.1e}"
        first = "" if r["first_call_ms"] is None else f"{r['first_call_ms']:.0f}"
        print(
            f"{r['label']:<38} {r['mode']:<8} {r['dtype']:<8} {r['ms_per_frame']:>9.2f} "
            f"{r['megapixels_per_s']:>8.2f} {ratio:>8} {r['min_ms']:>8.2f} {first:>11} {error:>10}"
        )


def main(args: argparse.Namespace) -> dict:
    size, repeats = args.size, args.repeats
    info = machine_info()
    print(f"strauss_fit.render vs NumPy float64, {size}x{size}, median of {repeats} interleaved warm calls")
    if info["XLA_FLAGS"]:
        print(f"XLA_FLAGS={info['XLA_FLAGS']}")

    local = make_scene(size, depth=4)
    local_depth1 = make_scene(size, depth=1)
    glass = make_scene(size, depth=4, background=checkerboard(), material=TRANSPARENT)
    tiny = make_scene(8, depth=4)

    # 1. the reference must agree with the library before anything is timed
    agreement = max(
        check_against_strauss_fit(scene, tol=1e-10)
        for scene in (make_scene(97, depth=1), make_scene(64, depth=4), local)
    )
    print(
        f"self-check: NumPy reference vs strauss_fit.render (float64, exact): max |diff| = {agreement:.2e} (<= 1e-10)"
    )

    # every configuration: (section, label, mode, dtype name, scene, call)
    numpy_args = arrays_from_scene(local)
    configs = [("local", "NumPy reference", "exact", "float64", local, lambda: render_numpy(**numpy_args))]
    for mode in MODES:
        for dtype in DTYPES:
            configs.append(
                (
                    "local",
                    "local model (opaque/black)",
                    mode,
                    jnp.dtype(dtype).name,
                    local,
                    jax_call(local, mode, dtype),
                )
            )
    for label, scene in (
        ("opaque/black depth 1", local_depth1),
        ("opaque/black depth 4", local),
        ("t=0.9/checker depth 4", glass),
    ):
        for dtype in DTYPES:
            configs.append(("global", label, "exact", jnp.dtype(dtype).name, scene, jax_call(scene, "exact", dtype)))
    for dtype in DTYPES:
        configs.append(
            (
                "overhead",
                "8x8 (fixed cost per call)",
                "exact",
                jnp.dtype(dtype).name,
                tiny,
                jax_call(tiny, "exact", dtype),
            )
        )

    opaque_checker = make_scene(size, depth=4, background=checkerboard())
    for background, scene in (("black", local), ("checkerboard", opaque_checker)):
        for plan_label, plan in (
            ("no plan", None),
            ("plan_render(scene)", plan_render(scene)),
            ("plan_render(scene, mat.)", plan_render(scene, scene.material)),
        ):
            for dtype in DTYPES:
                call = jax_call(scene, "exact", dtype, plan)
                configs.append(("plan", f"{background}, {plan_label}", "exact", jnp.dtype(dtype).name, scene, call))

    # first calls, each from empty caches (the depth-4 opaque rows share one compilation
    # with the local rows, so they are compiled once here too)
    firsts = {i: (None if c[1] == "NumPy reference" else first_call(c[5])) for i, c in enumerate(configs)}
    timings = time_interleaved({i: c[5] for i, c in enumerate(configs)}, repeats)
    numpy_s = timings[0]["median_s"]

    # accuracy: against exact float64 of the same scene
    references = {}
    rows = {"local": [], "global": [], "overhead": [], "plan": []}
    for i, (section, label, mode, dtype_name, scene, call) in enumerate(configs):
        key = id(scene)
        if key not in references:
            references[key] = np.asarray(render(scene, mode="exact", dtype=jnp.float64)[0])
        if label == "NumPy reference":
            image = render_numpy(**numpy_args)[0]
        else:  # the timed call's own image (a plan row's: rendered with its plan)
            image = np.asarray(call()[0], dtype=np.float64)
        error = None if section == "overhead" else float(np.max(np.abs(image - references[key])))
        timing = dict(timings[i], first_s=firsts[i])
        n = scene.camera.width * scene.camera.height
        rows[section].append(
            row(label, mode, dtype_name, timing, n, None if section == "overhead" else numpy_s, error, section)
        )

    print_table(
        f"Local model: {size}x{size}, one directional light, opaque over black (depth 4 -> local plan); "
        f"table size {DEFAULT_TABLE_SIZE}; error against exact float64",
        rows["local"],
    )
    print_table(
        "Global model (exact; error against the same scene in float64; ratio against the NumPy local frame)",
        rows["global"],
    )
    print_table("Fixed cost of one render() call", rows["overhead"])
    print_table(
        "A precomputed plan (render(..., plan=plan)): opaque material, depth 4; ratio against the NumPy local frame",
        rows["plan"],
    )

    exact32 = next(
        r for r in rows["local"] if r["mode"] == "exact" and r["dtype"] == "float32" and r["label"] != "NumPy reference"
    )
    numpy_min = rows["local"][0]["min_ms"]
    exact32["ratio_to_numpy_of_min_times"] = numpy_min / exact32["min_ms"]
    print(
        f"\nexact float32 / NumPy float64: {exact32['ratio_to_numpy']:.1f}x by medians, "
        f"{exact32['ratio_to_numpy_of_min_times']:.1f}x by minima (target: >= 50x)"
    )
    info["load_average_after"] = os.getloadavg()

    result = {
        "benchmark": "render_speed",
        "size": size,
        "repeats": repeats,
        "timestamp": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "machine": info,
        "self_check_max_abs_diff": agreement,
        "numpy_ms_per_frame": numpy_s * 1e3,
        "exact_float32_ratio_to_numpy": exact32["ratio_to_numpy"],
        "exact_float32_ratio_to_numpy_of_min_times": exact32["ratio_to_numpy_of_min_times"],
        "local": rows["local"],
        "global": rows["global"],
        "overhead": rows["overhead"],
        "plan": rows["plan"],
    }
    write_json(args.json, result)
    return result


if __name__ == "__main__":
    with strauss_fit.float64():  # all of it in float64 (importing strauss_fit no longer switches it on)
        main(ARGS)
