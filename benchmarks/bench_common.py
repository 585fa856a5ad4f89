"""What the benchmarks share (a library, not a benchmark): the fit settings they were
calibrated with, the scene file most of them use, the machine's description with its
calibration (:func:`machine`), and the JSON writer (:func:`write_json`).

``LEGACY_FIT`` holds the settings that were ``FitOptions()``'s defaults until they became
the ``balanced`` preset (4 starts, 100 polish steps, rtol 1e-6, atol 1e-8); the benchmarks
pass them explicitly, so that their numbers stay comparable with the tables in docs/benchmarks.md.
"""

from __future__ import annotations

import datetime
import os
import platform
import time
import tomllib
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

import strauss_fit as sf
from strauss_fit.io.files import write_json as _write_json

# the CPU devices the command line runs on (strauss_fit.runtime.use_cpu_cores): every benchmark
# imports this module before any JAX work, so that it measures what `strauss-fit` does
sf.use_cpu_cores()
# and its allocator setting (strauss_fit.runtime.keep_freed_memory), for SciPy and NumPy as for JAX
sf.keep_freed_memory()

ROOT = Path(__file__).resolve().parents[1]
#: Two directional lights (a key and a fill) and ambient light over black.
KEY_AND_FILL = ROOT / "data_synth" / "scenes" / "key_and_fill.toml"
#: ``FitOptions()``'s defaults before they became the balanced preset.
LEGACY_FIT = dict(starts=4, max_steps=100, rtol=1e-6, atol=1e-8)


def legacy_options(**fields: Any) -> sf.FitOptions:
    """:class:`strauss_fit.FitOptions` with :data:`LEGACY_FIT` and ``fields``."""
    return sf.FitOptions(**{**LEGACY_FIT, **fields})


def key_and_fill_scene(
    size: int,
    *,
    material: dict[str, Any] | None = None,
    background: dict[str, Any] | None = None,
    depth: int | None = None,
    source: str = "benchmark",
) -> sf.Scene:
    """``key_and_fill.toml`` at ``size`` × ``size`` pixels, with its ``[material]``
    replaced and a ``[background]`` and ``[render] depth`` added when given."""
    data = tomllib.loads(KEY_AND_FILL.read_text())
    data["camera"].update(width=size, height=size)
    if material is not None:
        data["material"] = dict(material)
    if background is not None:
        data["background"] = dict(background)
    if depth is not None:
        data["render"] = {"depth": depth}
    return sf.parse_scene(data, source=source)


#: How often each calibration workload runs; the fastest run is quoted (the least disturbed
#: by other work on the machine).
CALIBRATION_REPEATS = 9
#: Elements of the calibration workloads' arrays (float64, 8 MB each).
CALIBRATION_SIZE = 1 << 20


def _numpy_workload(x: np.ndarray) -> float:
    """A fixed NumPy workload of the kind the NumPy reference renderer does: element-wise
    transcendental functions over a megapixel, a reduction, and a 256² matrix product."""
    y = np.exp(-3.0 * x) * np.cos(7.0 * x) + np.sqrt(x + 1.0) ** 1.7
    square = y[: 256 * 256].reshape(256, 256)
    return float(y.sum() + (square @ square).trace())


@jax.jit
def _jax_workload(x: jax.Array) -> jax.Array:
    """The same arithmetic as :func:`_numpy_workload`, compiled by XLA."""
    y = jnp.exp(-3.0 * x) * jnp.cos(7.0 * x) + jnp.sqrt(x + 1.0) ** 1.7
    square = y[: 256 * 256].reshape(256, 256)
    return y.sum() + (square @ square).trace()


def _fastest_ms(run: Any) -> float:
    run()  # warm: compiled, caches filled
    times = []
    for _ in range(CALIBRATION_REPEATS):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return 1e3 * min(times)


def calibration() -> dict[str, Any]:
    """The machine's speed on two fixed workloads, timed now, in this process: NumPy's and
    JAX's (the same float64 arithmetic, :func:`_numpy_workload`), each the fastest of
    :data:`CALIBRATION_REPEATS` warm runs in milliseconds, with the load average at the time.
    Printed first by every benchmark and stored in its JSON, so that a figure measured on
    another machine (or the same one, busier) can be compared: divide it by the ratio of the
    two machines' calibrations, or compare ratios measured in one run, which need none."""
    x = np.linspace(0.0, 1.0, CALIBRATION_SIZE)
    x_device = jnp.asarray(x)
    load = os.getloadavg() if hasattr(os, "getloadavg") else None
    return {
        "numpy_ms": round(_fastest_ms(lambda: _numpy_workload(x)), 3),
        "jax_ms": round(_fastest_ms(lambda: _jax_workload(x_device).block_until_ready()), 3),
        "workload": f"exp, cos, sqrt, pow over {CALIBRATION_SIZE} float64 values, a sum and a 256² matrix product",
        "load_average": None if load is None else [round(v, 2) for v in load],
    }


def _processor() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine(print_it: bool = True) -> dict[str, Any]:
    """What a benchmark's JSON says about where it ran: the date, the processor, the cores,
    Python, JAX and its backend, and the :func:`calibration` (timed now). With ``print_it``
    it is printed as the benchmark's first line."""
    with sf.float64():  # the workloads are float64 in both libraries
        calibrated = calibration()
    info = {
        "date": datetime.date.today().isoformat(),
        "processor": _processor(),
        "cpus": os.cpu_count(),
        "usable_cpus": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "jax": jax.__version__,
        "backend": jax.default_backend(),
        "calibration": calibrated,
    }
    if print_it:
        print(describe(info))
    return info


def describe(info: dict[str, Any]) -> str:
    """One line for :func:`machine`'s ``info``."""
    c = info["calibration"]
    load = "?" if c["load_average"] is None else f"{c['load_average'][0]:.2f}"
    return (
        f"{info['date']}, {info['processor']}, {info['usable_cpus']} cores, JAX {info['jax']} on "
        f"{info['backend']}; calibration: NumPy {c['numpy_ms']:.1f} ms, JAX {c['jax_ms']:.1f} ms "
        f"(fastest of {CALIBRATION_REPEATS}), load {load}"
    )


def jsonable(value: Any) -> Any:
    """``value`` with what JSON cannot hold made plain: NumPy and JAX scalars and arrays as
    numbers and lists, tuples as lists, and NaN and infinities (a median of nothing, a ratio
    to zero) as ``null``, which every JSON reader accepts (Python's own ``NaN`` is not JSON)."""
    if isinstance(value, dict):
        return {str(key): jsonable(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(item) for item in value]
    if isinstance(value, (np.ndarray, jax.Array)):
        return jsonable(np.asarray(value).tolist())
    if isinstance(value, np.generic):
        return jsonable(value.item())
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def write_json(path: str | Path, payload: Any) -> Path:
    """Write a benchmark's JSON atomically (its folder made, an older file replaced), every
    write checked (:func:`strauss_fit.io.files.write_json`), the payload made
    :func:`jsonable` first, and say where."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    written = _write_json(path, jsonable(payload), force=True)
    print(f"wrote {written}")
    return written
