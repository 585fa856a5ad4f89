"""Keeping a long-running process healthy while it compiles many JAX programs.

XLA:CPU maps the machine code of every compiled program into memory separately, a few
hundred mappings per configuration of a fit (scene structure, free parameters, loss,
render plan). A process that fits many *different* configurations — a benchmark over
every loss and scene, a batch of targets from many scenes — therefore approaches the
kernel's limit on memory mappings per process (``vm.max_map_count``, 65 530 by default)
and then dies inside LLVM ("Cannot allocate memory", then a segmentation fault) with
gigabytes of memory free. Measured here: about 700 mappings per configuration, so about
90 configurations per process.

:func:`release_compiled_code_if_needed` is called before every fit: past
:data:`MAP_FRACTION` of the limit it clears JAX's caches (the programs are compiled again
when next needed, which costs time, never correctness). Where ``/proc`` does not exist it
does nothing.
"""

from __future__ import annotations

from pathlib import Path

#: Clear JAX's caches once the process holds this fraction of the mapping limit.
MAP_FRACTION = 0.5
_MAPS = Path("/proc/self/maps")
_LIMIT = Path("/proc/sys/vm/max_map_count")


def mapping_usage() -> tuple[int, int] | None:
    """(memory mappings of this process, the kernel's limit), or None where unknown."""
    try:
        with _MAPS.open("rb") as maps:
            count = sum(1 for _ in maps)
        limit = int(_LIMIT.read_text().strip())
    except (OSError, ValueError):
        return None
    return count, limit


def release_compiled_code_if_needed(fraction: float = MAP_FRACTION) -> bool:
    """Clear JAX's compilation caches when this process's memory mappings exceed
    ``fraction`` of the kernel's limit; return whether it did."""
    usage = mapping_usage()
    if usage is None or usage[0] <= fraction * usage[1]:
        return False
    import gc

    import jax

    jax.clear_caches()
    gc.collect()
    return True
