"""The process-level guards of strauss_fit.runtime: counting this process's memory
mappings, and clearing JAX's caches past a fraction of the kernel's limit."""

from __future__ import annotations

import mmap
from pathlib import Path

import pytest

from strauss_fit import runtime

pytestmark = pytest.mark.skipif(not Path("/proc/self/maps").exists(), reason="needs Linux's /proc")


def test_mapping_usage_counts_this_processs_mappings_and_reads_the_limit():
    lines = Path("/proc/self/maps").read_text().splitlines()
    count, limit = runtime.mapping_usage()
    assert abs(count - len(lines)) <= 2  # the two reads may see a mapping come or go
    assert limit == int(Path("/proc/sys/vm/max_map_count").read_text())
    # a new anonymous mapping with its own protection cannot merge with a neighbour: one more
    region = mmap.mmap(-1, 4 * mmap.PAGESIZE, prot=mmap.PROT_READ)
    try:
        assert runtime.mapping_usage()[0] >= count + 1
    finally:
        region.close()


def test_caches_are_cleared_only_past_the_fraction(monkeypatch):
    cleared = []
    monkeypatch.setattr("jax.clear_caches", lambda: cleared.append(True))
    count, limit = runtime.mapping_usage()
    assert runtime.release_compiled_code_if_needed((count + 10) / limit, min_interval=0.0) is False
    assert cleared == []
    assert runtime.release_compiled_code_if_needed((count - 10) / limit, min_interval=0.0) is True
    assert cleared == [True]


def test_the_mappings_are_looked_at_once_per_interval(monkeypatch):
    cleared, looked = [], []
    monkeypatch.setattr("jax.clear_caches", lambda: cleared.append(True))
    monkeypatch.setattr(runtime, "mapping_usage", lambda: looked.append(True) or (10, 20))
    now = [100.0]
    monkeypatch.setattr(runtime.time, "monotonic", lambda: now[0])
    monkeypatch.setattr(runtime, "_last_check", -float("inf"))
    assert runtime.release_compiled_code_if_needed(0.1, min_interval=1.0) is True
    now[0] += 0.5
    assert runtime.release_compiled_code_if_needed(0.1, min_interval=1.0) is False  # too soon: not looked at
    assert len(looked) == 1
    now[0] += 0.6
    assert runtime.release_compiled_code_if_needed(0.1, min_interval=1.0) is True
    assert len(looked) == 2 and cleared == [True, True]


def test_without_proc_nothing_is_counted_or_cleared(monkeypatch, tmp_path):
    monkeypatch.setattr(runtime, "_MAPS", tmp_path / "missing")
    assert runtime.mapping_usage() is None
    assert runtime.release_compiled_code_if_needed(fraction=0.0, min_interval=0.0) is False


_FREED_MEMORY_PROBE = """
import ctypes, os, sys
from strauss_fit import runtime
kept = runtime.keep_freed_memory()
libc = ctypes.CDLL(None)
libc.malloc.restype = ctypes.c_void_p
libc.malloc.argtypes = (ctypes.c_size_t,)
libc.free.argtypes = (ctypes.c_void_p,)
def resident():
    return int(open("/proc/self/statm").read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
size = 24 * 2**20  # over glibc's first threshold (128 KiB): mapped and unmapped by default
before = resident()
block = libc.malloc(size)
ctypes.memset(block, 1, size)
libc.free(block)
print(kept, (resident() - before) / size)
"""


def _freed_memory_probe(**settings: str) -> tuple[str, float]:
    """In a new process (the allocator's settings are the process's): whether
    `keep_freed_memory` set them, and how much of a 24 MiB block, written and freed, the
    process still holds (in blocks)."""
    import os
    import subprocess
    import sys

    environment = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_") and k != "GLIBC_TUNABLES"}
    environment.pop("STRAUSS_FIT_KEEP_FREED_MEMORY", None)
    done = subprocess.run(
        [sys.executable, "-c", _FREED_MEMORY_PROBE],
        env={**environment, **settings},
        capture_output=True,
        text=True,
        check=True,
    )
    kept, held = done.stdout.split()
    return kept, float(held)


@pytest.mark.skipif(
    not (hasattr(runtime.os, "confstr") and (runtime.os.confstr("CS_GNU_LIBC_VERSION") or "").startswith("glibc")),
    reason="glibc's allocator",
)
def test_keep_freed_memory_keeps_a_freed_block_for_the_next_call_and_leaves_a_tuned_allocator_alone():
    kept, held = _freed_memory_probe()
    assert kept == "True" and held > 0.9  # written, freed and still the process's: no new page faults
    kept, held = _freed_memory_probe(STRAUSS_FIT_KEEP_FREED_MEMORY="off")
    assert kept == "False" and held < 0.1  # glibc's default: handed back at once
    kept, held = _freed_memory_probe(MALLOC_TOP_PAD_="0")  # the user's own tuning is kept
    assert kept == "False" and held < 0.1
