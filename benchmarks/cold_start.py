"""Start-up cost of one command-line fit: cold, cached and warm.

    .venv/bin/python benchmarks/cold_start.py [--repeats 2] [--json PATH]

Runs the README's single-target fit (``strauss-fit fit
data_synth/bundled/strauss-noisy-0000.exr --scene data_synth/scenes/two_lights.toml -o
fit.json --render-fit fit.png --force``), each time in a new Python process with a fresh
``HOME`` (a temporary folder, so that the compilation cache and the traced kernels beside
it start empty, in their default place ``~/.cache/strauss-fit``) and a fresh copy of
strauss-fit's sources there (first on ``PYTHONPATH``, without bytecode: the cold run
compiles it, as a new checkout's first command does; the installed libraries' bytecode
is used as pip wrote it). The process ends the way the ``strauss-fit`` process does
(`strauss_fit_cli.interrupts.leave_process`):

- **cold**: the first run, with the caches empty;
- **cached**: a new process with the caches the cold run left (what every later command
  costs);
- **warm**: the same fit again inside that cached process (what a script calling
  :func:`strauss_fit_cli.main.main` twice, or a notebook, pays).

Each row: the process's wall time (from the parent: the interpreter's start, the imports,
the fit, the exit), the imports (JAX, :mod:`strauss_fit` and the command's modules), the
command itself, JAX's counts of jaxprs traced, of programs compiled (XLA, not found in
the persistent cache) and found in that cache, and the files the run added to the two
caches (compiled programs; traced and lowered kernels, :mod:`strauss_fit.export_cache`).
Counts come from :mod:`jax.monitoring` events. A cached run that added kept kernels is
flagged: the sources changed after its cold run (see :mod:`strauss_fit.export_cache`). The machine line
(:func:`bench_common.machine`: calibration and load) is printed first. Results: a table
on stdout and JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

ROOT = Path(__file__).resolve().parents[1]
#: The README's example: one bundled noisy Strauss target, the two-lights scene.
README_ARGS = [
    "fit",
    str(ROOT / "data_synth" / "bundled" / "strauss-noisy-0000.exr"),
    "--scene",
    str(ROOT / "data_synth" / "scenes" / "two_lights.toml"),
    "-o",
    "fit.json",
    "--render-fit",
    "fit.png",
    "--force",
]
#: JAX's monitoring events counted (jax/_src/dispatch.py, compiler.py).
TRACE_EVENT = "/jax/core/compile/jaxpr_trace_duration"
CACHE_HIT_EVENT = "/jax/compilation_cache/cache_hits"
CACHE_MISS_EVENT = "/jax/compilation_cache/cache_misses"
BACKEND_COMPILE_EVENT = "/jax/core/compile/backend_compile_duration"


def probe(stats_path: Path, calls: int) -> None:
    """Inside a fresh process: time the imports, register JAX's event listeners, run the
    command ``calls`` times (the first in a new process, the rest warm) and write what each
    call cost to ``stats_path`` (JSON)."""
    started = time.perf_counter()
    import jax

    import strauss_fit  # noqa: F401
    import strauss_fit_cli.fit_cmd  # noqa: F401
    import strauss_fit_cli.main as cli

    imported = time.perf_counter() - started
    counts: dict[str, int] = {}
    seconds: dict[str, float] = {}

    def on_event(event: str, **_: object) -> None:
        counts[event] = counts.get(event, 0) + 1

    def on_duration(event: str, duration: float, **_: object) -> None:
        counts[event] = counts.get(event, 0) + 1
        seconds[event] = seconds.get(event, 0.0) + duration

    assert Path(strauss_fit.__file__).is_relative_to(Path.home()), "not the fresh copy of the sources"
    jax.monitoring.register_event_listener(on_event)
    jax.monitoring.register_event_duration_secs_listener(on_duration)
    rows = []
    for _ in range(calls):
        counts.clear()
        seconds.clear()
        before = _cache_files()
        began = time.perf_counter()
        code = cli.main(list(README_ARGS))
        elapsed = time.perf_counter() - began
        after = _cache_files()
        rows.append(
            {
                "exit_code": code,
                "command_s": elapsed,
                "traces": counts.get(TRACE_EVENT, 0),
                "trace_s": seconds.get(TRACE_EVENT, 0.0),
                "compiled": counts.get(CACHE_MISS_EVENT, 0),
                "compile_s": seconds.get(BACKEND_COMPILE_EVENT, 0.0),
                "cache_hits": counts.get(CACHE_HIT_EVENT, 0),
                "added_compiled": after["compiled"] - before["compiled"],
                "added_exported": after["exported"] - before["exported"],
            }
        )
    stats_path.write_text(json.dumps({"import_s": imported, "calls": rows}))
    from strauss_fit_cli.interrupts import leave_process

    leave_process(0)  # as the strauss-fit process ends (its wall time as the parent sees it)


def _cache_files() -> dict[str, int]:
    """Files in the compilation cache and in the exported kernels' folder beside it."""
    base = Path.home() / ".cache" / "strauss-fit"
    return {
        "compiled": sum(1 for p in (base / "jax").glob("*") if p.is_file()),
        "exported": sum(1 for p in (base / "jax-export").glob("*.pkl")),
    }


def run_process(home: Path, work: Path, calls: int) -> dict:
    """One fresh process (``HOME=home``, run in ``work``) that probes ``calls`` fits; its
    wall time as the parent sees it, and the probe's figures."""
    stats = work / "stats.json"
    environment = {k: v for k, v in os.environ.items() if not k.startswith(("STRAUSS_FIT_", "JAX_", "XLA_"))}
    environment["HOME"] = str(home)
    # the copy of the sources in that HOME, before the editable install's: the cold run
    # compiles their bytecode as a fresh clone's first command does, later runs reuse it
    # (whatever PYTHONDONTWRITEBYTECODE says here)
    environment.pop("PYTHONDONTWRITEBYTECODE", None)
    environment.pop("PYTHONPYCACHEPREFIX", None)
    environment["PYTHONPATH"] = os.pathsep.join(filter(None, [str(home / "src"), environment.get("PYTHONPATH")]))
    command = [sys.executable, str(Path(__file__).resolve()), "--probe", str(stats), "--calls", str(calls)]
    began = time.perf_counter()
    finished = subprocess.run(command, cwd=work, env=environment, capture_output=True, text=True)
    wall = time.perf_counter() - began
    if finished.returncode != 0:
        raise SystemExit(f"the probe failed (status {finished.returncode}): {finished.stderr.strip()[-2000:]}")
    figures = json.loads(stats.read_text())
    if any(call["exit_code"] != 0 for call in figures["calls"]):
        raise SystemExit(f"strauss-fit fit failed in the probe: {finished.stderr.strip()[-2000:]}")
    return {"wall_s": wall, **figures}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=2, help="cold and cached runs (each in a fresh HOME)")
    parser.add_argument("--json", default=str(ROOT / "benchmarks" / "results" / "cold_start.json"))
    parser.add_argument("--probe", help=argparse.SUPPRESS)
    parser.add_argument("--calls", type=int, default=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.probe:
        probe(Path(args.probe), args.calls)
        return

    from bench_common import describe, machine, write_json

    info = machine(print_it=False)
    print(describe(info))
    rows: dict[str, list[dict]] = {"cold": [], "cached": [], "warm": []}
    for _ in range(args.repeats):
        home = Path(tempfile.mkdtemp(prefix="cold-start-home-"))
        try:
            work = home / "work"
            work.mkdir()
            fresh = shutil.ignore_patterns("__pycache__")
            shutil.copytree(ROOT / "strauss_fit", home / "src" / "strauss_fit", ignore=fresh)
            shutil.copytree(ROOT / "cli", home / "src" / "strauss_fit_cli", ignore=fresh)
            cold = run_process(home, work, calls=1)
            cached = run_process(home, work, calls=2)
        finally:
            shutil.rmtree(home, ignore_errors=True)
        first, again = cached["calls"]
        rows["cold"].append({"wall_s": cold["wall_s"], "import_s": cold["import_s"], **cold["calls"][0]})
        rows["cached"].append({"wall_s": cached["wall_s"], "import_s": cached["import_s"], **first})
        rows["warm"].append({"wall_s": None, "import_s": None, **again})

    print(f"the README's single-target CLI fit, median of {args.repeats} (each in a fresh HOME)")
    header = (
        f"{'run':8s} {'wall s':>7s} {'import s':>8s} {'fit s':>7s} {'traces':>7s} {'trace s':>7s} "
        f"{'compiled':>8s} {'compile s':>9s} {'cache hits':>10s} {'+cache':>7s} {'+export':>7s}"
    )
    print(header)
    summary = {}
    for name, runs in rows.items():

        def median(key: str, runs: list[dict] = runs) -> float | None:
            values = [run[key] for run in runs if run[key] is not None]
            return statistics.median(values) if values else None

        row = {key: median(key) for key in runs[0] if key != "exit_code"}
        summary[name] = row
        wall = "-" if row["wall_s"] is None else f"{row['wall_s']:.2f}"
        imported = "-" if row["import_s"] is None else f"{row['import_s']:.2f}"
        print(
            f"{name:8s} {wall:>7s} {imported:>8s} {row['command_s']:7.2f} {row['traces']:7.0f} "
            f"{row['trace_s']:7.2f} {row['compiled']:8.0f} {row['compile_s']:9.2f} {row['cache_hits']:10.0f} "
            f"{row['added_compiled']:7.0f} {row['added_exported']:7.0f}"
        )
    stale = sum(1 for run in rows["cached"] if run["added_exported"])
    if stale:
        # the kept kernels' key holds a hash of strauss_fit's sources: an edit between the
        # cold and the cached run (another checkout's work in a shared tree) traces them again
        print(
            f"note: {stale} of {args.repeats} cached run(s) traced and kept kernels again: strauss_fit's sources "
            "changed after their cold run, which changes the kept kernels' key; their figures are not a cached run's"
        )
    write_json(args.json, {"machine": info, "command": ["strauss-fit", *README_ARGS], "summary": summary, "runs": rows})


if __name__ == "__main__":
    main()
