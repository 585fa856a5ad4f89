"""JAX's runtime: the persistent compilation cache, and keeping a long-running process
healthy while it compiles many programs.

The compilation cache (`enable_compilation_cache`): compiled XLA programs are kept
on disk (``~/.cache/strauss-fit/jax``; ``STRAUSS_FIT_CACHE_DIR=PATH`` moves it,
``STRAUSS_FIT_CACHE_DIR=off`` turns it off), so that a new process — the next
``strauss-fit`` command, a Dask worker — loads them instead of compiling again. Every
program is kept, however quick to compile: a fit compiles a few hundred small ones, which
together cost a second in every new process.

Compiled code and memory mappings:

XLA:CPU maps the machine code of every compiled program into memory separately, a few
hundred mappings per configuration of a fit (scene structure, free parameters, loss,
render plan). A process that fits many *different* configurations — a benchmark over
every loss and scene, a batch of targets from many scenes — therefore approaches the
kernel's limit on memory mappings per process (``vm.max_map_count``, 65 530 by default)
and then dies inside LLVM ("Cannot allocate memory", then a segmentation fault) with
gigabytes of memory free. Measured here: about 700 mappings per configuration, so about
90 configurations per process.

`release_compiled_code_if_needed` is called before every fit (and looks at the mappings
at most once a second, `CHECK_INTERVAL_S`): past
`MAP_FRACTION` of the limit it clears JAX's caches (the programs are compiled again
when next needed, which costs time, never correctness). Where ``/proc`` does not exist it
does nothing.

CPU devices (`use_cpu_cores`): XLA:CPU runs the work of one device in order, on
one core for the small programs of a fit, and a small eager operation waits for the
program before it. Where JAX has several CPU devices the compiled kernels
(`strauss_fit.engine`) therefore run on a device other than the first, which is left
to the eager operations of the fits' Python — a single fit's kernels as a batch's, so that
both share their programs (`strauss_fit.engine.compute_device`: a program belongs to
its device, in memory and in the compilation cache) — and a large batch on several of them
where there are cores to spare. JAX's CPU device count is the process's, so the package
never changes it on import: the ``strauss-fit`` command asks for one device per usable core
(at most eight) and one more when it starts, and so does the first batch
(`strauss_fit.fit_many`) of a process whose JAX has not run anything yet. In a
program of your own, call `use_cpu_cores` right after importing the package (before
any JAX work) for the same; without it everything runs on JAX's one default CPU device,
with the same results, batches slower. A count you chose (``JAX_NUM_CPU_DEVICES``,
``XLA_FLAGS``' host device count, ``jax.config``'s ``jax_num_cpu_devices``) is kept.

Freed memory (`keep_freed_memory`): XLA:CPU allocates every buffer of a program anew at
each call and frees it after, through the C library's ``malloc``. glibc gives blocks of a few
megabytes (a 256² fit's Jacobian is 6.6 MB) fresh pages from the kernel and hands them back
when freed, so every call of a kernel pays a page fault per 4 KiB it touches: the noise
sandwich of a 256² fit spent half its time there (23 against 12 ms, 2026-12-05; NumPy's own
large temporaries pay the same). `keep_freed_memory` sets glibc's thresholds
(``mallopt``) so that blocks under `MMAP_THRESHOLD` (64 MiB; 32 MiB on a glibc before 2.35,
which refuses more) come from the heap and up to
`TRIM_THRESHOLD` of freed memory stays with the process for the next call. The fitting
functions (`strauss_fit.fit`, `strauss_fit.fit_many`, folders and captures) and the command
line call it once per process; the cost is memory the process keeps (at most
`TRIM_THRESHOLD` beyond what it uses, per allocator arena). It does nothing where the C
library is not glibc, where ``STRAUSS_FIT_KEEP_FREED_MEMORY=off``, or where the process's
allocator was tuned already (``MALLOC_MMAP_THRESHOLD_``, ``MALLOC_TRIM_THRESHOLD_``,
``MALLOC_TOP_PAD_`` or ``MALLOC_MMAP_MAX_`` set, or ``GLIBC_TUNABLES`` naming
``glibc.malloc``): yours are kept.
"""

from __future__ import annotations

import ctypes
import os
import sys
import time
from pathlib import Path

from ._environment import turned_off

#: Clear JAX's caches once the process holds this fraction of the mapping limit.
MAP_FRACTION = 0.5
#: Seconds between two looks at the mappings. Why not at every fit: the kernel takes about
#: 2 ms to list a JAX process's 1,500 mappings, 5 % of a 64² fit; and a second of fits cannot
#: approach the limit (a new configuration adds about 700 mappings, and compiling it takes
#: seconds), with half of the limit kept in reserve (`MAP_FRACTION`).
CHECK_INTERVAL_S = 1.0
_last_check = -float("inf")
_MAPS = Path("/proc/self/maps")
_LIMIT = Path("/proc/sys/vm/max_map_count")


#: CPU devices for batches at most (`use_cpu_cores`): a batch of 64 fits uses at most
#: four (`strauss_fit.engine.ITEMS_PER_DEVICE`), and each device holds its own programs.
MAX_COMPUTE_DEVICES = 8


def usable_cores() -> int:
    """The CPU cores this process may run on (its affinity mask where known)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def use_cpu_cores() -> bool:
    """Ask JAX for one CPU device per usable core (at most `MAX_COMPUTE_DEVICES`)
    and one more (see the module docstring), unless a count was chosen
    (``JAX_NUM_CPU_DEVICES``, ``XLA_FLAGS``' host device count, ``jax_num_cpu_devices``) or
    JAX already ran something (the count cannot change then). True when the count was set.

    Before JAX is imported, through ``JAX_NUM_CPU_DEVICES`` in this process's environment
    (JAX reads it on import; the processes it starts, local Dask workers for one, inherit
    it): the command line's way, which keeps ``--help`` and its errors from importing JAX.
    After, through ``jax.config`` (public), which JAX accepts only before its backends
    start: it refuses later with a ``RuntimeError``, here "too late, keep what there is"."""
    if "JAX_NUM_CPU_DEVICES" in os.environ or "xla_force_host_platform_device_count" in os.environ.get("XLA_FLAGS", ""):
        return False
    devices = min(usable_cores(), MAX_COMPUTE_DEVICES) + 1
    jax = sys.modules.get("jax")
    if jax is None:
        os.environ["JAX_NUM_CPU_DEVICES"] = str(devices)
        return True
    if jax.config.jax_num_cpu_devices != -1:  # chosen through jax.config already
        return False
    try:
        jax.config.update("jax_num_cpu_devices", devices)
    except RuntimeError:  # JAX's backends are running: batches use the devices there are
        return False
    return True


#: Blocks under this many bytes come from the heap once `keep_freed_memory` ran (glibc's
#: own threshold moves between 128 KiB and 32 MiB as blocks are freed). Not 32 MiB: a 256²
#: fit's noise sandwich has a 33 MB temporary, and with 32 MiB it took 22-23 ms, not 14-15.
MMAP_THRESHOLD = 64 * 2**20
#: What a glibc before 2.35 accepts at most (it refuses `MMAP_THRESHOLD`).
_OLD_GLIBC_MMAP_THRESHOLD = 32 * 2**20
#: Freed memory at the top of a heap the process keeps, in bytes, once `keep_freed_memory` ran.
TRIM_THRESHOLD = 256 * 2**20
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # mallopt's parameter numbers (glibc's malloc.h)
#: The environment settings by which glibc's allocator is tuned at a process's start.
_ALLOCATOR_SETTINGS = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_TOP_PAD_", "MALLOC_MMAP_MAX_")
_kept_freed_memory: bool | None = None


def keep_freed_memory() -> bool:
    """Set glibc's allocator to keep freed memory for the next call (see the module
    docstring), once per process; whether it is set. Nothing where the C library is not
    glibc, where ``STRAUSS_FIT_KEEP_FREED_MEMORY=off``, or where the allocator was tuned
    through the environment already."""
    global _kept_freed_memory
    if _kept_freed_memory is None:
        _kept_freed_memory = _set_allocator_thresholds()
    return _kept_freed_memory


def _set_allocator_thresholds() -> bool:
    if turned_off(os.environ.get("STRAUSS_FIT_KEEP_FREED_MEMORY")):
        return False
    if any(name in os.environ for name in _ALLOCATOR_SETTINGS) or "glibc.malloc." in os.environ.get(
        "GLIBC_TUNABLES", ""
    ):
        return False
    try:
        if not os.confstr("CS_GNU_LIBC_VERSION").startswith("glibc"):
            return False
        mallopt = ctypes.CDLL(None).mallopt  # the process's own C library
    except (AttributeError, OSError, ValueError, TypeError):  # not glibc, not Unix
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    # both, each on its own (setting either ends glibc's moving thresholds, mallopt(3))
    mapped = mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD) or mallopt(_M_MMAP_THRESHOLD, _OLD_GLIBC_MMAP_THRESHOLD)
    trimmed = mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD)
    return bool(mapped) and bool(trimmed)


def cache_folder() -> Path | None:
    """The persistent compilation cache's folder, or None when it is turned off."""
    setting = os.environ.get("STRAUSS_FIT_CACHE_DIR")
    if turned_off(setting):
        return None
    return Path(setting) if setting else Path.home() / ".cache" / "strauss-fit" / "jax"


def enable_compilation_cache() -> Path | None:
    """Turn on JAX's persistent compilation cache in `cache_folder` (see the module
    docstring); returns the folder, or None (turned off, or not writable: it only costs
    time)."""
    folder = cache_folder()
    if folder is None:
        return None
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    import jax

    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    # beside it, the kernels' traced and lowered programs (jax.export): <folder>-export,
    # STRAUSS_FIT_EXPORT_CACHE=off turns that one off (strauss_fit.export_cache)
    from .export_cache import configure

    configure(folder)
    return folder


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation (Linux's ``MemAvailable``), or None
    where unknown."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def mapping_usage() -> tuple[int, int] | None:
    """(memory mappings of this process, the kernel's limit), or None where unknown."""
    try:
        count = _MAPS.read_bytes().count(b"\n")  # one line per mapping
        limit = int(_LIMIT.read_text().strip())
    except (OSError, ValueError):
        return None
    return count, limit


def release_compiled_code_if_needed(fraction: float = MAP_FRACTION, min_interval: float = CHECK_INTERVAL_S) -> bool:
    """Clear JAX's compilation caches when this process's memory mappings exceed
    ``fraction`` of the kernel's limit; return whether it did. Looks at most once per
    ``min_interval`` seconds (`CHECK_INTERVAL_S`)."""
    global _last_check
    now = time.monotonic()
    if now - _last_check < min_interval:
        return False
    _last_check = now
    usage = mapping_usage()
    if usage is None or usage[0] <= fraction * usage[1]:
        return False
    import gc

    import jax

    jax.clear_caches()
    gc.collect()
    return True
