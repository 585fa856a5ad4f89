"""Speed against accuracy: what each knob of strauss-fit costs and what it buys.

Run from the repository root::

    .venv/bin/python benchmarks/tradeoff.py [--quick] [--out benchmarks/results/tradeoff]

Knobs measured (all in one process, on this machine):

1. **Evaluator**: mode (exact / table / j-table) x table size x precision (float32 /
   float64). Cost: wall time of a warm ``strauss_fit.render`` call of a 256x256 sphere
   (median and fastest of interleaved rounds, ``block_until_ready`` included) and memory
   (see *Memory* below). Accuracy: |image - exact float64 image| over the sphere's pixels
   (max and mean), for the timed material and, as the worst case, over a set of materials
   that light the grazing region where the tables err most. The plain NumPy float64
   reference (``numpy_reference.py``) is the baseline point.
2. **Image resolution** (fits): fits of ground truth - known materials rendered with
   Gaussian noise of 1 % of the image's 98th percentile, several materials including the
   extremes s, m in {0, 1} - at each resolution. Cost: warm wall time of
   ``strauss_fit.fitting.api.fit`` (the first call, which compiles, is reported apart) and memory.
   Accuracy: the largest error over the parameters the image constrains (below).
3. **Solver tolerance** (rtol, atol) and **number of starts**, at one resolution: fit time
   against parameter error and the fraction of fits landing within 0.02 of the truth.
4. **Sampler length**: emcee chains (``strauss_fit.inference.sampler.run_sampler`` on
   ``strauss_fit.inference.posterior.LogPosterior``) over repeated noise draws of one small
   problem; for each chain length, the width of the 68 % and 95 % central credible
   intervals and their coverage of the truth, beside the Laplace intervals of the fits
   (``FitResult.uncertainty``). A walkers sweep is added without ``--quick``.

Which parameters are scored. All fits free (colour, smoothness, metalness), one layout,
so that the solver compiles once per setting. A parameter counts towards the error only
where the image constrains it: its predicted standard deviation at the noise level, with
all three free, is at most 0.05 (the threshold of the library's identifiability rule),
from the Jacobian at the *true* material at the reference resolution, exactly degenerate
directions counting as unconstrained (see :func:`constrained_parameters`). At s = 0 the
metalness only tints the weak off-specular term: fitted values there are arbitrary and
scoring them would measure the noise, not the knob. A mirror (s = 1) over this uniform
backdrop shows only its tint m (C - 1): every (m, C) with the same tint renders the same
image, including, for a plastic mirror (m = 0), the branch C = 1 with any m, which an
analysis at the truth does not see (there C is invisible and m looks constrained). For
mirrors the tint is scored in place of C and m, as the fit's own mirror rule and
``benchmarks/recovery.py`` do.

Memory. NumPy: ``tracemalloc`` peak of one reference render. JAX on the CPU backend has no
``jax.devices()[0].memory_stats()`` (it returns None; where it exists, e.g. on a GPU, its
``peak_bytes_in_use`` is recorded too), so the JAX cost is XLA's own buffer assignment of
the compiled program (``compiled.memory_analysis()``: temporary + output bytes, i.e. the
working memory of one call; arguments are the caller's) plus, for the table modes, the
size of the table constants. The process's peak RSS (``resource.getrusage``) is recorded
per knob for completeness; it only ever grows, so it bounds, not measures.

Outputs (in ``--out``): ``tradeoff.json`` (every row, the machine), one Pareto plot per
knob (``pareto_*.png``: cost on x, error on y, log scales, points labelled, the Pareto
front drawn), ``tradeoff.md`` (the Markdown tables, the verdict on the table modes and the
recommended presets, also printed).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import statistics
import sys
import time
import tomllib
import tracemalloc
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from bench_common import key_and_fill_scene, legacy_options, machine, write_json  # noqa: E402
from numpy_reference import arrays_from_scene, render_numpy  # noqa: E402

import strauss_fit as sf  # noqa: E402
from strauss_fit import Target, fit, parse_scene, plan_render  # noqa: E402
from strauss_fit.fitting.identifiability import DEFAULT_THRESHOLD, MIRROR_SMOOTHNESS  # noqa: E402
from strauss_fit.fitting.solvers import solve_starts  # noqa: E402
from strauss_fit.models.strauss import DEFAULT_TABLE_SIZE  # noqa: E402
from strauss_fit.rendering.strauss import render_jit  # noqa: E402
from strauss_fit.stats.laplace import information as laplace_information  # noqa: E402
from strauss_fit.stats.laplace import jacobian as laplace_jacobian  # noqa: E402

FREE = ("color", "smoothness", "metalness")
NOISE = 0.01  # of the clean image's 98th percentile over the sphere
WITHIN = 0.02  # "landed on the truth"
DTYPES = (jnp.float32, jnp.float64)

# --- scenes ----------------------------------------------------------------------------

EVALUATOR_SCENE = """
[camera]
width = {size}
height = {size}
[[light]]
kind = "directional"
direction = [0.3, 0.5, 1.0]
intensity = 1.0
[[light]]
kind = "directional"
direction = [-1.0, 0.2, 0.15]
intensity = 0.8
[[light]]
kind = "ambient"
intensity = 0.1
[render]
depth = 1
"""
# A frontal key light and a light from the side, so that grazing incidence (where the
# F and G tables err most, see strauss_fit.models.strauss.shade) is lit on part of the sphere.
TIMED_MATERIAL = dict(color=(0.8, 0.3, 0.2), smoothness=0.6, metalness=0.3, transparency=0.0)
ERROR_MATERIALS = [
    dict(color=(1.0, 1.0, 1.0), smoothness=s, metalness=m, transparency=t)
    for s in (0.3, 0.6, 0.9, 1.0)
    for m in (0.0, 1.0)
    for t in (0.0, 0.5)
]


def fit_scene(size: int):
    """``key_and_fill.toml`` at ``size`` pixels over a grey backdrop, at depth 2: a mirror
    (s = 1) reflects it, so even s = 1 leaves an image."""
    return key_and_fill_scene(size, background={"color": [0.4, 0.45, 0.5]}, depth=2, source="tradeoff")


FIT_MATERIALS = [
    dict(color=(0.8, 0.3, 0.2), smoothness=0.0, metalness=0.0),
    dict(color=(0.2, 0.5, 0.9), smoothness=0.0, metalness=1.0),
    dict(color=(0.8, 0.3, 0.2), smoothness=1.0, metalness=0.0),
    dict(color=(0.2, 0.5, 0.9), smoothness=1.0, metalness=1.0),
    dict(color=(0.7, 0.4, 0.2), smoothness=0.5, metalness=0.5),
    dict(color=(0.3, 0.6, 0.4), smoothness=0.8, metalness=0.2),
]
QUICK_FIT_MATERIALS = [FIT_MATERIALS[0], FIT_MATERIALS[3], FIT_MATERIALS[4]]
SAMPLER_MATERIAL = dict(color=(0.7, 0.4, 0.2), smoothness=0.6, metalness=0.4)


def scene_from(template: str, size: int):
    return parse_scene(tomllib.loads(template.format(size=size)), source="tradeoff")


# --- helpers ---------------------------------------------------------------------------


def machine_info() -> dict:
    """:func:`bench_common.machine` (printed) with the library versions, the device and ``XLA_FLAGS``."""
    return {
        **machine(),
        "numpy": np.__version__,
        "jax_device": str(jax.devices()[0]),
        "strauss_fit": sf.__version__,
        "XLA_FLAGS": os.environ.get("XLA_FLAGS", ""),
        "load_average_before": os.getloadavg(),
    }


def device_memory_stats() -> dict | None:
    """``jax.devices()[0].memory_stats()`` where the backend has it (None on CPU)."""
    try:
        stats = jax.devices()[0].memory_stats()
    except Exception:  # noqa: BLE001 - backends without it raise or return None
        return None
    return dict(stats) if stats else None


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # kB on Linux


def xla_memory(compiled) -> dict | None:
    """Temporary and output bytes of a compiled XLA program (its working memory)."""
    compiled = getattr(compiled, "compiled", compiled)  # equinox wraps jax's Compiled
    try:
        stats = compiled.memory_analysis()
    except Exception:  # noqa: BLE001
        return None
    if stats is None:
        return None
    return {
        "temp_bytes": int(stats.temp_size_in_bytes),
        "output_bytes": int(stats.output_size_in_bytes),
        "argument_bytes": int(stats.argument_size_in_bytes),
        "working_bytes": int(stats.temp_size_in_bytes + stats.output_size_in_bytes),
    }


def noisy_target(scene, material: dict, seed: int) -> tuple[Target, float]:
    image, hit = sf.render(scene, sf.Material(**material))
    image, hit = np.asarray(image), np.asarray(hit)
    sigma = NOISE * float(np.percentile(image[hit], 98))
    pixels = image + sigma * np.random.default_rng(seed).normal(size=image.shape)
    return Target(pixels, np.ones(hit.shape, bool), "synthetic", "linear", 0, 0), sigma


def truth_vector(material: dict) -> np.ndarray:
    return np.r_[np.asarray(material["color"], float), material["smoothness"], material["metalness"]]


LABELS = ["color_r", "color_g", "color_b", "smoothness", "metalness"]


def fitted_vector(result) -> np.ndarray:
    m = result.material
    return np.r_[np.asarray(m.color, float), float(m.smoothness), float(m.metalness)]


def pareto_front(points: list[tuple[float, float]]) -> list[int]:
    """Indices of the non-dominated points (lower cost and lower error are better)."""
    front = []
    for i, (c, e) in enumerate(points):
        dominated = any((c2 <= c and e2 <= e) and (c2 < c or e2 < e) for j, (c2, e2) in enumerate(points) if j != i)
        if not dominated:
            front.append(i)
    return sorted(front, key=lambda i: points[i][0])


def fmt(x, digits=2) -> str:
    if x is None:
        return "-"
    if isinstance(x, str):
        return x
    if x == 0:
        return "0"
    if abs(x) >= 1e4 or abs(x) < 1e-2:
        return f"{x:.{digits - 1}e}"
    return f"{x:.{digits + 1}g}" if abs(x) < 100 else f"{x:.0f}"


def markdown_table(header: list[str], rows: list[list]) -> str:
    lines = [
        "| " + " | ".join(header) + " |",
        "|" + "|".join("---" if i == 0 else "---:" for i in range(len(header))) + "|",
    ]
    lines += ["| " + " | ".join(fmt(v) if not isinstance(v, str) else v for v in row) + " |" for row in rows]
    return "\n".join(lines)


# --- knob 1: the evaluator -------------------------------------------------------------


def knob_evaluator(quick: bool) -> dict:
    size = 256
    repeats = 5 if quick else 15
    table_sizes = (256, 1024) if quick else (64, 256, 1024, 4096)
    scene = scene_from(EVALUATOR_SCENE, size)
    timed = sf.Material(**TIMED_MATERIAL)
    plan = plan_render(scene, timed)
    configs = [("exact", None, d) for d in DTYPES]
    configs += [(mode, n, d) for mode in ("table", "j-table") for n in table_sizes for d in DTYPES]
    hit = np.asarray(sf.render(scene, timed)[1])

    def call(mode, n, dtype, material=timed):
        image, _ = sf.render(scene, material, mode=mode, table_size=n or DEFAULT_TABLE_SIZE, dtype=dtype)
        return jax.block_until_ready(image)

    # first calls (each configuration is its own compilation: mode, size and dtype are static)
    first = {}
    for config in configs:
        started = time.perf_counter()
        call(*config)
        first[config] = time.perf_counter() - started
    # NumPy reference: time and tracemalloc peak
    numpy_args = arrays_from_scene(scene, timed)
    render_numpy(**numpy_args)
    tracemalloc.start()
    render_numpy(**numpy_args)
    _, numpy_peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    # interleaved warm rounds
    times = {c: [] for c in configs}
    times["numpy"] = []
    for config in configs:
        call(*config)
    for _ in range(repeats):
        for config in configs:
            started = time.perf_counter()
            call(*config)
            times[config].append(time.perf_counter() - started)
        started = time.perf_counter()
        render_numpy(**numpy_args)
        times["numpy"].append(time.perf_counter() - started)

    # accuracy against exact float64, the timed material and the worst over ERROR_MATERIALS
    materials = [timed] + [sf.Material(**m) for m in ERROR_MATERIALS]
    references = [np.asarray(call("exact", None, jnp.float64, m)) for m in materials]
    numpy_image = render_numpy(**numpy_args)[0]
    rows = []
    angle_reference: dict = {}
    numpy_error = np.abs(numpy_image - references[0]).max(-1)[hit]
    rows.append(
        {
            "label": "NumPy reference",
            "mode": "numpy",
            "table_size": None,
            "dtype": "float64",
            "median_ms": statistics.median(times["numpy"]) * 1e3,
            "min_ms": min(times["numpy"]) * 1e3,
            "first_call_s": None,
            "memory": {"tracemalloc_peak_bytes": numpy_peak},
            "working_mb": numpy_peak / 2**20,
            "table_mb": 0.0,
            "max_error": float(numpy_error.max()),
            "mean_error": float(numpy_error.mean()),
            "worst_material_max_error": None,
            "worst_material_mean_error": None,
            "all_angle_max_error": None,
        }
    )
    for config in configs:
        mode, n, dtype = config
        errors = [
            np.abs(np.asarray(call(mode, n, dtype, m), np.float64) - ref).max(-1)[hit]
            for m, ref in zip(materials, references)
        ]
        lowered = render_jit.lower(scene, timed, plan, mode, int(n or DEFAULT_TABLE_SIZE), jnp.dtype(dtype))
        memory = xla_memory(lowered.compile())
        itemsize = jnp.dtype(dtype).itemsize
        table_bytes = 0 if mode == "exact" else (2 * n * itemsize if mode == "table" else (n * n + n) * itemsize)
        label = "exact" if mode == "exact" else f"{mode} {n}"
        angle_error = all_angle_errors(mode, n, dtype, angle_reference)
        rows.append(
            {
                "label": f"{label} {jnp.dtype(dtype).name}",
                "mode": mode,
                "table_size": n,
                "dtype": jnp.dtype(dtype).name,
                "median_ms": statistics.median(times[config]) * 1e3,
                "min_ms": min(times[config]) * 1e3,
                "first_call_s": first[config],
                "memory": memory,
                "working_mb": None if memory is None else memory["working_bytes"] / 2**20,
                "table_mb": table_bytes / 2**20,
                "max_error": float(errors[0].max()),
                "mean_error": float(errors[0].mean()),
                "worst_material_max_error": float(max(e.max() for e in errors)),
                "worst_material_mean_error": float(max(e.mean() for e in errors)),
                "all_angle_max_error": angle_error,
            }
        )
    exact = {r["dtype"]: r for r in rows if r["mode"] == "exact"}
    for r in rows:
        base = exact.get(r["dtype"], exact["float64"])
        r["ratio_to_exact_same_dtype"] = r["median_ms"] / base["median_ms"]
        r["min_ratio_to_exact_same_dtype"] = r["min_ms"] / base["min_ms"]
    return {
        "image_size": size,
        "repeats": repeats,
        "table_sizes": list(table_sizes),
        "rows": rows,
        "materials_for_worst_case": ERROR_MATERIALS,
        "timed_material": TIMED_MATERIAL,
        "device_memory_stats": device_memory_stats(),
        "peak_rss_mb_after": peak_rss_mb(),
    }


def all_angle_errors(mode: str, table_size: int | None, dtype, reference: dict) -> tuple[float, np.ndarray]:
    """Worst |shade - exact float64| over a dense grid of incidence and view angles (0 to
    89.999°, viewer in and across the mirror plane) and :data:`ANGLE_MATERIALS`: the
    evaluator's error bound, which a rendered sphere (whose rim pixels never reach N·V -> 0)
    does not exercise fully. s = 1 is left out: the grid holds exactly mirrored directions,
    where the delta highlight is on or off depending on the last bit of cos β."""
    key = (mode, table_size, jnp.dtype(dtype).name)
    if "grid" not in reference:
        angles = np.radians(np.linspace(0.0, 89.999, 181))
        light = np.stack([np.sin(angles), np.zeros_like(angles), np.cos(angles)], -1)
        eye = np.concatenate(
            [
                np.stack([-np.sin(angles), np.zeros_like(angles), np.cos(angles)], -1),
                np.stack([np.zeros_like(angles), np.sin(angles), np.cos(angles)], -1),
            ]
        )
        params = np.asarray([[m["smoothness"], m["metalness"], m["transparency"]] for m in ANGLE_MATERIALS])
        reference["grid"] = (light, eye, params)
    light, eye, params = reference["grid"]

    def one(p, mode, size, dt):
        material = sf.Material(color=jnp.ones(3, dt), smoothness=p[0], metalness=p[1], transparency=p[2])
        return sf.shade(
            material,
            jnp.asarray([0.0, 0.0, 1.0], dt),
            jnp.asarray(light, dt)[:, None, :],
            jnp.asarray(eye, dt)[None, :, :],
            mode=mode,
            table_size=size,
        )

    def evaluate(mode, size, dt):
        f = jax.jit(jax.vmap(lambda p: one(p, mode, size, dt)))
        return np.asarray(f(jnp.asarray(params, dt)), np.float64)

    if "exact" not in reference:
        reference["exact"] = evaluate("exact", DEFAULT_TABLE_SIZE, jnp.float64)
    out = evaluate(mode, table_size or DEFAULT_TABLE_SIZE, dtype)
    reference[key] = float(np.abs(out - reference["exact"]).max())
    return reference[key]


ANGLE_MATERIALS = [
    dict(smoothness=s, metalness=m, transparency=t)
    for s in (0.0, 0.5, 0.9, 0.99)
    for m in (0.0, 1.0)
    for t in (0.0, 0.5)
]


def table_mode_verdict(evaluator: dict) -> dict:
    """Whether any table configuration is faster than exact in the same precision, from
    the medians *and* the fastest rounds (a table counts as faster only if both say so)."""
    rows = [r for r in evaluator["rows"] if r["mode"] in ("table", "j-table")]
    faster = [r for r in rows if r["ratio_to_exact_same_dtype"] < 1.0 and r["min_ratio_to_exact_same_dtype"] < 1.0]
    best = min(rows, key=lambda r: r["ratio_to_exact_same_dtype"])
    worth = bool(faster)
    if worth:
        text = (
            "Table modes ARE faster than exact on this machine for: "
            + ", ".join(
                f"{r['label']} ({r['ratio_to_exact_same_dtype']:.2f}x the exact time, max error "
                f"{r['worst_material_max_error']:.1e})"
                for r in faster
            )
            + "."
        )
    else:
        text = (
            f"The table modes are NOT worth it on this machine ({jax.default_backend().upper()}, "
            f"{os.cpu_count()} cores): every table configuration is slower than exact in the same precision "
            f"(the fastest, {best['label']}, takes {best['ratio_to_exact_same_dtype']:.2f}x the exact median "
            f"and {best['min_ratio_to_exact_same_dtype']:.2f}x its fastest round) while adding error (float64 "
            f"tables) up to {max(r['worst_material_max_error'] for r in rows if r['dtype'] == 'float64'):.1e} on "
            f"the rendered sphere and {max(r['all_angle_max_error'] for r in rows if r['dtype'] == 'float64'):.1e} "
            "over all angles. Exact mode is both faster and exact; "
            "the tables only pay off where gathers are cheap and transcendental functions are not."
        )
    return {"worth_it": worth, "faster_configurations": [r["label"] for r in faster], "text": text}


# --- fits: shared machinery -------------------------------------------------------------

NULL_EIGENVALUE = 1e-10  # relative to the largest eigenvalue of the Fisher information
PREDICTED_SD_LIMIT = DEFAULT_THRESHOLD  # the library's identifiability threshold


def constrained_parameters(
    layout, jacobian: np.ndarray, sigma: float, threshold: float = PREDICTED_SD_LIMIT
) -> tuple[list[str], dict[str, str]]:
    """Parameters whose predicted standard deviation, with *every* fitted parameter free
    (as in these fits), is at most ``threshold`` at noise ``sigma``: the criterion of the
    library's ``numerical_decision``, without its step of holding parameters one by one
    (the fits here hold none) and with exactly degenerate directions counted as
    unconstrained: an eigenvalue of the Fisher information J^T J / sigma^2 below
    :data:`NULL_EIGENVALUE` times the largest gives every parameter with a component along
    it an infinite deviation (a pseudo-inverse would drop the direction silently, and at
    s = 1, where only m (C - 1) is visible, call both m and C well determined)."""
    information = laplace_information(jacobian) / sigma**2
    values, vectors = np.linalg.eigh(information)
    null = values <= NULL_EIGENVALUE * max(values.max(), 1e-300)
    variance = (vectors[:, ~null] ** 2 / values[~null]).sum(axis=1)
    degenerate = np.any(np.abs(vectors[:, null]) > 1e-6, axis=1) if null.any() else np.zeros(values.size, bool)
    sd = np.where(degenerate, np.inf, np.sqrt(variance))
    free, held = [], {}
    for name, size, offset in zip(layout.names, layout.sizes, layout.offsets):
        worst = float(sd[offset : offset + size].max())
        if worst <= threshold:
            free.append(name)
        else:
            held[name] = (
                "degenerate (a null direction of the Fisher information)"
                if math.isinf(worst)
                else f"predicted deviation {worst:.2g} > {threshold}"
            )
    return free, held


class FitBench:
    """Targets and the scoring of fits, per resolution."""

    def __init__(self, materials: list[dict], draws: int, reference_size: int):
        self.materials = materials
        self.draws = draws
        self.reference_size = reference_size
        self.targets: dict[int, list] = {}
        self.scored: list[np.ndarray] | None = None
        self.scored_names: list[list[str]] = []

    def targets_at(self, size: int) -> list:
        if size not in self.targets:
            scene = fit_scene(size)
            items = []
            for i, material in enumerate(self.materials):
                for d in range(self.draws):
                    target, sigma = noisy_target(scene, material, seed=1000 * size + 10 * i + d)
                    items.append((i, material, target, sigma))
            self.targets[size] = (scene, items)
        return self.targets[size]

    def decide_scored(self, results_at_reference: list) -> None:
        """Which entries each material's image constrains: the library's rule at the truth."""
        scored, names = [], []
        done = {}
        _, items = self.targets_at(self.reference_size)
        for (i, material, _, sigma), result in zip(items, results_at_reference):
            if i in done:
                continue
            problem = result.problem
            x_true = problem.layout.join(material)
            jacobian = np.asarray(laplace_jacobian(problem, jnp.asarray(x_true)))
            free, held = constrained_parameters(problem.layout, jacobian, sigma)
            if material["smoothness"] >= MIRROR_SMOOTHNESS:  # scored as the tint (see score)
                held.update({n: "a mirror: only the tint m (C - 1) is seen" for n in ("color", "metalness")})
                free = [n for n in free if n not in ("color", "metalness")] + ["mirror tint m(C-1)"]
            mask = np.concatenate(
                [np.full(size, name in free) for name, size in zip(problem.layout.names, problem.layout.sizes)]
            )
            done[i] = (mask, free, held)
        for i in range(len(self.materials)):
            scored.append(done[i][0])
            names.append(done[i][1])
        self.scored, self.scored_names = scored, names
        self.held_reasons = [done[i][2] for i in range(len(self.materials))]

    def score(self, items: list, results: list) -> dict:
        errors, per_param = [], []
        for (i, material, _, _), result in zip(items, results):
            error = np.abs(fitted_vector(result) - truth_vector(material))
            scored = self.scored[i].copy()
            worst = 0.0
            if material["smoothness"] >= MIRROR_SMOOTHNESS:
                # over the uniform backdrop a mirror shows only its tint m (C - 1): score
                # that instead of C and m (see the module docstring)
                fitted, true = fitted_vector(result), truth_vector(material)
                worst = float(np.max(np.abs(fitted[4] * (fitted[:3] - 1) - true[4] * (true[:3] - 1))))
                scored[[0, 1, 2, 4]] = False
            per_param.append(np.where(scored, error, np.nan))
            errors.append(max(worst, float(error[scored].max()) if scored.any() else 0.0))
        errors = np.asarray(errors)
        per_param = np.asarray(per_param)
        finite = [bool(np.all(np.isfinite(fitted_vector(r)))) for r in results]
        return {
            "median_max_error": float(np.median(errors)),
            "p90_max_error": float(np.percentile(errors, 90)),
            "worst_max_error": float(errors.max()),
            "mean_max_error": float(errors.mean()),
            "within_0.02": float(np.mean(errors <= WITHIN)),
            "median_error_by_parameter": {
                label: (None if np.all(np.isnan(per_param[:, k])) else float(np.nanmedian(per_param[:, k])))
                for k, label in enumerate(LABELS)
            },
            "all_finite": all(finite),
            "errors": errors.tolist(),
        }


def run_fits(bench: FitBench, size: int, options: sf.FitOptions) -> tuple[dict, list]:
    """One compiling call, then every target warm. Returns the row and the results."""
    scene, items = bench.targets_at(size)
    started = time.perf_counter()
    fit(scene, items[0][2], options)
    first = time.perf_counter() - started
    results, times, solve_times, steps, statuses = [], [], [], [], []
    for _, _, target, _ in items:
        started = time.perf_counter()
        result = fit(scene, target, options)
        times.append(time.perf_counter() - started)
        solve_times.append(result.compile_and_solve["solve_s"])
        steps.append(result.solver["steps"])
        statuses.append(result.solver["status"])
        results.append(result)
    problem = results[0].problem
    thetas = jnp.zeros((options.starts, problem.layout.size))
    memory = None
    try:
        lowered = solve_starts.lower(problem, thetas, options.solver, options.rtol, options.atol, options.start_steps)
        memory = xla_memory(lowered.compile())
    except Exception:  # noqa: BLE001 - memory is a bonus, never a failure
        pass
    problem_bytes = sum(
        np.asarray(leaf).nbytes for leaf in jax.tree_util.tree_leaves(problem) if hasattr(leaf, "nbytes")
    )
    row = {
        "size": size,
        "rtol": options.rtol,
        "atol": options.atol,
        "starts": options.starts,
        "max_steps": options.max_steps,
        "pixels_used": results[0].pixels_used,
        "fits": len(results),
        "first_call_s": first,
        "median_fit_s": statistics.median(times),
        "min_fit_s": min(times),
        "total_fit_s": float(sum(times)),
        "median_solve_s": statistics.median(solve_times),
        "median_steps": statistics.median(steps),
        "max_steps_used": max(steps),
        "max_polish_steps": max(r.solver["polish_steps"] for r in results),
        "statuses": {s: statuses.count(s) for s in sorted(set(statuses))},
        "memory": {"xla_solve": memory, "problem_bytes": int(problem_bytes)},
        "working_mb": None if memory is None else (memory["working_bytes"] + problem_bytes) / 2**20,
        "peak_rss_mb_after": peak_rss_mb(),
    }
    row.update(bench.score(items, results) if bench.scored is not None else {})
    return row, results


# --- knob 2, 3: resolution, tolerance, starts ---------------------------------------------


def knob_fits(quick: bool) -> dict:
    sizes = (32, 64) if quick else (32, 64, 128, 256)
    reference = 32 if quick else 64
    bench = FitBench(QUICK_FIT_MATERIALS if quick else FIT_MATERIALS, draws=1 if quick else 2, reference_size=reference)
    default = legacy_options(free=FREE)
    resolution, cached = [], {}
    # the reference resolution first: its fits decide which parameters each image constrains
    order = [reference] + [s for s in sizes if s != reference]
    for size in order:
        row, results = run_fits(bench, size, default)
        if size == reference:
            bench.decide_scored(results)
            _, items = bench.targets_at(size)
            row.update(bench.score(items, results))
        cached[(size, default.rtol, default.atol, default.starts)] = row
        resolution.append(row)
    resolution.sort(key=lambda r: r["size"])

    tolerances = ((1e-3, 1e-5), (1e-6, 1e-8)) if quick else ((1e-2, 1e-4), (1e-4, 1e-6), (1e-6, 1e-8), (1e-8, 1e-10))
    tolerance = []
    for rtol, atol in tolerances:
        key = (reference, rtol, atol, default.starts)
        row = cached.get(key) or run_fits(bench, reference, legacy_options(free=FREE, rtol=rtol, atol=atol))[0]
        cached[key] = row
        tolerance.append(row)

    starts_values = (1, 4) if quick else (1, 2, 4, 8)
    starts = []
    for count in starts_values:
        key = (reference, default.rtol, default.atol, count)
        row = cached.get(key) or run_fits(bench, reference, legacy_options(free=FREE, starts=count))[0]
        cached[key] = row
        starts.append(row)
    return {
        "reference_size": reference,
        "materials": bench.materials,
        "draws_per_material": bench.draws,
        "noise": f"Gaussian, sigma = {NOISE:.0%} of the clean image's 98th percentile over the sphere",
        "free": list(FREE),
        "scored": [
            {"material": m, "constrained": names, "not_scored": held}
            for m, names, held in zip(bench.materials, bench.scored_names, bench.held_reasons)
        ],
        "resolution": resolution,
        "tolerance": tolerance,
        "starts": starts,
        "device_memory_stats": device_memory_stats(),
    }


BUNDLED_TARGET = ROOT / "data_synth" / "bundled" / "strauss-noisy-0000.exr"
BUNDLED_SCENE = ROOT / "data_synth" / "scenes" / "two_lights.toml"


def _bundled_fit(starts: int, max_steps: int, rtol: float, atol: float) -> dict:
    from strauss_fit import load_scene, load_target, match_scene

    target = load_target(BUNDLED_TARGET)
    scene, _ = match_scene(load_scene(BUNDLED_SCENE), target)
    result = fit(scene, target, sf.FitOptions(starts=starts, max_steps=max_steps, rtol=rtol, atol=atol))
    return {"starts": starts, "rms": result.residual["rms"], "smoothness": float(result.material.smoothness)}


def check_presets_on_bundled(derived: dict) -> list[dict]:
    """Each derived fit preset on the README's set-up fit (the bundled
    ``strauss-noisy-0000.exr``, s = 0.2825, in its own scene, every parameter decided by the
    library). The synthetic set above has no local minimum that a quick fit falls into;
    this image has one (s = 0, RMS 0.0149 against 0.0144), where a single start with a
    loose tolerance stops. A preset whose RMS there exceeds the tightest preset's by more
    than 1 % gets twice the starts until it does not (at most 8), and the presets after it
    at least as many; the justification says so. Updates ``derived`` in place."""
    presets, why = derived["presets"], derived["justification"]
    names = ("fast", "balanced", "accurate")
    settings = {
        n: (presets[n].get("max_steps", 100), presets[n].get("rtol", 1e-6), presets[n].get("atol", 1e-8)) for n in names
    }
    reference = _bundled_fit(presets["accurate"].get("starts", 4), *settings["accurate"])["rms"]
    checks, floor = [], 1
    for name in names:
        starts = max(presets[name].get("starts", 1), floor)
        result = _bundled_fit(starts, *settings[name])
        while result["rms"] > 1.01 * reference and starts < 8:
            why[name].append(
                f"starts {starts} stop at s = {result['smoothness']:.3g} on the bundled "
                f"strauss-noisy-0000.exr (RMS {result['rms']:.4g} against {reference:.4g}): doubled"
            )
            starts *= 2
            result = _bundled_fit(starts, *settings[name])
        if starts != presets[name].get("starts"):
            why[name].append(
                f"starts {starts}: reaches the bundled example's optimum (RMS {result['rms']:.4g}, "
                f"s = {result['smoothness']:.3g})"
            )
        presets[name]["starts"] = starts
        floor = starts if name == "fast" else 2 * starts  # accurate keeps twice balanced's
        checks.append({"preset": name, **result})
    return checks


# --- knob 4: sampler length ------------------------------------------------------------------


def central_interval(samples: np.ndarray, level: float) -> tuple[np.ndarray, np.ndarray]:
    tail = (1 - level) / 2 * 100
    return np.percentile(samples, tail, axis=0), np.percentile(samples, 100 - tail, axis=0)


def sample_chain(run_sampler, settings_class, log_posterior, start: np.ndarray, steps: int, seed: int) -> dict:
    """A chain of exactly ``steps`` steps from ``start``: through ``strauss_fit.inference.sampler.run_sampler``
    (in memory, its stopping rule disabled), or, should its signature have changed under
    us, through emcee directly on the same vectorised log-posterior."""
    import dataclasses

    import emcee

    wanted = {"max_steps": steps, "min_tau_multiple": 1e9, "check_every": steps, "seed": seed}
    try:
        names = {f.name for f in dataclasses.fields(settings_class)}
        settings = settings_class(**{k: v for k, v in wanted.items() if k in names})
        run = run_sampler(log_posterior, None, start=start, settings=settings)
        return {
            "chain": np.asarray(run.chain),
            "sampling_s": float(run.sampling_s),
            "acceptance": float(run.diagnostics.acceptance_mean),
            "driver": "strauss_fit.inference.sampler.run_sampler",
        }
    except (TypeError, AttributeError) as exc:
        sampler = emcee.EnsembleSampler(start.shape[0], start.shape[1], log_posterior, vectorize=True)
        state = emcee.State(start, random_state=np.random.RandomState(seed).get_state())
        started = time.perf_counter()
        sampler.run_mcmc(state, steps)
        return {
            "chain": sampler.get_chain(),
            "sampling_s": time.perf_counter() - started,
            "acceptance": float(np.mean(sampler.acceptance_fraction)),
            "driver": f"emcee directly (run_sampler failed: {type(exc).__name__}: {exc})",
        }


def laplace_row(laplace: list[dict], truth: np.ndarray, fit_times: list[float]) -> dict:
    """Width and coverage of the fits' Laplace intervals x_hat ± z sd (z = 0.994, 1.960)."""
    sd = np.asarray([l["sd"] for l in laplace])
    error = np.abs(np.asarray([l["x"] for l in laplace]) - truth)
    return {
        "kind": "laplace",
        "walkers": None,
        "steps": 0,
        "cost_s": statistics.median(fit_times),
        "sampling_s": 0.0,
        "log_probs": 0,
        "width95_mean": float(np.mean(2 * 1.960 * sd)),
        "width68_mean": float(np.mean(2 * 0.994 * sd)),
        "width95_by_parameter": dict(zip(LABELS, np.mean(2 * 1.960 * sd, axis=0).tolist())),
        "coverage95": float(np.mean(error <= 1.960 * sd)),
        "coverage68": float(np.mean(error <= 0.994 * sd)),
        "tau_multiple_median": None,
        "acceptance_median": None,
    }


def knob_sampler(quick: bool) -> dict:
    """Repeated noise draws of one small problem: the fits' Laplace intervals, and emcee
    chains of several lengths (if ``strauss_fit.inference.sampler`` is usable)."""
    size = 32
    draws = 4 if quick else 16
    lengths = (100, 250, 500) if quick else (100, 250, 500, 1000, 2000)
    scene = fit_scene(size)
    truth = truth_vector(SAMPLER_MATERIAL)
    options = legacy_options(free=FREE)
    fit(scene, noisy_target(scene, SAMPLER_MATERIAL, 0)[0], options)  # compile (shared with the 32 px fits)
    fits, laplace, fit_times = [], [], []
    for d in range(draws):
        target, sigma = noisy_target(scene, SAMPLER_MATERIAL, seed=50_000 + d)
        started = time.perf_counter()
        result = fit(scene, target, options)
        fit_times.append(time.perf_counter() - started)
        sd = np.concatenate([np.atleast_1d(result.uncertainty[name]) for name in FREE])
        laplace.append({"x": fitted_vector(result), "sd": sd})
        fits.append((result, sigma))
    out = {
        "size": size,
        "draws": draws,
        "material": SAMPLER_MATERIAL,
        "pairs_per_coverage": draws * truth.size,
        "coverage_standard_error_at_0.95": math.sqrt(0.95 * 0.05 / (draws * truth.size)),
        "rows": [laplace_row(laplace, truth, fit_times)],
    }
    try:
        from strauss_fit.inference.posterior import LogPosterior, default_prior
        from strauss_fit.inference.sampler import (
            SampleSettings,
            autocorrelation_times,
            burn_in,
            default_walkers,
            initial_walkers,
            run_sampler,
        )
        from strauss_fit.stats.laplace import laplace_covariance
    except ImportError as exc:  # the sampler is another engineer's work in progress
        return dict(
            out,
            status=f"sampler part pending: strauss_fit.inference.sampler is not usable yet ({exc}); "
            "Laplace intervals only",
        )
    walkers_list = (default_walkers(truth.size),) if quick else (16, default_walkers(truth.size), 64)
    runs = {w: [] for w in walkers_list}
    for d, (result, sigma) in enumerate(fits):
        problem, x_hat = result.problem, fitted_vector(result)
        prior = default_prior(problem.layout, x_hat)
        log_posterior = LogPosterior(problem, prior, sigma)
        covariance = laplace_covariance(problem, x_hat, sigma)
        for w in walkers_list:
            start = initial_walkers(x_hat, covariance, prior, w, np.random.default_rng(d), log_posterior)
            if d == 0:  # compile both batch sizes emcee uses (all walkers, half) outside the timing
                log_posterior(start)
                log_posterior(start[: w // 2])
            runs[w].append(sample_chain(run_sampler, SampleSettings, log_posterior, start, max(lengths), seed=d))
    rows = []
    for w, chains in runs.items():
        per_step = statistics.median(c["sampling_s"] for c in chains) / max(lengths)
        for length in lengths:
            widths68, widths95, cover68, cover95, multiples = [], [], [], [], []
            for c in chains:
                chain = c["chain"][:length]
                tau = autocorrelation_times(chain)
                samples = chain[burn_in(tau, length) :].reshape(-1, chain.shape[-1])
                for level, widths, cover in ((0.68, widths68, cover68), (0.95, widths95, cover95)):
                    lo, hi = central_interval(samples, level)
                    widths.append(hi - lo)
                    cover.append((truth >= lo) & (truth <= hi))
                multiples.append(length / float(np.max(tau)))
            rows.append(
                {
                    "kind": "emcee",
                    "walkers": w,
                    "steps": length,
                    "cost_s": statistics.median(fit_times) + per_step * length,
                    "sampling_s": per_step * length,
                    "log_probs": w * length,
                    "width95_mean": float(np.mean(widths95)),
                    "width68_mean": float(np.mean(widths68)),
                    "width95_by_parameter": dict(zip(LABELS, np.mean(widths95, axis=0).tolist())),
                    "coverage95": float(np.mean(cover95)),
                    "coverage68": float(np.mean(cover68)),
                    "tau_multiple_median": float(np.median(multiples)),
                    "acceptance_median": float(statistics.median(c["acceptance"] for c in chains)),
                }
            )
    long_chains = runs[default_walkers(truth.size)]
    taus = [float(np.max(autocorrelation_times(c["chain"]))) for c in long_chains]
    out["rows"] += rows
    out.update(
        {
            "status": "measured",
            "sigma": "known (the noise the target was drawn with)",
            "lengths": list(lengths),
            "walkers": list(walkers_list),
            "tau_max_median_longest_chain": float(np.median(taus)),
            "default_walkers": default_walkers(truth.size),
            "driver": sorted({c["driver"] for chains in runs.values() for c in chains}),
            "peak_rss_mb_after": peak_rss_mb(),
        }
    )
    return out


# --- presets ----------------------------------------------------------------------------------


def ceil_to(x: float, step: int) -> int:
    return int(math.ceil(x / step) * step)


def derive_presets(evaluator: dict | None, fits: dict | None, sampler: dict | None) -> dict:
    presets = {name: {} for name in ("fast", "balanced", "accurate")}
    why = {name: [] for name in presets}

    # evaluator (fits run in float64): the fastest float64 configuration within an error budget
    if evaluator:
        rows = [r for r in evaluator["rows"] if r["dtype"] == "float64" and r["mode"] != "numpy"]
        exact = next(r for r in rows if r["mode"] == "exact")
        for name, budget in (("fast", 1e-3), ("balanced", 1e-4), ("accurate", 0.0)):
            ok = [
                r for r in rows if max(r["worst_material_max_error"] or 0.0, r["all_angle_max_error"] or 0.0) <= budget
            ]
            best = min(ok, key=lambda r: r["median_ms"])
            presets[name]["mode"] = best["mode"]
            presets[name]["table_size"] = best["table_size"] or DEFAULT_TABLE_SIZE
            if best["mode"] == "exact":
                faster = [r for r in rows if r["median_ms"] < exact["median_ms"]]
                why[name].append(
                    f"mode exact: {exact['median_ms']:.1f} ms per 256² float64 frame (error budget {budget:g}); "
                    + (
                        "no table configuration is faster here"
                        if not faster
                        else f"the faster table configurations ({', '.join(r['label'] for r in faster)}) exceed the "
                        f"error budget {budget:g}"
                    )
                    + " (table_size unused)"
                )
            else:
                why[name].append(
                    f"mode {best['mode']} {best['table_size']}: {best['median_ms']:.1f} ms vs exact "
                    f"{exact['median_ms']:.1f} ms, worst error (render or all-angle) "
                    f"{max(best['worst_material_max_error'], best['all_angle_max_error']):.1e} "
                    f"<= budget {budget:g}"
                )

    if fits:
        tol = fits["tolerance"]
        tightest = min(tol, key=lambda r: r["rtol"])
        reference_error = tightest["median_max_error"]

        def good_enough(r):
            return (
                r["median_max_error"] <= reference_error + max(0.1 * reference_error, 5e-4)
                and r["within_0.02"] >= tightest["within_0.02"] - 1e-9
            )

        ok = sorted([r for r in tol if good_enough(r)], key=lambda r: -r["rtol"])  # loosest first
        fast = ok[0] if ok else tightest
        by_rtol = sorted(tol, key=lambda r: -r["rtol"])
        index = by_rtol.index(fast)
        balanced = by_rtol[min(index + 1, len(by_rtol) - 1)]
        for name, row, note in (
            (
                "fast",
                fast,
                "the loosest pair whose median error is within max(10 %, 5e-4) of the "
                "tightest pair's and whose within-0.02 fraction is no lower",
            ),
            ("balanced", balanced, "one step tighter than fast, as a margin"),
            ("accurate", tightest, "the tightest pair measured"),
        ):
            presets[name]["rtol"], presets[name]["atol"] = row["rtol"], row["atol"]
            why[name].append(
                f"rtol/atol {row['rtol']:g}/{row['atol']:g}: median error {row['median_max_error']:.2g}, "
                f"{row['within_0.02']:.0%} within {WITHIN}, {row['median_fit_s'] * 1e3:.0f} ms per fit "
                f"({note})"
            )
            polish = max(row["max_polish_steps"], 1)
            steps = {
                "fast": max(20, ceil_to(2 * polish, 10)),
                "balanced": max(50, ceil_to(3 * polish, 10)),
                "accurate": max(200, ceil_to(5 * polish, 10)),
            }[name]
            presets[name]["max_steps"] = steps
            why[name].append(
                f"max_steps {steps}: the polish phase (the only one max_steps caps) took at most "
                f"{polish} steps in all its rounds at this tolerance; cap = 2x / 3x / 5x that, at least "
                "20 / 50 / 200"
            )
        st = fits["starts"]
        best_fraction = max(r["within_0.02"] for r in st)
        best_error = min(r["median_max_error"] for r in st)
        by_count = sorted(st, key=lambda r: r["starts"])
        fast_s = next(r for r in by_count if r["within_0.02"] >= best_fraction - 0.1)
        balanced_s = next(
            r for r in by_count if r["within_0.02"] >= best_fraction and r["median_max_error"] <= best_error + 1e-3
        )
        accurate_s = next((r for r in by_count if r["starts"] >= 2 * balanced_s["starts"]), by_count[-1])
        for name, row, note in (
            ("fast", fast_s, "fewest starts within 0.1 of the best within-0.02 fraction"),
            ("balanced", balanced_s, "fewest starts reaching the best fraction and error"),
            (
                "accurate",
                accurate_s,
                "twice balanced (or the most measured): robustness against local minima not in this test set",
            ),
        ):
            presets[name]["starts"] = row["starts"]
            why[name].append(
                f"starts {row['starts']}: {row['within_0.02']:.0%} within {WITHIN}, median error "
                f"{row['median_max_error']:.2g}, {row['median_fit_s'] * 1e3:.0f} ms per fit ({note})"
            )

    if sampler and sampler.get("status") == "measured":
        rows = [r for r in sampler["rows"] if r["kind"] == "emcee" and r["walkers"] == sampler["default_walkers"]]
        longest = max(rows, key=lambda r: r["steps"])
        tau = sampler["tau_max_median_longest_chain"]
        se = sampler["coverage_standard_error_at_0.95"]
        stable = [
            r
            for r in rows
            if abs(r["width95_mean"] / longest["width95_mean"] - 1) <= 0.1
            and r["coverage95"] >= longest["coverage95"] - se
        ]
        fast = min(stable, key=lambda r: r["steps"]) if stable else longest
        fast_note = (
            (
                f"shortest measured chain whose mean 95 % width is within 10 % of the {longest['steps']}-step "
                f"chain's and whose 95 % coverage ({fast['coverage95']:.0%}) is within one standard error "
                f"({se:.0%}) of it ({longest['coverage95']:.0%})"
            )
            if stable
            else f"no shorter chain matched the longest ({longest['steps']} steps), so the longest"
        )
        trusted = max(100, ceil_to(50 * tau, 100))  # the library's rule: >= 50 autocorrelation times
        for name, steps, note in (
            ("fast", fast["steps"], fast_note),
            (
                "balanced",
                trusted,
                f"50 x the measured autocorrelation time (tau ~ {tau:.0f} steps): the "
                "length strauss_fit.inference.sampler trusts",
            ),
            (
                "accurate",
                max(2 * trusted, 10000),
                "the sampler's own stopping rule (>= 50 tau and a stable tau) with room up to this many steps",
            ),
        ):
            presets[name]["sample_walkers"] = sampler["default_walkers"]
            presets[name]["sample_steps"] = int(steps)
            why[name].append(f"sampling {sampler['default_walkers']} walkers x {int(steps)} steps: {note}")
        if len(sampler["walkers"]) > 1:
            by_walkers = {
                w: next(r for r in sampler["rows"] if r["walkers"] == w and r["steps"] == longest["steps"])
                for w in sampler["walkers"]
            }
            why["balanced"].append(
                "walkers: "
                + "; ".join(
                    f"{w}: 95 % width {r['width95_mean']:.3g}, coverage {r['coverage95']:.0%}, {r['sampling_s']:.1f} s"
                    for w, r in by_walkers.items()
                )
                + f" at {longest['steps']} steps (default rule max(32, 4P))"
            )
    elif sampler:
        for name in presets:
            why[name].append("sampling: pending (" + sampler.get("status", "not measured") + ")")
    return {"presets": presets, "justification": why}


# --- plots -------------------------------------------------------------------------------------


def plot(
    path: Path,
    title: str,
    points: list[dict],
    xlabel: str,
    ylabel: str,
    *,
    floor: float | None = None,
    logy: bool = True,
    logx: bool = True,
    annotate: str | None = None,
    extra: list[dict] | None = None,
    extra_label: str = "",
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5.0), dpi=110)
    xs = [p["x"] for p in points]
    ys = [max(p["y"], floor) if floor else p["y"] for p in points]
    colours = [p.get("color", "C0") for p in points]
    ax.scatter(xs, ys, c=colours, zorder=3)
    for p, x, y in zip(points, xs, ys):
        ax.annotate(p["label"], (x, y), textcoords="offset points", xytext=(4, 4), fontsize=7)
    if extra:
        ax.scatter(
            [p["x"] for p in extra],
            [max(p["y"], floor) if floor else p["y"] for p in extra],
            facecolors="none",
            edgecolors=[p.get("color", "C0") for p in extra],
            s=18,
            zorder=2,
            label=extra_label,
        )
    front = pareto_front(list(zip(xs, ys)))
    ax.plot([xs[i] for i in front], [ys[i] for i in front], "k--", lw=0.8, zorder=2, label="Pareto front")
    if logx:
        ax.set_xscale("log")
    if logy:
        ax.set_yscale("log")
    if floor:
        ax.axhline(floor, color="grey", lw=0.5, ls=":")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    if annotate:
        ax.text(0.01, 0.01, annotate, transform=ax.transAxes, fontsize=7, va="bottom")
    ax.grid(True, which="both", lw=0.3, alpha=0.5)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def plot_sampler(path: Path, sampler: dict) -> None:
    """Cost against the 95 % interval's width (top) and coverage (bottom, with the nominal
    0.95 and ±2 standard errors of a coverage estimated from this many pairs). Narrower is
    not better here: the right width is the one whose coverage is nominal."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (top, bottom) = plt.subplots(2, 1, figsize=(7.5, 7.0), dpi=110, sharex=True)
    groups: dict = {}
    for r in sampler["rows"]:
        key = "Laplace (fit only)" if r["kind"] == "laplace" else f"emcee, {r['walkers']} walkers"
        groups.setdefault(key, []).append(r)
    for k, (key, rows) in enumerate(groups.items()):
        rows = sorted(rows, key=lambda r: r["cost_s"])
        xs = [r["cost_s"] for r in rows]
        style = dict(marker="s" if "Laplace" in key else "o", color=f"C{k}", label=key)
        top.plot(xs, [r["width95_mean"] for r in rows], **style)
        bottom.plot(xs, [r["coverage95"] for r in rows], **style)
        for r, x in zip(rows, xs):
            if r["steps"]:
                top.annotate(
                    f"{r['steps']}", (x, r["width95_mean"]), textcoords="offset points", xytext=(3, 3), fontsize=7
                )
    se = sampler["coverage_standard_error_at_0.95"]
    bottom.axhline(0.95, color="k", lw=0.8)
    bottom.axhspan(0.95 - 2 * se, min(0.95 + 2 * se, 1.0), color="grey", alpha=0.2, label="0.95 ± 2 s.e.")
    top.set_xscale("log")
    top.set_ylabel("mean width of the 95 % interval")
    bottom.set_ylabel("95 % coverage of the truth")
    bottom.set_xlabel("seconds per problem (median fit + sampling); labels: chain steps")
    top.set_title(
        f"Sampler length: {sampler['draws']} noise draws, {sampler['size']}x{sampler['size']} px", fontsize=10
    )
    for ax in (top, bottom):
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
        ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def make_plots(out: Path, evaluator, fits, sampler) -> list[str]:
    written = []
    if evaluator:
        floor = 1e-17
        colours = {"numpy": "k", "exact": "C2", "table": "C0", "j-table": "C3"}
        points = [
            {
                "x": r["median_ms"],
                "y": r["worst_material_max_error"] if r["worst_material_max_error"] is not None else r["max_error"],
                "label": r["label"].replace("float", "f"),
                "color": colours[r["mode"]],
            }
            for r in evaluator["rows"]
        ]
        extra = [
            {"x": r["median_ms"], "y": r["all_angle_max_error"], "color": colours[r["mode"]]}
            for r in evaluator["rows"]
            if r["all_angle_max_error"] is not None
        ]
        path = out / "pareto_evaluator.png"
        plot(
            path,
            "Evaluator: 256² render time vs max |error| against exact float64 (worst material)",
            points,
            "median ms per warm render() call",
            "max |error| (0 plotted at 1e-17)",
            floor=floor,
            annotate="filled: rendered sphere; hollow: all angles (bound). exact float64 is the reference (0)",
            extra=extra,
            extra_label="all-angle worst case",
        )
        written.append(path.name)
    if fits:
        floor = 1e-5
        for key, label, name in (
            ("resolution", lambda r: f"{r['size']} px", "pareto_resolution.png"),
            ("tolerance", lambda r: f"rtol {r['rtol']:g} / atol {r['atol']:g}", "pareto_tolerance.png"),
            ("starts", lambda r: f"{r['starts']} start(s)", "pareto_starts.png"),
        ):
            points = [
                {
                    "x": r["median_fit_s"],
                    "y": r["median_max_error"],
                    "label": f"{label(r)}, {r['within_0.02']:.0%} within 0.02",
                }
                for r in fits[key]
            ]
            path = out / name
            plot(
                path,
                f"Fits by {key}: warm fit time vs median parameter error",
                points,
                "median wall time per fit (s)",
                "median of the largest scored parameter error",
                floor=floor,
            )
            written.append(path.name)
    if sampler and sampler.get("rows"):
        path = out / "pareto_sampler.png"
        plot_sampler(path, sampler)
        written.append(path.name)
    return written


# --- report ----------------------------------------------------------------------------------------


def report(results: dict) -> str:
    parts = []
    ev = results.get("evaluator")
    if ev:
        rows = []
        for r in ev["rows"]:
            rows.append(
                [
                    r["label"],
                    fmt(r["median_ms"], 3),
                    fmt(r["min_ms"], 3),
                    fmt(r.get("ratio_to_exact_same_dtype")),
                    fmt(r["first_call_s"]),
                    fmt(r["working_mb"]),
                    fmt(r["table_mb"]),
                    fmt(r["max_error"]),
                    fmt(r["mean_error"]),
                    fmt(r["worst_material_max_error"]),
                    fmt(r["worst_material_mean_error"]),
                    fmt(r["all_angle_max_error"]),
                ]
            )
        parts.append(
            f"### Evaluator ({ev['image_size']}x{ev['image_size']} sphere, two lights + ambient, "
            f"median of {ev['repeats']} interleaved warm calls)\n\n"
            + markdown_table(
                [
                    "configuration",
                    "median ms",
                    "min ms",
                    "x exact (same dtype)",
                    "1st call s",
                    "working MB",
                    "table MB",
                    "max err",
                    "mean err",
                    "worst-material max err",
                    "worst-material mean err",
                    "all-angle max err",
                ],
                rows,
            )
            + "\n\nworking MB: XLA buffer assignment (temporary + output) of the compiled render; NumPy: "
            "tracemalloc peak. Errors: |image - exact float64| over the sphere, timed material "
            f"{ev['timed_material']}; worst material over {len(ev['materials_for_worst_case'])} materials "
            "(s in {0.3, 0.6, 0.9, 1}, m in {0, 1}, t in {0, 0.5}, white). all-angle: worst "
            "|shade - exact float64| over incidence and view angles 0-89.999° (viewer in and across the "
            "mirror plane) and 16 white materials (s in {0, 0.5, 0.9, 0.99}, m in {0, 1}, t in {0, 0.5}; "
            "s = 1 left out: its delta highlight at exactly mirrored directions is on or off by rounding), "
            "the evaluator's bound; a rendered sphere never reaches the grazing views where the tables err "
            "most."
        )
        parts.append("**Table modes:** " + results["table_mode_verdict"]["text"])
    fits = results.get("fits")
    if fits:
        for key, title, first in (
            ("resolution", "Image resolution", "px"),
            ("tolerance", f"Solver tolerance ({fits['reference_size']} px)", "rtol / atol"),
            ("starts", f"Number of starts ({fits['reference_size']} px)", "starts"),
        ):
            rows = []
            for r in fits[key]:
                name = {
                    "resolution": str(r["size"]),
                    "tolerance": f"{r['rtol']:g} / {r['atol']:g}",
                    "starts": str(r["starts"]),
                }[key]
                by = r["median_error_by_parameter"]
                colour = [v for k, v in by.items() if k.startswith("color") and v is not None]
                rows.append(
                    [
                        name,
                        str(r["pixels_used"]),
                        fmt(r["median_fit_s"], 3),
                        fmt(r["first_call_s"]),
                        fmt(r["working_mb"]),
                        f"{r['median_steps']:.0f}",
                        fmt(r["median_max_error"]),
                        fmt(r["p90_max_error"]),
                        f"{r['within_0.02']:.0%}",
                        fmt(max(colour) if colour else None),
                        fmt(by["smoothness"]),
                        fmt(by["metalness"]),
                        "yes" if r["all_finite"] else "NO",
                    ]
                )
            parts.append(
                f"### {title}\n\n"
                + markdown_table(
                    [
                        first,
                        "pixels",
                        "fit s (median, warm)",
                        "1st call s",
                        "working MB",
                        "steps",
                        "median max err",
                        "p90 max err",
                        f"within {WITHIN}",
                        "median err C",
                        "median err s",
                        "median err m",
                        "finite",
                    ],
                    rows,
                )
            )
        if results.get("bundled_check"):
            parts.append(
                "Each preset on the README's set-up fit (bundled `strauss-noisy-0000.exr`, truth "
                "s = 0.2825, every parameter decided by the library): "
                + "; ".join(
                    f"{c['preset']} with {c['starts']} start(s): RMS {c['rms']:.5g}, s = {c['smoothness']:.3g}"
                    for c in results["bundled_check"]
                )
                + "."
            )
        parts.append(
            f"Fits: {len(fits['materials'])} materials x {fits['draws_per_material']} noise draws each "
            f"({fits['noise']}); "
            "free (color, smoothness, metalness); errors over the parameters the image constrains (predicted "
            f"deviation <= {PREDICTED_SD_LIMIT} at the truth with all three free, {fits['reference_size']} px, "
            "degenerate directions counted as unconstrained): "
            + "; ".join(
                f"s={s['material']['smoothness']:g}, m={s['material']['metalness']:g}: "
                f"{', '.join(s['constrained']) or 'none'}"
                for s in fits["scored"]
            )
            + ". working MB: XLA buffers of the vectorised solve + the prepared problem arrays."
        )
    sm = results.get("sampler")
    if sm and sm.get("rows"):
        rows = []
        for r in sm["rows"]:
            rows.append(
                [
                    "Laplace (fit)" if r["kind"] == "laplace" else f"emcee {r['walkers']} walkers",
                    str(r["steps"]),
                    fmt(r["cost_s"], 3),
                    fmt(r["sampling_s"], 3),
                    fmt(r["width68_mean"]),
                    fmt(r["width95_mean"]),
                    f"{r['coverage68']:.0%}",
                    f"{r['coverage95']:.0%}",
                    fmt(r["tau_multiple_median"]),
                ]
            )
        status = "" if sm.get("status") == "measured" else f"**{sm.get('status')}**\n\n"
        parts.append(
            f"### Sampler length ({sm['size']}x{sm['size']} px, {sm['draws']} noise draws, "
            f"{len(LABELS)} parameters)\n\n"
            + status
            + markdown_table(
                [
                    "intervals from",
                    "steps",
                    "cost s",
                    "sampling s",
                    "68% width",
                    "95% width",
                    "68% coverage",
                    "95% coverage",
                    "steps / tau",
                ],
                rows,
            )
            + f"\n\nCoverage is over {sm['pairs_per_coverage']} (draw, parameter) pairs: its standard error "
            f"at 95 % is about {sm['coverage_standard_error_at_0.95']:.0%}."
            + (
                ""
                if sm.get("status") != "measured"
                else f" Chains: sigma {sm['sigma']}; burn-in the library's 2 tau (at most half the chain); median "
                f"max tau of the longest chains {sm['tau_max_median_longest_chain']:.0f} steps; "
                f"driven by {', '.join(sm['driver'])}."
            )
        )
    elif sm:
        parts.append(f"### Sampler length\n\n{sm.get('status')}")
    presets = results.get("presets")
    if presets:
        lines = [
            "### Recommended presets (derived from the curves above)",
            "",
            "```json",
            json.dumps(presets["presets"], indent=2),
            "```",
            "",
        ]
        for name, reasons in presets["justification"].items():
            lines.append(f"- **{name}**: " + "; ".join(reasons))
        parts.append("\n".join(lines))
    return "\n\n".join(parts) + "\n"


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer settings and repeats (smoke test, ~2 minutes)")
    parser.add_argument("--out", type=Path, default=HERE / "results" / "tradeoff", help="output folder")
    parser.add_argument(
        "--knobs",
        default="evaluator,fits,sampler",
        help="comma-separated subset of evaluator,fits,sampler (default: all)",
    )
    args = parser.parse_args(argv)
    knobs = set(args.knobs.split(","))
    args.out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    info = machine_info()
    print(f"strauss-fit speed/accuracy trade-offs{' (quick)' if args.quick else ''}", flush=True)
    results: dict = {
        "benchmark": "tradeoff",
        "quick": args.quick,
        "timestamp": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "machine": info,
        "timings_s": {},
    }
    evaluator = fits = sampler = None
    if "evaluator" in knobs:
        t0 = time.perf_counter()
        evaluator = results["evaluator"] = knob_evaluator(args.quick)
        results["table_mode_verdict"] = table_mode_verdict(evaluator)
        results["timings_s"]["evaluator"] = time.perf_counter() - t0
        print(f"evaluator done in {results['timings_s']['evaluator']:.0f} s", flush=True)
    if "fits" in knobs:
        t0 = time.perf_counter()
        fits = results["fits"] = knob_fits(args.quick)
        results["timings_s"]["fits"] = time.perf_counter() - t0
        print(f"fits done in {results['timings_s']['fits']:.0f} s", flush=True)
    if "sampler" in knobs:
        t0 = time.perf_counter()
        sampler = results["sampler"] = knob_sampler(args.quick)
        results["timings_s"]["sampler"] = time.perf_counter() - t0
        print(f"sampler done in {results['timings_s']['sampler']:.0f} s", flush=True)
    results["presets"] = derive_presets(evaluator, fits, sampler)
    if fits:
        results["bundled_check"] = check_presets_on_bundled(results["presets"])
    results["plots"] = make_plots(args.out, evaluator, fits, sampler)
    info["load_average_after"] = os.getloadavg()
    info["peak_rss_mb"] = peak_rss_mb()
    results["timings_s"]["total"] = time.perf_counter() - started
    text = report(results)
    print()
    print(text)
    (args.out / "tradeoff.md").write_text(text)
    write_json(args.out / "tradeoff.json", results)
    print(
        f"wrote {args.out / 'tradeoff.json'}, {args.out / 'tradeoff.md'} and {', '.join(results['plots'])} "
        f"in {results['timings_s']['total']:.0f} s"
    )
    return results


if __name__ == "__main__":
    with sf.float64():  # all of it in float64 (importing strauss_fit no longer switches it on)
        main()
