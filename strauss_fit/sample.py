r"""Posterior sampling with emcee's affine-invariant ensemble sampler.

What runs: :class:`emcee.EnsembleSampler` with ``vectorize=True`` over the log-posterior
of :mod:`strauss_fit.posterior` (one jitted, ``vmap``-ed JAX call per half-ensemble
update), walkers started around the least-squares optimum θ̂.

Start. Walkers are drawn from the Laplace (Gauss–Newton) Gaussian :math:`N(\hat\theta,\Sigma)`
(each standard deviation kept between 1e-6 and 1/4 of its prior width, so degenerate
directions neither collapse nor explode) and folded back into the prior box by reflection
at its faces. Entries the fit pinned at a bound start just inside it, since the posterior
there is one-sided.

Stopping (checked every ``check_every`` steps). With :math:`\hat\tau_i` emcee's estimate of
the integrated autocorrelation time of parameter i over the whole chain (Sokal's
windowing, c = 5), the run stops when the chain is at least ``min_tau_multiple`` (50)
times :math:`\max_i\hat\tau_i` long *and* :math:`\max_i\hat\tau_i` changed by less than
:data:`TAU_STABILITY` since the previous check (short chains underestimate τ), or at
``max_steps`` (the whole chain's length, earlier runs included), or on Ctrl-C.

Diagnostics (:func:`diagnose`): the burn-in discarded is :math:`\lceil 2\max_i\hat\tau_i\rceil`
steps (at most half the chain); the effective sample size of parameter i is
:math:`\mathrm{ESS}_i = W (S - b) / \hat\tau_i` (W walkers, S steps, b burn-in); the
acceptance fraction is per walker over the whole chain. The chain is *trustworthy* when
all of these hold (else the failed ones are listed):

1. S ≥ ``min_tau_multiple`` · max τ̂ (the τ estimate and everything after it are reliable);
2. the mean acceptance fraction lies in [0.1, 0.9] and no walker is below 0.02 (a stuck
   walker sits in a spurious mode or at a corner of the prior);
3. every parameter has ESS ≥ 100;
4. every stored log-probability is finite.

Storage: emcee's own HDF5 layout (group ``mcmc``: ``chain`` (S, W, P), ``log_prob`` (S, W),
``accepted`` (W,), the random state) — load it with
``emcee.backends.HDFBackend(path, read_only=True)`` or h5py — plus a group ``strauss_fit``
holding what is needed to resume and report (labels, prior, σ, the fit, the target's
digest). Steps are buffered in memory and written at least every
:data:`FLUSH_SECONDS` seconds and at every check (emcee's backend opens the file for every
step, which costs more than a step itself); Ctrl-C writes every step sampled so far before
the interrupt propagates. Resuming restores the last walkers, log-probabilities and the
random state, so an interrupted-and-resumed chain equals an uninterrupted one.
"""

from __future__ import annotations

import json
import math
import signal
import threading
import time
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

import emcee
import h5py
import numpy as np

from .errors import StraussFitError
from .posterior import LogPosterior, Prior

#: Default check interval (steps) of the stopping rule.
CHECK_EVERY = 100
#: Relative change of max τ̂ between checks below which the estimate counts as stable.
TAU_STABILITY = 0.05
#: Buffered steps are written to the file at least this often (seconds).
FLUSH_SECONDS = 2.0
DEFAULT_MIN_TAU_MULTIPLE = 50.0
#: Trustworthiness thresholds (see the module docstring).
MIN_ESS = 100.0
ACCEPTANCE_RANGE = (0.1, 0.9)
STUCK_WALKER = 0.02
CHAIN_GROUP = "mcmc"
META_GROUP = "strauss_fit"
FORMAT = "strauss-fit chain"
FORMAT_VERSION = 1


class ChainError(StraussFitError):
    """A chain file is missing, unreadable, foreign, or does not match the request."""


def default_walkers(ndim: int) -> int:
    """max(32, 4·P), even (emcee needs at least 2·P walkers; more helps with correlations)."""
    n = max(32, 4 * ndim)
    return n + n % 2


# --- buffered HDF5 backend ---------------------------------------------------------------

class BufferedHDFBackend(emcee.backends.HDFBackend):
    """emcee's HDF5 backend, same file layout, but steps are kept in memory until
    :meth:`flush` writes them in one go."""

    def __init__(self, filename: str | Path, **kwargs: Any):
        super().__init__(str(filename), name=CHAIN_GROUP, **kwargs)
        self._coords: list[np.ndarray] = []
        self._log_prob: list[np.ndarray] = []
        self._accepted: np.ndarray | None = None
        self._random_state: Any = None

    def save_step(self, state, accepted):  # noqa: D102 (emcee's API)
        self._coords.append(np.array(state.coords, dtype=np.float64))
        self._log_prob.append(np.array(state.log_prob, dtype=np.float64))
        self._accepted = accepted.astype(np.int64) if self._accepted is None else self._accepted + accepted
        self._random_state = state.random_state

    def pending(self) -> int:
        return len(self._coords)

    def grow(self, ngrow, blobs):  # noqa: D102
        self.flush()
        super().grow(ngrow, blobs)

    def flush(self, trim: bool = False) -> None:
        """Write the buffered steps; with ``trim``, also drop the unused rows emcee
        reserved, so that plain h5py readers see exactly the sampled steps."""
        if not self._coords and not trim:
            return
        with self.open("a") as f:
            if self.name not in f:  # nothing was ever started in this file
                return
            g = f[self.name]
            start = int(g.attrs["iteration"])
            k = len(self._coords)
            if k:
                if g["chain"].shape[0] < start + k:
                    g["chain"].resize(start + k, axis=0)
                    g["log_prob"].resize(start + k, axis=0)
                g["chain"][start:start + k] = np.stack(self._coords)
                g["log_prob"][start:start + k] = np.stack(self._log_prob)
                g["accepted"][:] += self._accepted
                for i, v in enumerate(self._random_state):
                    g.attrs[f"random_state_{i}"] = v
                g.attrs["iteration"] = start + k
            if trim:
                g["chain"].resize(start + k, axis=0)
                g["log_prob"].resize(start + k, axis=0)
        self._coords, self._log_prob, self._accepted = [], [], None


# --- diagnostics ---------------------------------------------------------------------------

@dataclass
class Diagnostics:
    """Convergence diagnostics of a chain (see the module docstring for the rules)."""

    labels: list[str]
    steps: int
    walkers: int
    tau: list[float]
    burn_in: int
    ess: list[float]
    acceptance_mean: float
    acceptance_min: float
    acceptance_max: float
    tau_multiple: float
    min_tau_multiple: float
    converged: bool
    trustworthy: bool
    reasons: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def autocorrelation_times(chain: np.ndarray) -> np.ndarray:
    """τ̂ per parameter of a chain (S, W, P) — emcee's estimator, no length check."""
    tau = emcee.autocorr.integrated_time(chain, c=5, tol=0, quiet=True)
    return np.maximum(np.asarray(tau, dtype=np.float64), 1.0)


def burn_in(tau: np.ndarray, steps: int) -> int:
    return int(min(math.ceil(2 * float(np.max(tau))), steps // 2))


def diagnose(chain: np.ndarray, log_prob: np.ndarray, accepted: np.ndarray, labels: list[str],
             min_tau_multiple: float = DEFAULT_MIN_TAU_MULTIPLE) -> Diagnostics:
    """Diagnostics of a chain (S, W, P) with log-probabilities (S, W) and acceptance counts (W,)."""
    steps, walkers, _ = chain.shape
    tau = autocorrelation_times(chain)
    burn = burn_in(tau, steps)
    ess = walkers * (steps - burn) / tau
    acceptance = accepted / max(steps, 1)
    multiple = steps / float(np.max(tau))
    reasons = []
    converged = multiple >= min_tau_multiple
    if not converged:
        reasons.append(f"the chain is {multiple:.0f} autocorrelation times long; at least "
                       f"{min_tau_multiple:.0f} are needed (run longer: --resume with a larger --max-steps)")
    low, high = ACCEPTANCE_RANGE
    if not low <= float(np.mean(acceptance)) <= high:
        reasons.append(f"the mean acceptance fraction {np.mean(acceptance):.2f} is outside [{low}, {high}]")
    stuck = int(np.sum(acceptance < STUCK_WALKER))
    if stuck:
        reasons.append(f"{stuck} walker(s) accepted fewer than {STUCK_WALKER:.0%} of their moves (stuck)")
    if float(np.min(ess)) < MIN_ESS:
        worst = labels[int(np.argmin(ess))]
        reasons.append(f"{worst} has only {np.min(ess):.0f} effective samples (fewer than {MIN_ESS:.0f})")
    if not np.all(np.isfinite(log_prob)):
        reasons.append("some stored log-probabilities are not finite")
    return Diagnostics(
        labels=list(labels), steps=int(steps), walkers=int(walkers), tau=tau.tolist(), burn_in=burn,
        ess=ess.tolist(), acceptance_mean=float(np.mean(acceptance)), acceptance_min=float(np.min(acceptance)),
        acceptance_max=float(np.max(acceptance)), tau_multiple=float(multiple),
        min_tau_multiple=float(min_tau_multiple), converged=bool(converged), trustworthy=not reasons,
        reasons=reasons,
    )


# --- starting points -----------------------------------------------------------------------

def initial_walkers(x_hat: np.ndarray, covariance: np.ndarray, prior: Prior, walkers: int,
                    rng: np.random.Generator, log_posterior: Callable[[np.ndarray], np.ndarray] | None = None,
                    ) -> np.ndarray:
    """Walkers (W, P) drawn from N(x̂, Σ) as the module docstring says, strictly inside the
    prior box, redrawn (up to 100 times) where ``log_posterior`` is not finite."""
    x_hat = np.asarray(x_hat, dtype=np.float64)
    width = prior.upper - prior.lower
    sd = np.sqrt(np.maximum(np.diag(covariance), 0.0))
    norm = np.outer(sd, sd)
    corr = np.divide(covariance, norm, out=np.eye(len(sd)), where=norm > 0)
    sd = np.clip(np.nan_to_num(sd, nan=0.0, posinf=0.0), 1e-6 * width, 0.25 * width)
    cov = corr * np.outer(sd, sd) + np.diag((1e-9 * width) ** 2)
    try:
        factor = np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:  # a correlation of ±1: fall back to the diagonal
        factor = np.diag(sd)
    centre = np.clip(x_hat, prior.lower, prior.upper)
    inset = 1e-6 * width

    def draw(n: int) -> np.ndarray:
        x = centre + rng.standard_normal((n, len(centre))) @ factor.T
        for _ in range(4):  # reflect at the faces (a draw may cross twice if the box is narrow)
            x = np.where(x < prior.lower, 2 * prior.lower - x, x)
            x = np.where(x > prior.upper, 2 * prior.upper - x, x)
        return np.clip(x, prior.lower + inset, prior.upper - inset)

    x = draw(walkers)
    if log_posterior is not None:
        for _ in range(100):
            bad = ~np.isfinite(log_posterior(x))
            if not bad.any():
                break
            x[bad] = draw(int(bad.sum()))
        else:
            raise ChainError("cannot start the walkers: the log-probability is not finite around the fit's optimum")
    return x


# --- the chain file --------------------------------------------------------------------------

def _check_file(path: Path) -> None:
    if not path.exists():
        raise ChainError(f"chain file not found: {path}")
    if path.is_dir():
        raise ChainError(f"chain path is a directory: {path}")
    try:
        ok = h5py.is_hdf5(str(path))
    except OSError as exc:
        raise ChainError(f"cannot read chain file {path}: {exc}") from None
    if not ok:
        raise ChainError(f"cannot read chain file {path}: not an HDF5 file (corrupt, or not a chain)")


def read_metadata(path: str | Path) -> dict[str, Any]:
    """The ``strauss_fit`` group's metadata of a chain file (one-line errors for a missing,
    corrupt or foreign file)."""
    path = Path(path)
    _check_file(path)
    try:
        with h5py.File(path, "r") as f:
            if META_GROUP not in f or f[META_GROUP].attrs.get("format") != FORMAT:
                raise ChainError(f"{path} is an HDF5 file but not a strauss-fit chain (no '{META_GROUP}' group)")
            version = int(f[META_GROUP].attrs.get("format_version", -1))
            if version != FORMAT_VERSION:
                raise ChainError(f"{path} is a strauss-fit chain of format version {version}; "
                                 f"this version reads {FORMAT_VERSION}")
            meta = json.loads(f[META_GROUP].attrs["metadata"])
            if CHAIN_GROUP not in f:
                raise ChainError(f"chain file {path} has no '{CHAIN_GROUP}' group: it holds no samples")
    except ChainError:
        raise
    except OSError as exc:  # h5py: "Unable to synchronously open file (bad superblock version number)"
        detail = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ChainError(f"cannot read chain file {path}: corrupt or truncated HDF5 file ({detail})") from None
    except (KeyError, ValueError, TypeError) as exc:
        raise ChainError(f"cannot read chain file {path}: its strauss-fit metadata is damaged ({type(exc).__name__})") from None
    return meta


def write_metadata(path: str | Path, meta: dict[str, Any]) -> None:
    """Create or replace the ``strauss_fit`` group (the emcee group is left alone)."""
    with h5py.File(path, "a") as f:
        if META_GROUP in f:
            del f[META_GROUP]
        g = f.create_group(META_GROUP)
        g.attrs["format"] = FORMAT
        g.attrs["format_version"] = FORMAT_VERSION
        g.attrs["metadata"] = json.dumps(meta, allow_nan=False)


@dataclass
class Chain:
    """A stored chain: ``chain`` (S, W, P), ``log_prob`` (S, W), ``accepted`` (W,), and
    the metadata written by :func:`run_sampler`."""

    path: str
    chain: np.ndarray
    log_prob: np.ndarray
    accepted: np.ndarray
    meta: dict[str, Any]

    @property
    def labels(self) -> list[str]:
        return list(self.meta["labels"])

    def diagnostics(self, min_tau_multiple: float | None = None) -> Diagnostics:
        k = min_tau_multiple if min_tau_multiple is not None else self.meta.get("min_tau_multiple", DEFAULT_MIN_TAU_MULTIPLE)
        return diagnose(self.chain, self.log_prob, self.accepted, self.labels, k)

    def samples(self, discard: int | None = None) -> np.ndarray:
        """The flattened samples (n, P) after the burn-in (:func:`burn_in` unless given)."""
        if discard is None:
            discard = burn_in(autocorrelation_times(self.chain), self.chain.shape[0])
        return self.chain[discard:].reshape(-1, self.chain.shape[-1])


def load_chain(path: str | Path) -> Chain:
    """Read a chain file written by :func:`run_sampler` (one-line errors otherwise)."""
    meta = read_metadata(path)
    try:
        backend = emcee.backends.HDFBackend(str(path), name=CHAIN_GROUP, read_only=True)
        iteration = backend.iteration
        if iteration <= 0:
            raise ChainError(f"chain file {path} holds no steps yet")
        chain = backend.get_chain()
        log_prob = backend.get_log_prob()
        accepted = np.asarray(backend.accepted)
    except ChainError:
        raise
    except (OSError, KeyError, ValueError, AttributeError) as exc:
        raise ChainError(f"cannot read the samples in {path}: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}") from None
    if chain.shape[-1] != len(meta.get("labels", [])):
        raise ChainError(f"chain file {path} is inconsistent: {chain.shape[-1]} parameters but "
                         f"{len(meta.get('labels', []))} labels")
    return Chain(str(path), np.asarray(chain, dtype=np.float64), np.asarray(log_prob, dtype=np.float64),
                 accepted, meta)


# --- running ---------------------------------------------------------------------------------

@dataclass(frozen=True)
class SampleSettings:
    """How long to sample (the number of walkers is that of the starting points)."""

    max_steps: int = 10000
    min_tau_multiple: float = DEFAULT_MIN_TAU_MULTIPLE
    check_every: int = CHECK_EVERY
    seed: int = 0


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
    """What one call of :func:`run_sampler` did."""

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


def run_sampler(log_posterior: LogPosterior, path: str | Path | None, *, start: np.ndarray | None = None,
                settings: SampleSettings = SampleSettings(), metadata: dict[str, Any] | None = None,
                resume: bool = False, progress: Callable[[Progress], None] | None = None) -> SampleRun:
    """Sample until the stopping rule of the module docstring holds.

    New chain: ``start`` (W, P) are the walkers' starting points and ``metadata`` (labels,
    prior, σ, ...) is written to the file's ``strauss_fit`` group; an existing file must
    have been removed by the caller. ``resume``: continue the chain in ``path`` from its
    last state (``start`` is ignored). ``path=None`` keeps the chain in memory (tests,
    benchmarks). A KeyboardInterrupt is re-raised after every step so far is written.
    """
    started = time.perf_counter()
    ndim = log_posterior.prior.lower.size
    if path is None:
        backend: emcee.backends.Backend = emcee.backends.Backend()
    else:
        backend = BufferedHDFBackend(path)
    if resume:
        try:
            steps_stored = 0 if path is None or not backend.initialized else int(backend.iteration)
            walkers, file_ndim = backend.shape if steps_stored else (0, 0)
        except (OSError, KeyError, ValueError) as exc:
            raise ChainError(f"cannot resume from {path}: its samples are damaged ({type(exc).__name__})") from None
        if steps_stored <= 0:
            raise ChainError(f"cannot resume: {path} holds no steps")
        if file_ndim != ndim:
            raise ChainError(f"cannot resume: {path} has {file_ndim} parameters but this fit has {ndim}")
    else:
        if start is None:
            raise ValueError("a new chain needs starting points")
        walkers = start.shape[0]
        if walkers < 2 * ndim or walkers % 2:
            raise ChainError(f"the number of walkers must be even and at least twice the number of "
                             f"parameters ({2 * ndim}); got {walkers}")
        if path is not None:
            write_metadata(path, dict(metadata or {}, labels=list(log_posterior.prior.labels),
                                      min_tau_multiple=settings.min_tau_multiple))
    sampler = emcee.EnsembleSampler(walkers, ndim, log_posterior, vectorize=True, backend=backend)
    if resume:
        state = backend.get_last_sample()
    else:
        state = emcee.State(start, random_state=np.random.RandomState(settings.seed).get_state())
    done = backend.iteration
    tau_previous: float | None = None
    stopped = "max_steps"
    sampling = 0.0
    new_steps = 0
    check = max(int(settings.check_every), 1)
    try:
        with deferred_interrupt() as interrupted:
            while done < settings.max_steps:
                chunk = min(check - done % check, settings.max_steps - done)
                t0 = time.perf_counter()
                last_flush = t0
                for state in sampler.sample(state, iterations=chunk, store=True, skip_initial_state_check=True):
                    done += 1
                    new_steps += 1
                    if interrupted():
                        raise KeyboardInterrupt
                    if path is not None and time.perf_counter() - last_flush > FLUSH_SECONDS:
                        backend.flush()
                        last_flush = time.perf_counter()
                sampling += time.perf_counter() - t0
                if path is not None:
                    backend.flush()
                tau = autocorrelation_times(backend.get_chain())
                tau_max = float(np.max(tau))
                stable = tau_previous is not None and abs(tau_max - tau_previous) < TAU_STABILITY * tau_max
                tau_previous = tau_max
                if progress is not None:
                    progress(Progress(done, settings.max_steps, new_steps, tau_max,
                                      int(math.ceil(settings.min_tau_multiple * tau_max)),
                                      float(np.mean(backend.accepted / max(done, 1))),
                                      new_steps / sampling if sampling > 0 else 0.0))
                if done >= settings.min_tau_multiple * tau_max and stable:
                    stopped = "converged"
                    break
    finally:
        if path is not None:
            backend.flush(trim=True)
    chain, log_prob = backend.get_chain(), backend.get_log_prob()
    if path is not None:
        meta = read_metadata(path)
        meta["min_tau_multiple"] = settings.min_tau_multiple
        write_metadata(path, meta)
    diagnostics = diagnose(chain, log_prob, np.asarray(backend.accepted), list(log_posterior.prior.labels),
                           settings.min_tau_multiple)
    return SampleRun(path=None if path is None else str(path), diagnostics=diagnostics, stopped=stopped,
                     new_steps=new_steps, wall_s=time.perf_counter() - started, sampling_s=sampling,
                     steps_per_s=new_steps / sampling if sampling > 0 else 0.0, chain=chain, log_prob=log_prob)
