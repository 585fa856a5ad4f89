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
