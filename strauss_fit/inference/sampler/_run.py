"""Running emcee: the settings (`SampleSettings`), what a run reports
(`Progress`, `SampleRun`), Ctrl-C handling (`deferred_interrupt`), and
`run_sampler`, which samples a log-posterior into a chain file until the stopping
rule holds ("Stopping" in `strauss_fit.inference.sampler`).
"""

from __future__ import annotations

import math
import signal
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import emcee
import numpy as np

from ...fitting.options import DEFAULT_QUALITY, quality_preset
from ...precision import uses_float64
from ..posterior import LogPosterior
from ._backends import BufferedHDFBackend
from ._chain import read_metadata
from ._diagnostics import DEFAULT_MIN_TAU_MULTIPLE, Diagnostics, autocorrelation_times, diagnose
from ._format import ChainError

#: Default check interval (steps) of the stopping rule.
CHECK_EVERY = 100
#: Relative change of max τ̂ between checks below which the estimate counts as stable.
TAU_STABILITY = 0.05


@dataclass(frozen=True)
class SampleSettings:
    """How long to sample, and with how many walkers (None: `default_walkers`;
    `run_sampler` takes the number of its starting points). The defaults are the
    ``balanced`` quality preset; `preset` gives the others."""

    max_steps: int = 10000
    min_tau_multiple: float = DEFAULT_MIN_TAU_MULTIPLE
    check_every: int = CHECK_EVERY
    seed: int = 0
    walkers: int | None = None

    @classmethod
    def preset(cls, name: str = DEFAULT_QUALITY, **overrides: Any) -> SampleSettings:
        """The sampling settings of quality preset ``name``
        (`strauss_fit.fitting.options.QUALITY_PRESETS`: ``walkers``,
        ``min_tau_multiple``, ``sample_max_steps``), with ``overrides`` (a value of None
        keeps the preset's or the default)."""
        values = quality_preset(name)
        settings = {
            "max_steps": values["sample_max_steps"],
            "min_tau_multiple": values["min_tau_multiple"],
            "walkers": values["walkers"],
        }
        settings.update({key: value for key, value in overrides.items() if value is not None})
        return cls(**settings)


@dataclass
class Progress:
    """Passed to the progress callback after every check."""

    steps: int
    max_steps: int
    new_steps: int
    tau_max: float
    needed_steps: int
    acceptance: float
    steps_per_s: float


@dataclass
class SampleRun:
    """What one call of `run_sampler` did."""

    path: str | None
    diagnostics: Diagnostics
    stopped: str  # "converged", "max_steps"
    new_steps: int
    wall_s: float
    sampling_s: float
    steps_per_s: float
    chain: np.ndarray = field(repr=False, default=None)  # type: ignore[assignment]
    log_prob: np.ndarray = field(repr=False, default=None)  # type: ignore[assignment]


@contextmanager
def deferred_interrupt() -> Iterator[Callable[[], bool]]:
    """Within the block, a first Ctrl-C only sets a flag (the caller stops at the next safe
    point, after the current step is stored); a second one interrupts at once. Yields a
    function telling whether Ctrl-C was pressed. A no-op outside the main thread."""
    if threading.current_thread() is not threading.main_thread():
        yield lambda: False
        return
    pressed = [False]
    previous = signal.getsignal(signal.SIGINT)

    def handler(signum, frame):
        if pressed[0]:
            raise KeyboardInterrupt
        pressed[0] = True

    signal.signal(signal.SIGINT, handler)
    try:
        yield lambda: pressed[0]
    finally:
        signal.signal(signal.SIGINT, previous)


@dataclass
class _Counts:
    """How far a run has got: the chain's length ``done`` (earlier runs included), the steps
    this run added, and the seconds spent sampling (writing the chain file excluded, so that
    the speed is the sampler's)."""

    done: int
    new_steps: int = 0
    sampling: float = 0.0

    @property
    def steps_per_s(self) -> float:
        """Steps sampled per second of sampling (0 before any)."""
        return self.new_steps / self.sampling if self.sampling > 0 else 0.0


def _open_backend(path: str | Path | None, resume: bool, replaces: tuple[str | Path, ...]) -> emcee.backends.Backend:
    """Where the chain goes: emcee's in-memory backend without a path, else the chain file
    held in memory (`BufferedHDFBackend`), read first when resuming; a new chain
    removes ``replaces`` when it first replaces the file."""
    if path is None:
        return emcee.backends.Backend()
    if resume:
        return BufferedHDFBackend.load(path)
    backend = BufferedHDFBackend(path)
    backend.replaces = [Path(p) for p in replaces]
    return backend


def _stored_walkers(backend: emcee.backends.Backend, path: str | Path | None, ndim: int) -> int:
    """The number of walkers of the chain to resume, after checking that it holds steps and
    the random state (so that resuming continues it exactly) over ``ndim`` parameters."""
    try:
        steps_stored = 0 if path is None or not backend.initialized else int(backend.iteration)
        walkers, file_ndim = backend.shape if steps_stored else (0, 0)
        if steps_stored and backend.random_state is None:
            raise KeyError("random_state")
    except (OSError, KeyError, ValueError, TypeError) as exc:
        raise ChainError(f"cannot resume from {path}: its samples are damaged ({type(exc).__name__})") from None
    if steps_stored <= 0:
        raise ChainError(f"cannot resume: {path} holds no steps")
    if file_ndim != ndim:
        raise ChainError(f"cannot resume: {path} has {file_ndim} parameters but this fit has {ndim}")
    return walkers


def _start_walkers(start: np.ndarray | None, ndim: int) -> int:
    """The number of walkers of a new chain: the rows of ``start``, which emcee's stretch
    move needs to be even and at least twice the number of parameters."""
    if start is None:
        raise ValueError("a new chain needs starting points")
    walkers = start.shape[0]
    if walkers < 2 * ndim or walkers % 2:
        raise ChainError(
            f"the number of walkers must be even and at least twice the number of "
            f"parameters ({2 * ndim}); got {walkers}"
        )
    return walkers


def _write_start_metadata(
    backend: BufferedHDFBackend,
    path: str | Path,
    labels: list[str],
    settings: SampleSettings,
    metadata: dict[str, Any] | None,
    resume: bool,
) -> None:
    """Put the chain's metadata (the stored one when resuming, else ``metadata`` with the
    labels) and this run's ``min_tau_multiple`` in the in-memory file; it reaches the disk
    with the first write."""
    meta = read_metadata(path, required=False) if resume else dict(metadata or {}, labels=labels)
    meta["min_tau_multiple"] = settings.min_tau_multiple
    backend.write_metadata(meta)


def _sample_chunk(
    sampler: emcee.EnsembleSampler,
    backend: emcee.backends.Backend,
    state: emcee.State,
    steps: int,
    counts: _Counts,
    interrupted: Callable[[], bool],
    persist: bool,
) -> emcee.State:
    """Take ``steps`` steps from ``state`` and return the last state (it starts the next
    chunk). With ``persist`` the chain file is written whenever it is due, during the chunk
    and at its end; a Ctrl-C stops after the step that was being taken."""
    t0 = time.perf_counter()
    # the state after the last step starts the next chunk
    for state in sampler.sample(  # noqa: B007, B020
        state, iterations=steps, store=True, skip_initial_state_check=True
    ):
        counts.done += 1
        counts.new_steps += 1
        if interrupted():
            raise KeyboardInterrupt
        if persist and backend.persist_due():
            counts.sampling += time.perf_counter() - t0
            backend.persist()
            t0 = time.perf_counter()
    counts.sampling += time.perf_counter() - t0
    if persist:
        backend.flush()
        if backend.persist_due():
            backend.persist()
    return state


def _check(
    backend: emcee.backends.Backend,
    counts: _Counts,
    settings: SampleSettings,
    progress: Callable[[Progress], None] | None,
) -> float:
    """max τ̂ of the whole chain so far (the stopping rule's figure), also passed to
    ``progress`` with the steps it asks for and the acceptance."""
    tau_max = float(np.max(autocorrelation_times(backend.get_chain())))
    if progress is not None:
        progress(
            Progress(
                counts.done,
                settings.max_steps,
                counts.new_steps,
                tau_max,
                int(math.ceil(settings.min_tau_multiple * tau_max)),
                float(np.mean(backend.accepted / max(counts.done, 1))),
                counts.steps_per_s,
            )
        )
    return tau_max


def _sample_until_stopped(
    sampler: emcee.EnsembleSampler,
    backend: emcee.backends.Backend,
    state: emcee.State,
    settings: SampleSettings,
    *,
    persist: bool,
    resume: bool,
    progress: Callable[[Progress], None] | None,
) -> tuple[_Counts, str]:
    """Sample in chunks up to the next check until the stopping rule holds or the chain is
    ``max_steps`` long; return the counts and why it stopped ("converged", "max_steps").
    With ``persist`` every step sampled is written at the end, on Ctrl-C too, but not after
    a failed write (the chain on disk stays as the last successful write left it)."""
    counts = _Counts(done=backend.iteration)
    tau_previous: float | None = None
    stopped = "max_steps"
    check = max(int(settings.check_every), 1)
    write_failed = False
    try:
        with deferred_interrupt() as interrupted:
            while counts.done < settings.max_steps:
                chunk = min(check - counts.done % check, settings.max_steps - counts.done)
                state = _sample_chunk(sampler, backend, state, chunk, counts, interrupted, persist)
                tau_max = _check(backend, counts, settings, progress)
                # short chains underestimate τ: the length test waits until the estimate settles
                stable = tau_previous is not None and abs(tau_max - tau_previous) < TAU_STABILITY * tau_max
                tau_previous = tau_max
                if counts.done >= settings.min_tau_multiple * tau_max and stable:
                    stopped = "converged"
                    break
    except ChainError:
        write_failed = True
        raise
    finally:
        if persist and not write_failed and (counts.new_steps or resume):
            backend.persist()
    return counts, stopped


@uses_float64
def run_sampler(
    log_posterior: LogPosterior,
    path: str | Path | None,
    *,
    start: np.ndarray | None = None,
    settings: SampleSettings = SampleSettings(),
    metadata: dict[str, Any] | None = None,
    resume: bool = False,
    progress: Callable[[Progress], None] | None = None,
    replaces: tuple[str | Path, ...] = (),
) -> SampleRun:
    """Sample until the stopping rule of `strauss_fit.inference.sampler` holds.

    New chain: ``start`` (W, P) are the walkers' starting points and ``metadata`` (labels,
    prior, σ, ...) is written to the file's ``strauss_fit`` group; an existing file is
    replaced when the first steps are written. ``resume``: continue the chain in ``path``
    from its last state (``start`` is ignored). ``path=None`` keeps the chain in memory
    (tests, benchmarks). A KeyboardInterrupt is re-raised after every step so far is
    written; a failed write (a full disk) is a `ChainError` and leaves the file as
    the previous write left it.
    """
    started = time.perf_counter()
    ndim = log_posterior.prior.lower.size
    labels = list(log_posterior.prior.labels)
    backend = _open_backend(path, resume, replaces)
    walkers = _stored_walkers(backend, path, ndim) if resume else _start_walkers(start, ndim)
    if path is not None:
        _write_start_metadata(backend, path, labels, settings, metadata, resume)
    sampler = emcee.EnsembleSampler(walkers, ndim, log_posterior, vectorize=True, backend=backend)
    if resume:
        state = backend.get_last_sample()
    else:
        state = emcee.State(start, random_state=np.random.RandomState(settings.seed).get_state())
    counts, stopped = _sample_until_stopped(
        sampler, backend, state, settings, persist=path is not None, resume=resume, progress=progress
    )
    chain, log_prob = backend.get_chain(), backend.get_log_prob()
    diagnostics = diagnose(chain, log_prob, np.asarray(backend.accepted), labels, settings.min_tau_multiple)
    return SampleRun(
        path=None if path is None else str(path),
        diagnostics=diagnostics,
        stopped=stopped,
        new_steps=counts.new_steps,
        wall_s=time.perf_counter() - started,
        sampling_s=counts.sampling,
        steps_per_s=counts.steps_per_s,
        chain=chain,
        log_prob=log_prob,
    )
