r"""Fitting many targets in one call: `fit_many`.

Every target is fitted exactly as `strauss_fit.fit` fits it — the same steps
(`strauss_fit.fitting.api.fit_steps`), the same decisions, the same result — but the
targets of a chunk advance together (`strauss_fit.engine.run_batched`): their calls
of the same compiled kernel with arguments of the same structure (the targets of one
scene and image size) run as one compiled call over the chunk, and the scene is prepared
once for all of them. Compilation therefore depends on the scenes and the settings, not on
the number of targets.

Failures stay with their target: a target that cannot be read, does not match its scene,
or breaks the fit is returned as a `FitFailure` (with the one-line message the
single fit would print) and the others go on.

Where the work runs is the ``executor``'s business (`strauss_fit.fitting.executors`): in
this process (the default), or on a Dask cluster, in chunks of targets.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..engine import run_batched
from ..errors import StraussFitError
from ..io.targets import Target, load_target, match_scene
from ..precision import uses_float64
from ..runtime import keep_freed_memory, release_compiled_code_if_needed, use_cpu_cores
from ..scene.loading import Scene, load_scene
from .api import fit_steps
from .options import FitOptions
from .result import FitResult

#: Targets advanced together by default (one compiled call covers at most this many).
DEFAULT_CHUNK = 64


@dataclass(frozen=True)
class FitJob:
    """One target of `fit_many`: the image (a path or a loaded
    `Target`), its scene (a path or a
    `Scene`), an optional mask and encoding for a path,
    and its fit options."""

    target: Target | str | Path
    scene: Scene | str | Path
    options: FitOptions = field(default_factory=FitOptions)
    mask: str | Path | None = None
    encoding: str = "auto"

    @property
    def name(self) -> str:
        return str(self.target.path) if isinstance(self.target, Target) else str(self.target)


@dataclass
class FitFailure:
    """A target `fit_many` could not fit: its name and the reason (one line)."""

    target: str
    message: str
    error: BaseException | None = field(default=None, repr=False)

    def __str__(self) -> str:
        return f"{self.target}: {self.message}"


@dataclass(frozen=True)
class BatchProgress:
    """Where a batch stands: targets done (fitted or failed) of ``total``, failures,
    seconds since the start, targets per second, and an estimate of the seconds left."""

    done: int
    total: int
    failed: int
    elapsed_s: float

    @property
    def rate(self) -> float:
        return self.done / self.elapsed_s if self.elapsed_s > 0 else 0.0

    @property
    def eta_s(self) -> float | None:
        return (self.total - self.done) / self.rate if self.rate > 0 else None


def jobs_for(
    targets: Iterable[Target | str | Path | FitJob],
    scenes: Scene | str | Path | Sequence[Scene | str | Path],
    options: FitOptions | Sequence[FitOptions] = FitOptions(),
) -> list[FitJob]:
    """`FitJob` s from targets and one scene (or one per target) and one set of
    options (or one per target); a `FitJob` given as a target is kept as it is."""
    targets = list(targets)
    scene_list = list(scenes) if isinstance(scenes, (list, tuple)) else [scenes] * len(targets)
    option_list = list(options) if isinstance(options, (list, tuple)) else [options] * len(targets)
    if len(scene_list) != len(targets) or len(option_list) != len(targets):
        raise StraussFitError(
            f"fit_many: {len(targets)} target(s) but {len(scene_list)} scene(s) and {len(option_list)} option set(s)"
        )
    return [t if isinstance(t, FitJob) else FitJob(t, s, o) for t, s, o in zip(targets, scene_list, option_list)]


def _failure(job: FitJob, error: BaseException) -> FitFailure:
    if isinstance(error, StraussFitError):
        return FitFailure(job.name, str(error), error)
    if isinstance(error, OSError):
        return FitFailure(job.name, f"{error.strerror or error}", error)
    return FitFailure(job.name, f"{type(error).__name__}: {error}", error)


def _loaded(job: FitJob, scenes: dict[str, Scene]) -> tuple[Scene, Target]:
    """The job's scene (loaded once per path) matched to its target."""
    scene = job.scene
    if not isinstance(scene, Scene):
        key = str(scene)
        if key not in scenes:
            scenes[key] = load_scene(scene)
        scene = scenes[key]
    target = job.target if isinstance(job.target, Target) else load_target(job.target, job.mask, job.encoding)
    scene, _ = match_scene(scene, target)
    return scene, target


@uses_float64
def fit_chunk(
    jobs: Sequence[FitJob],
    *,
    on_result: Callable[[int, FitResult | FitFailure], None] | None = None,
    max_batch: int | None = None,
) -> list[FitResult | FitFailure]:
    """Fit ``jobs`` in this process, advancing together (see the module docstring); in
    order, each a `FitResult` or a `FitFailure`.
    ``on_result(index, result)`` is called as each finishes."""
    keep_freed_memory()
    release_compiled_code_if_needed()
    scenes: dict[str, Scene] = {}
    cache: dict = {}  # prepared scenes, shared by the targets of one scene
    results: list[Any] = [None] * len(jobs)
    steps, positions = [], []
    for index, job in enumerate(jobs):
        try:
            scene, target = _loaded(job, scenes)
        except Exception as error:  # an unreadable target fails alone
            results[index] = _failure(job, error)
            if on_result is not None:
                on_result(index, results[index])
            continue
        steps.append(fit_steps(scene, target, job.options, cache=cache))
        positions.append(index)

    def done(slot: int, value: Any) -> None:
        index = positions[slot]
        results[index] = value if isinstance(value, FitResult) else _failure(jobs[index], value)
        if on_result is not None:
            on_result(index, results[index])

    run_batched(steps, on_done=done, max_batch=max_batch)
    return results


class InProcessExecutor:
    """Fit the chunks here, one after the other (`fit_chunk`): `fit_many`'s
    default executor. It lives beside the work it runs; the executors that send chunks
    elsewhere (`strauss_fit.fitting.executors`) sit above this module."""

    def __init__(self, max_batch: int | None = None):
        self.max_batch = max_batch

    def run(self, jobs: Sequence[FitJob], chunks: list[list[int]], arrived: Callable[[int, Any], None]) -> None:
        for chunk in chunks:
            fit_chunk(
                [jobs[i] for i in chunk],
                on_result=lambda position, result, chunk=chunk: arrived(chunk[position], result),
                max_batch=self.max_batch,
            )


def fit_many(
    targets: Iterable[Target | str | Path | FitJob],
    scenes: Scene | str | Path | Sequence[Scene | str | Path],
    options: FitOptions | Sequence[FitOptions] = FitOptions(),
    *,
    executor: Any = None,
    chunk_size: int = DEFAULT_CHUNK,
    progress: Callable[[BatchProgress], None] | None = None,
    on_result: Callable[[int, FitResult | FitFailure], None] | None = None,
) -> list[FitResult | FitFailure]:
    """Fit many targets: the results in the order of ``targets``, each a
    `FitResult` (the same as `strauss_fit.fit` gives
    for that target alone) or a `FitFailure`.

    ``targets``: images (paths or loaded targets) or `FitJob` s; ``scenes``: one
    scene for all (a path or a loaded scene) or one per target; ``options``: one
    `FitOptions` for all or one per target. The targets
    run ``chunk_size`` at a time on the ``executor``: ``None`` (this process), or an
    executor of `strauss_fit.fitting.executors` (e.g. ``DaskExecutor(workers=2)``).
    ``progress`` is called with a `BatchProgress` after each target,
    ``on_result(index, result)`` with each result as it arrives (to write it at once:
    a killed run then loses only the targets in flight).

    In a process whose JAX has run nothing yet, the first batch asks JAX for a CPU device
    per core (`strauss_fit.runtime.use_cpu_cores`) before loading anything."""
    use_cpu_cores()
    jobs = jobs_for(targets, scenes, options)
    if chunk_size < 1:
        raise StraussFitError(f"the chunk size must be at least 1, got {chunk_size}")
    executor = executor if executor is not None else InProcessExecutor()
    results: list[Any] = [None] * len(jobs)
    started = time.perf_counter()
    counts = {"done": 0, "failed": 0}

    def arrived(index: int, result: FitResult | FitFailure) -> None:
        results[index] = result
        counts["done"] += 1
        counts["failed"] += isinstance(result, FitFailure)
        if on_result is not None:
            on_result(index, result)
        if progress is not None:
            progress(BatchProgress(counts["done"], len(jobs), counts["failed"], time.perf_counter() - started))

    chunks = [list(range(i, min(i + chunk_size, len(jobs)))) for i in range(0, len(jobs), chunk_size)]
    executor.run(jobs, chunks, arrived)
    return results
