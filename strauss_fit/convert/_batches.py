"""The batch driver both conversion directions run on.

A direction (`Direction`) says how an entry becomes an item and which steps convert
an item; `stream` prepares the entries one by one, converts them a chunk at a time
(their kernel calls batched by `strauss_fit.engine.run_batched`) and yields the
results in input order. A material that fails is an error result and the batch goes on.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

from ..engine import Steps, run_batched
from ..io.material_tables import Entry
from ._shared import error_result, message_of

#: A progress callback: ``(done, total, message)`` after every finished material.
Progress = Callable[[int, int, str], None]


@dataclass
class Direction:
    """One direction of the conversion for the generic chunk driver (`stream`): how
    an item is made from an entry (``prepare``, raises for a bad material) and the steps
    that convert it (``steps``: a generator of `strauss_fit.engine.Call`, returning
    the result dict)."""

    prepare: Callable[[int, Entry], tuple]
    steps: Callable[[tuple], Steps]


class Reporter:
    """Counts finished materials and passes a one-line summary of each to ``progress``."""

    def __init__(self, progress: Progress | None, total: int, done: int = 0):
        self.progress, self.total, self.done = progress, total, done

    def __call__(self, entry: Entry, result: dict[str, Any]) -> dict[str, Any]:
        self.done += 1
        if self.progress is not None:
            self.progress(self.done, self.total, f"{entry.name}: {summary(result)}")
        return result


def summary(result: dict[str, Any]) -> str:
    """A one-line summary of a result (its status, and for a conversion its residual)."""
    if result["status"] != "ok":
        return f"error: {result['message']}"
    residual = result["residual"]
    return f"ok, RMS {residual['rms']:.3g}, ΔE2000 mean {residual['delta_e2000_mean']:.3g}"


def stream(
    entries: list[Entry],
    direction: Direction,
    progress: Progress | None,
    start: int,
    *,
    chunk: int,
    batched: bool,
) -> Iterator[tuple[int, dict[str, Any]]]:
    """Prepare the entries one by one, convert them ``chunk`` at a time and yield
    ``(index, result)`` in input order as soon as every earlier one is done (a bad
    material is an error result; the batch goes on). ``batched``: the chunk's kernel calls
    run side by side (an accelerator), else one after another.

    Chunks are fixed by index (entries ``[k·chunk, (k + 1)·chunk)``), and a run from
    ``start`` (a resumed conversion) converts again the entries of its first chunk
    before ``start`` without reporting them: a material's result depends, in its last
    digits, on the batch it was computed in, and so a resumed run writes exactly what
    an uninterrupted one does."""
    report = Reporter(progress, len(entries), start)
    done: dict[int, dict[str, Any]] = {}
    queue: list[tuple] = []
    following = start

    def ready() -> Iterator[tuple[int, dict[str, Any]]]:
        nonlocal following
        while following in done:
            yield following, done.pop(following)
            following += 1

    def solve() -> None:
        for item, outcome in zip(queue, run_chunk(queue, direction, batched)):
            if item[0] >= start:  # the others were done before (only their batch is needed)
                done[item[0]] = report(item[1], outcome)
            item[1].release()
        queue.clear()

    for i in range(start - start % chunk, len(entries)):
        entry = entries[i]
        if entry.error:
            if i >= start:
                done[i] = report(entry, error_result(entry, entry.error))
        else:
            try:
                queue.append(direction.prepare(i, entry))
            except Exception as exc:  # noqa: BLE001 - one bad material never stops the batch
                entry.release()
                if i >= start:
                    done[i] = report(entry, error_result(entry, message_of(exc)))
        if (i + 1) % chunk == 0 and queue:
            solve()
        yield from ready()
    if queue:
        solve()
    yield from ready()


def run_chunk(chunk: list[tuple], direction: Direction, batched: bool) -> list[dict[str, Any]]:
    """Convert the items of ``chunk`` (``(i, entry, ...)``) together: their steps run
    batched (`strauss_fit.engine.run_batched`; a material that fails is an error
    result, the others go on)."""
    outcomes = run_batched([direction.steps(item) for item in chunk], sequential=not batched, python_bound=False)
    return [
        error_result(item[1], message_of(outcome)) if isinstance(outcome, BaseException) else outcome
        for item, outcome in zip(chunk, outcomes)
    ]
