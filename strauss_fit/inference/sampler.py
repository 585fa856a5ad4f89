r"""Posterior sampling with emcee's affine-invariant ensemble sampler.

What runs: :class:`emcee.EnsembleSampler` with ``vectorize=True`` over the log-posterior
of :mod:`strauss_fit.inference.posterior` (one jitted, ``vmap``-ed JAX call per half-ensemble
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
digest, and the ``adjustment``: its method and reason, the fit's covariance V and the
centre θ̂, and for the affine one the matrix A with the steps and burn-in it was computed
from and the draws it drops; :mod:`strauss_fit.inference.adjustment`).

Adjustment (``adjust``). On a target the model cannot reproduce, the Gaussian
likelihood's posterior does not have the spread of the fitted values over fresh noise
(the fit's noise sandwich V). With ``"affine"`` (the default when the fit's uncertainty is
the sandwich and its verdict a mismatch) the chain is sampled as usual and A, with
A Σ_post Aᵀ = V, is computed from its draws after burn-in when sampling ends and stored;
:meth:`Chain.samples` returns the mapped draws θ̂ + A(θ − θ̂) (those outside the prior
dropped) and ``adjusted=False`` the raw ones. ``"temperature"`` samples with σ√T instead
(T ≥ 1: it only widens; :func:`strauss_fit.inference.adjustment.temperature`).

Least squares only. The likelihood is Gaussian, so its optimum is the least-squares fit's
θ̂: a fit made with another loss (Huber, which ``fit --loss auto`` switches to on a visible
mismatch; Cauchy; perceptual) has its θ̂ elsewhere, and its noise sandwich is the spread of
*that* estimator. The walkers' start, the temperature and the affine map θ̂ + A(θ − θ̂)
(A Σ_post Aᵀ = V, V the fit's sandwich) all take θ̂ and V to be the chain's own optimum and
the spread of the estimator the chain describes; with a Huber fit the chain centres on the
least-squares optimum instead (many deviations away) and the map moves it to neither. So
:func:`sample` refuses such a fit (:func:`check_least_squares`), and the fit it makes
itself is least squares.

Writing the chain safely. HDF5 cannot survive a full disk: a failed write inside it can
crash the process (a segmentation fault in h5py's clean-up) and leave a file that no
longer opens. So HDF5 never writes to the disk here: the chain file is held in memory
(:class:`BufferedHDFBackend`; h5py writes into a ``BytesIO``), and
:meth:`BufferedHDFBackend.persist` writes the whole file image to a temporary file, every
write and the ``fsync`` checked, and renames it over the chain
(:class:`strauss_fit.io.files.Outputs`). A failed write (a full disk) removes the temporary
and leaves the chain on disk exactly as it was after the previous write; ``--resume`` reads
it once there is space again. The file is written at least every :data:`FLUSH_SECONDS`
seconds — less often when one write costs more than a tenth of that time
(:data:`PERSIST_SHARE`), as for long chains — at every check when that is due, and at the
end; Ctrl-C writes every step sampled so far before the interrupt propagates. Resuming
restores the last walkers, log-probabilities and the random state, so an
interrupted-and-resumed chain equals an uninterrupted one.

Reading a chain (:func:`load_chain`) checks what it reads: metadata with every key a
report or a resume needs, as many rows as the iteration count says, finite samples; a
damaged file is a one-line :class:`ChainError`.
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
import signal
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import emcee
import h5py
import numpy as np

from ..errors import StraussFitError
from ..fit.api import fit as run_fit
from ..fit.options import DEFAULT_QUALITY, FitOptions, quality_preset
from ..fit.result import FitResult
from ..io.files import Outputs, WriteError, check_writable, read_json
from ..io.targets import load_target, match_scene
from ..precision import uses_float64
from ..scene.loading import load_scene
from ..stats import laplace
from .adjustment import METHODS as ADJUST_METHODS
from .adjustment import (
    AdjustmentError,
    adjust_samples,
    adjusted_entries,
    default_method,
    full_matrix,
    loss_of,
    temperature,
)
from .posterior import (
    LogPosterior,
    Prior,
    default_prior,
    estimate_sigma,
    parse_priors,
    problem_from_fit,
    target_digest,
)
from .summaries import summarise_chain

#: Default check interval (steps) of the stopping rule.
CHECK_EVERY = 100
#: Relative change of max τ̂ between checks below which the estimate counts as stable.
TAU_STABILITY = 0.05
#: The chain file is written at least this often (seconds) while sampling ...
FLUSH_SECONDS = 2.0
#: ... or less often, so that writing it takes at most this share of the time.
PERSIST_SHARE = 0.1
#: Steps per HDF5 chunk of the chain and log-probability datasets.
CHUNK_STEPS = 64
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
    """emcee's HDF5 backend, same file layout, but the HDF5 file lives in memory: steps are
    buffered until :meth:`flush` adds them to the in-memory file, and only :meth:`persist`
    writes the file to ``filename`` (atomically, every write checked; see the module
    docstring). ``image`` is the bytes of an existing chain file (to resume it)."""

    def __init__(self, filename: str | Path, image: bytes | None = None, **kwargs: Any):
        super().__init__(str(filename), name=CHAIN_GROUP, **kwargs)
        self._image = io.BytesIO(image or b"")
        self._coords: list[np.ndarray] = []
        self._log_prob: list[np.ndarray] = []
        self._accepted: np.ndarray | None = None
        self._random_state: Any = None
        self.persisted_steps = 0 if image is None else self._stored_iteration()
        self.persist_seconds = 0.0
        self.last_persist = time.perf_counter()
        self.replaces: list[Path] = []

    @classmethod
    def load(cls, filename: str | Path) -> BufferedHDFBackend:
        """The chain file ``filename``, read into memory."""
        try:
            image = Path(filename).read_bytes()
        except OSError as exc:
            raise ChainError(f"cannot read chain file {filename}: {exc.strerror or exc}") from None
        return cls(filename, image)

    def _stored_iteration(self) -> int:
        try:
            with self.open() as f:
                return int(f[self.name].attrs["iteration"]) if self.name in f else 0
        except (OSError, KeyError, ValueError):
            return 0

    @property
    def initialized(self) -> bool:  # noqa: D102 (emcee's API)
        if self._image.getbuffer().nbytes == 0:
            return False
        try:
            with self.open() as f:
                return self.name in f
        except OSError:
            return False

    def open(self, mode: str = "r"):  # noqa: D102 (emcee's API)
        if self.read_only and mode != "r":
            raise RuntimeError("The backend has been loaded in read-only mode.")
        if mode != "r" and self._image.getbuffer().nbytes == 0:
            mode = "w"  # a new file
        f = h5py.File(self._image, mode)
        if not self.dtype_set and self.name in f:
            g = f[self.name]
            if "chain" in g:
                self.dtype = g["chain"].dtype
                self.dtype_set = True
        return f

    def reset(self, nwalkers, ndim):  # noqa: D102 (emcee's API)
        """emcee's layout, with chunks of :data:`CHUNK_STEPS` whole steps (h5py's automatic
        chunks split the walkers and made a chain of a few steps weigh 200 KB)."""
        with self.open("a") as f:
            if self.name in f:
                del f[self.name]
            g = f.create_group(self.name)
            g.attrs["version"] = emcee.__version__
            g.attrs["nwalkers"] = nwalkers
            g.attrs["ndim"] = ndim
            g.attrs["has_blobs"] = False
            g.attrs["iteration"] = 0
            g.create_dataset("accepted", data=np.zeros(nwalkers))
            g.create_dataset(
                "chain",
                (0, nwalkers, ndim),
                maxshape=(None, nwalkers, ndim),
                dtype=self.dtype,
                chunks=(CHUNK_STEPS, nwalkers, ndim),
            )
            g.create_dataset(
                "log_prob", (0, nwalkers), maxshape=(None, nwalkers), dtype=self.dtype, chunks=(CHUNK_STEPS, nwalkers)
            )

    def save_step(self, state, accepted):  # noqa: D102 (emcee's API)
        self._coords.append(np.array(state.coords, dtype=np.float64))
        self._log_prob.append(np.array(state.log_prob, dtype=np.float64))
        self._accepted = accepted.astype(np.int64) if self._accepted is None else self._accepted + accepted
        self._random_state = state.random_state

    def pending(self) -> int:
        return len(self._coords)

    def grow(self, ngrow, blobs):  # noqa: D102 - rows are added as they are flushed, never reserved
        self.flush()

    def flush(self, trim: bool = False) -> None:
        """Add the buffered steps to the in-memory file (its datasets hold exactly the
        sampled steps: no rows are reserved ahead). ``trim`` is kept for compatibility."""
        if not self._coords:
            return
        with self.open("a") as f:
            if self.name not in f:  # nothing was ever started in this file
                return
            g = f[self.name]
            start = int(g.attrs["iteration"])
            k = len(self._coords)
            g["chain"].resize(start + k, axis=0)
            g["log_prob"].resize(start + k, axis=0)
            g["chain"][start : start + k] = np.stack(self._coords)
            g["log_prob"][start : start + k] = np.stack(self._log_prob)
            g["accepted"][:] += self._accepted
            for i, v in enumerate(self._random_state):
                g.attrs[f"random_state_{i}"] = v
            g.attrs["iteration"] = start + k
        self._coords, self._log_prob, self._accepted = [], [], None

    def write_metadata(self, meta: dict[str, Any]) -> None:
        """Create or replace the ``strauss_fit`` group of the in-memory file."""
        with self.open("a") as f:
            _write_metadata_group(f, meta)

    def persist_due(self) -> bool:
        """Whether the file is due to be written (see :data:`FLUSH_SECONDS`)."""
        interval = max(FLUSH_SECONDS, self.persist_seconds / PERSIST_SHARE)
        return time.perf_counter() - self.last_persist >= interval

    def persist(self) -> None:
        """Flush, then write the whole file to ``filename``: a temporary file, every write
        and the fsync checked, renamed over the chain. A failure (a full disk) leaves the
        chain on disk as it was and raises a :class:`ChainError` saying how many steps it
        keeps."""
        self.flush()
        steps = self._stored_iteration()
        started = time.perf_counter()
        try:
            with Outputs(force=True) as out:
                out.add_bytes(self.filename, self._image.getbuffer())
                out.commit()
        except WriteError as exc:
            kept = (
                f"{self.filename} keeps the {self.persisted_steps} steps written before "
                "(free some space and continue with --resume)"
                if self.persisted_steps
                else "no chain was written (free some space and start again)"
            )
            raise ChainError(f"{exc}; {kept}") from None
        self.persisted_steps = steps
        self.persist_seconds = time.perf_counter() - started
        self.last_persist = time.perf_counter()
        for stale in self.replaces:  # files that belonged to the chain just replaced
            Path(stale).unlink(missing_ok=True)
        self.replaces = []


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


def diagnose(
    chain: np.ndarray,
    log_prob: np.ndarray,
    accepted: np.ndarray,
    labels: list[str],
    min_tau_multiple: float = DEFAULT_MIN_TAU_MULTIPLE,
) -> Diagnostics:
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
        reasons.append(
            f"the chain is {multiple:.0f} autocorrelation times long; at least "
            f"{min_tau_multiple:.0f} are needed (run longer: --resume with a larger --max-steps)"
        )
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
        labels=list(labels),
        steps=int(steps),
        walkers=int(walkers),
        tau=tau.tolist(),
        burn_in=burn,
        ess=ess.tolist(),
        acceptance_mean=float(np.mean(acceptance)),
        acceptance_min=float(np.min(acceptance)),
        acceptance_max=float(np.max(acceptance)),
        tau_multiple=float(multiple),
        min_tau_multiple=float(min_tau_multiple),
        converged=bool(converged),
        trustworthy=not reasons,
        reasons=reasons,
    )


# --- starting points -----------------------------------------------------------------------


def initial_walkers(
    x_hat: np.ndarray,
    covariance: np.ndarray,
    prior: Prior,
    walkers: int,
    rng: np.random.Generator,
    log_posterior: Callable[[np.ndarray], np.ndarray] | None = None,
) -> np.ndarray:
    """Walkers (W, P) drawn from N(x̂, Σ) as the module docstring says, strictly inside the
    prior box, redrawn (up to 100 times) where ``log_posterior`` is not finite."""
    x_hat = np.asarray(x_hat, dtype=np.float64)
    width = prior.upper - prior.lower
    sd = laplace.deviations(covariance)
    corr = laplace.correlation(covariance, fallback=np.eye(len(sd)))
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


#: Metadata keys every chain of :func:`sample` holds, and what each must be.
REQUIRED_METADATA = {
    "labels": "a list of parameter names",
    "fit": "the fit result it started from",
    "sigma": "the noise level, a number > 0",
    "prior": "the prior box, {label: [low, high]}",
}


def _check_metadata(path: Path, meta: Any, required: bool) -> dict[str, Any]:
    """One-line errors for metadata that a report or a resume cannot use."""

    def damaged(what: str) -> ChainError:
        return ChainError(f"chain file {path}: its strauss-fit metadata is damaged ({what})")

    if not isinstance(meta, dict):
        raise damaged("not a JSON object")
    labels = meta.get("labels")
    if "labels" in meta or required:
        if not isinstance(labels, list) or not labels or not all(isinstance(x, str) for x in labels):
            raise damaged(f"'labels' must be {REQUIRED_METADATA['labels']}")
    if not required:
        return meta
    missing = [key for key in REQUIRED_METADATA if key not in meta]
    if missing:
        raise damaged(f"no {', '.join(repr(k) for k in missing)}: {REQUIRED_METADATA[missing[0]]}")
    if not isinstance(meta["fit"], dict):
        raise damaged("'fit' is not a fit result")
    sigma = meta["sigma"]
    if isinstance(sigma, bool) or not isinstance(sigma, (int, float)) or not math.isfinite(sigma) or sigma <= 0:
        raise damaged(f"'sigma' must be a finite number > 0, got {sigma!r}")
    prior = meta["prior"]
    for label in labels:
        bounds = prior.get(label) if isinstance(prior, dict) else None
        if (
            not isinstance(bounds, list)
            or len(bounds) != 2
            or not all(isinstance(b, (int, float)) and not isinstance(b, bool) and math.isfinite(b) for b in bounds)
            or not bounds[0] < bounds[1]
        ):
            raise damaged(f"the prior of {label} must be [low, high] with low < high, got {bounds!r}")
    for key in ("target", "scene", "target_sha256"):
        if key in meta and not isinstance(meta[key], str):
            raise damaged(f"'{key}' must be a string")
    return meta


def read_metadata(path: str | Path, *, required: bool = True) -> dict[str, Any]:
    """The ``strauss_fit`` group's metadata of a chain file (one-line errors for a missing,
    corrupt or foreign file, or metadata lacking what a report or a resume needs; with
    ``required=False`` only the file's identity and the labels are checked)."""
    path = Path(path)
    _check_file(path)
    try:
        with h5py.File(path, "r") as f:
            if META_GROUP not in f or f[META_GROUP].attrs.get("format") != FORMAT:
                raise ChainError(f"{path} is an HDF5 file but not a strauss-fit chain (no '{META_GROUP}' group)")
            version = int(f[META_GROUP].attrs.get("format_version", -1))
            if version != FORMAT_VERSION:
                raise ChainError(
                    f"{path} is a strauss-fit chain of format version {version}; this version reads {FORMAT_VERSION}"
                )
            meta = json.loads(f[META_GROUP].attrs["metadata"])
            if CHAIN_GROUP not in f:
                raise ChainError(f"chain file {path} has no '{CHAIN_GROUP}' group: it holds no samples")
    except ChainError:
        raise
    except OSError as exc:  # h5py: "Unable to synchronously open file (bad superblock version number)"
        detail = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ChainError(f"cannot read chain file {path}: corrupt or truncated HDF5 file ({detail})") from None
    except (KeyError, ValueError, TypeError) as exc:
        raise ChainError(
            f"cannot read chain file {path}: its strauss-fit metadata is damaged ({type(exc).__name__})"
        ) from None
    return _check_metadata(path, meta, required)


def _write_metadata_group(f: h5py.File, meta: dict[str, Any]) -> None:
    if META_GROUP in f:
        del f[META_GROUP]
    g = f.create_group(META_GROUP)
    g.attrs["format"] = FORMAT
    g.attrs["format_version"] = FORMAT_VERSION
    g.attrs["metadata"] = json.dumps(meta, allow_nan=False)


def write_metadata(path: str | Path, meta: dict[str, Any]) -> None:
    """Create or replace the ``strauss_fit`` group of the chain file ``path`` (the emcee
    group is left alone), atomically (the file is rewritten, see the module docstring)."""
    backend = BufferedHDFBackend.load(path) if Path(path).exists() else BufferedHDFBackend(path)
    backend.write_metadata(meta)
    backend.persist()


@dataclass
class Chain:
    """A stored chain: ``chain`` (S, W, P), ``log_prob`` (S, W), ``accepted`` (W,), and
    the metadata written by :func:`run_sampler`."""

    path: str
    chain: np.ndarray
    log_prob: np.ndarray
    accepted: np.ndarray
    meta: dict[str, Any]
    _adjusted: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def labels(self) -> list[str]:
        return list(self.meta["labels"])

    def diagnostics(self, min_tau_multiple: float | None = None) -> Diagnostics:
        k = (
            min_tau_multiple
            if min_tau_multiple is not None
            else self.meta.get("min_tau_multiple", DEFAULT_MIN_TAU_MULTIPLE)
        )
        return diagnose(self.chain, self.log_prob, self.accepted, self.labels, k)

    def samples(self, discard: int | None = None, *, adjusted: bool = True) -> np.ndarray:
        """The flattened samples (n, P) after the burn-in (:func:`burn_in` unless given):
        with ``adjusted`` (the default) mapped as the chain's adjustment says (see
        :meth:`adjusted`), else the raw draws as sampled."""
        if discard is None:
            discard = burn_in(autocorrelation_times(self.chain), self.chain.shape[0])
        if adjusted:
            return self.adjusted(discard)[0]
        return self.chain[discard:].reshape(-1, self.chain.shape[-1])

    @property
    def adjustment(self) -> dict[str, Any]:
        """The chain's adjustment (``method`` "affine", "temperature" or "none"; see
        :mod:`strauss_fit.inference.adjustment`); ``{"method": "none"}`` for chains
        written without one."""
        value = self.meta.get("adjustment")
        return value if isinstance(value, dict) else {"method": "none"}

    def adjusted(self, discard: int | None = None) -> tuple[np.ndarray, int]:
        """The samples after the burn-in with the affine adjustment applied
        (θ' = θ̂ + A(θ − θ̂), A as stored when the chain was written, recomputed from the
        draws if the chain has grown since), those outside the prior box dropped; and how
        many were dropped. Without an affine adjustment, the raw samples and 0."""
        if discard is None:
            discard = burn_in(autocorrelation_times(self.chain), self.chain.shape[0])
        raw = self.chain[discard:].reshape(-1, self.chain.shape[-1])
        info = self.adjustment
        if info.get("method") != "affine":
            return raw, 0
        key = (discard, self.chain.shape[0])
        cached = self._adjusted.get(key)
        if cached is not None:
            return cached
        size = raw.shape[1]
        try:
            target = np.asarray(info["target_covariance"], dtype=np.float64)
            center = np.asarray(info["center"], dtype=np.float64)
            if target.shape != (size, size) or center.shape != (size,) or not np.all(np.isfinite(target)):
                raise ValueError("shape")
            stored = info.get("matrix")
            if stored is not None and info.get("steps") == self.chain.shape[0] and info.get("burn_in") == discard:
                matrix = np.asarray(stored, dtype=np.float64)
                if matrix.shape != (size, size) or not np.all(np.isfinite(matrix)):
                    raise ValueError("matrix")
            else:
                matrix = full_matrix(raw, target)
        except AdjustmentError as exc:
            raise ChainError(f"cannot adjust the chain {self.path}: {exc} (too few distinct draws?)") from None
        except (KeyError, TypeError, ValueError):
            raise ChainError(f"chain file {self.path}: its strauss-fit metadata is damaged ('adjustment')") from None
        prior = self.meta.get("prior", {})
        lower = np.array([prior.get(label, [-np.inf, np.inf])[0] for label in self.labels], dtype=np.float64)
        upper = np.array([prior.get(label, [-np.inf, np.inf])[1] for label in self.labels], dtype=np.float64)
        result = adjust_samples(raw, center, matrix, lower, upper)
        self._adjusted[key] = result
        return result


def load_chain(path: str | Path, *, required: bool = False) -> Chain:
    """Read a chain file written by :func:`run_sampler` (one-line errors otherwise: see
    :func:`read_metadata`, whose ``required`` says whether the metadata must hold what a
    report or a resume needs; the samples must be as many as the iteration count says,
    and finite)."""
    meta = read_metadata(path, required=required)
    try:
        with h5py.File(path, "r") as f:
            g = f[CHAIN_GROUP]
            iteration = int(g.attrs["iteration"])
            rows, chain_rows = g["chain"].shape[0], g["log_prob"].shape[0]
            if iteration <= 0:
                raise ChainError(f"chain file {path} holds no steps yet")
            if iteration > min(rows, chain_rows):
                raise ChainError(
                    f"chain file {path} is damaged: it says {iteration} steps but holds {min(rows, chain_rows)}"
                )
            chain = np.asarray(g["chain"][:iteration], dtype=np.float64)
            log_prob = np.asarray(g["log_prob"][:iteration], dtype=np.float64)
            accepted = np.asarray(g["accepted"][...])
    except ChainError:
        raise
    except (OSError, KeyError, ValueError, AttributeError, TypeError) as exc:
        raise ChainError(
            f"cannot read the samples in {path}: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}"
        ) from None
    if chain.ndim != 3 or log_prob.shape != chain.shape[:2] or accepted.shape != chain.shape[1:2]:
        raise ChainError(
            f"chain file {path} is damaged: its datasets' shapes disagree "
            f"(chain {chain.shape}, log_prob {log_prob.shape}, accepted {accepted.shape})"
        )
    if chain.shape[-1] != len(meta.get("labels", [])):
        raise ChainError(
            f"chain file {path} is inconsistent: {chain.shape[-1]} parameters but {len(meta.get('labels', []))} labels"
        )
    bad = int(np.sum(~np.isfinite(chain)))
    if bad:
        raise ChainError(f"chain file {path} is damaged: {bad} of its sample values are NaN or infinite")
    if np.any(np.isnan(log_prob)):
        raise ChainError(f"chain file {path} is damaged: some of its log-probabilities are NaN")
    if not np.all(np.isfinite(accepted)) or np.any(accepted < 0) or np.any(accepted > iteration):
        raise ChainError(f"chain file {path} is damaged: its acceptance counts are not between 0 and {iteration}")
    return Chain(str(path), chain, log_prob, accepted.astype(np.float64), meta)


# --- running ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class SampleSettings:
    """How long to sample, and with how many walkers (None: :func:`default_walkers`;
    :func:`run_sampler` takes the number of its starting points). The defaults are the
    ``balanced`` quality preset; :meth:`preset` gives the others."""

    max_steps: int = 10000
    min_tau_multiple: float = DEFAULT_MIN_TAU_MULTIPLE
    check_every: int = CHECK_EVERY
    seed: int = 0
    walkers: int | None = None

    @classmethod
    def preset(cls, name: str = DEFAULT_QUALITY, **overrides: Any) -> SampleSettings:
        """The sampling settings of quality preset ``name``
        (:data:`strauss_fit.fit.options.QUALITY_PRESETS`: ``walkers``,
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
    """Sample until the stopping rule of the module docstring holds.

    New chain: ``start`` (W, P) are the walkers' starting points and ``metadata`` (labels,
    prior, σ, ...) is written to the file's ``strauss_fit`` group; an existing file is
    replaced when the first steps are written. ``resume``: continue the chain in ``path``
    from its last state (``start`` is ignored). ``path=None`` keeps the chain in memory
    (tests, benchmarks). A KeyboardInterrupt is re-raised after every step so far is
    written; a failed write (a full disk) is a :class:`ChainError` and leaves the file as
    the previous write left it.
    """
    started = time.perf_counter()
    ndim = log_posterior.prior.lower.size
    if path is None:
        backend: emcee.backends.Backend = emcee.backends.Backend()
    elif resume:
        backend = BufferedHDFBackend.load(path)
    else:
        backend = BufferedHDFBackend(path)
        backend.replaces = [Path(p) for p in replaces]
    if resume:
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
    else:
        if start is None:
            raise ValueError("a new chain needs starting points")
        walkers = start.shape[0]
        if walkers < 2 * ndim or walkers % 2:
            raise ChainError(
                f"the number of walkers must be even and at least twice the number of "
                f"parameters ({2 * ndim}); got {walkers}"
            )
    meta: dict[str, Any] | None = None
    if path is not None:
        meta = (
            read_metadata(path, required=False)
            if resume
            else dict(metadata or {}, labels=list(log_posterior.prior.labels))
        )
        meta["min_tau_multiple"] = settings.min_tau_multiple
        backend.write_metadata(meta)  # in memory; on disk at the first write
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
    write_failed = False
    try:
        with deferred_interrupt() as interrupted:
            while done < settings.max_steps:
                chunk = min(check - done % check, settings.max_steps - done)
                t0 = time.perf_counter()
                # the state after the last step starts the next chunk
                for state in sampler.sample(  # noqa: B007, B020
                    state, iterations=chunk, store=True, skip_initial_state_check=True
                ):
                    done += 1
                    new_steps += 1
                    if interrupted():
                        raise KeyboardInterrupt
                    if path is not None and backend.persist_due():
                        sampling += time.perf_counter() - t0
                        backend.persist()
                        t0 = time.perf_counter()
                sampling += time.perf_counter() - t0
                if path is not None:
                    backend.flush()
                    if backend.persist_due():
                        backend.persist()
                tau = autocorrelation_times(backend.get_chain())
                tau_max = float(np.max(tau))
                stable = tau_previous is not None and abs(tau_max - tau_previous) < TAU_STABILITY * tau_max
                tau_previous = tau_max
                if progress is not None:
                    progress(
                        Progress(
                            done,
                            settings.max_steps,
                            new_steps,
                            tau_max,
                            int(math.ceil(settings.min_tau_multiple * tau_max)),
                            float(np.mean(backend.accepted / max(done, 1))),
                            new_steps / sampling if sampling > 0 else 0.0,
                        )
                    )
                if done >= settings.min_tau_multiple * tau_max and stable:
                    stopped = "converged"
                    break
    except ChainError:
        write_failed = True
        raise
    finally:
        # every step sampled is written, on Ctrl-C too (not after a failed write: the
        # chain on disk stays as the last successful write left it)
        if path is not None and not write_failed and (new_steps or resume):
            backend.persist()
    chain, log_prob = backend.get_chain(), backend.get_log_prob()
    diagnostics = diagnose(
        chain, log_prob, np.asarray(backend.accepted), list(log_posterior.prior.labels), settings.min_tau_multiple
    )
    return SampleRun(
        path=None if path is None else str(path),
        diagnostics=diagnostics,
        stopped=stopped,
        new_steps=new_steps,
        wall_s=time.perf_counter() - started,
        sampling_s=sampling,
        steps_per_s=new_steps / sampling if sampling > 0 else 0.0,
        chain=chain,
        log_prob=log_prob,
    )


# --- the whole workflow ------------------------------------------------------------------------


def _adjustment_target(adjust: str, fit_json: dict[str, Any], labels: list[str]) -> tuple[str, str, np.ndarray]:
    """The adjustment to make (``adjust``, or the default for ``auto``), why, and the fit's
    covariance V in the chain's label order (the noise sandwich when the fit used it)."""
    from .summaries import Laplace

    default, why = default_method(fit_json)
    if adjust == "auto":
        method, reason = default, why
    elif adjust == "none":
        method, reason = "none", "--adjust none"
    else:
        if (fit_json.get("uncertainty_method") or {}).get("name") != "noise sandwich":
            raise ChainError(
                f"--adjust {adjust} maps the chain to the fit's noise sandwich, but this fit's uncertainty is the "
                "Laplace approximation (the target's noise was unknown to it): give the fit the noise level "
                "(a sidecar, or fit's noise option), or use --adjust none"
            )
        method, reason = adjust, f"--adjust {adjust}: {why}"
    fitted = Laplace.from_fit(fit_json)
    if fitted.labels != list(labels):
        raise ChainError(
            f"the fit result's uncertainties are for {', '.join(fitted.labels)}, not {', '.join(labels)}: "
            "it does not belong to this problem"
        )
    target = fitted.covariance
    if method != "none" and not (np.all(np.isfinite(target)) and np.any(np.diag(target) > 0)):
        raise ChainError("the fit's noise sandwich has no finite, positive variance to adjust the chain to")
    return method, reason, target


def check_least_squares(
    fit_json: dict[str, Any], what: str = "the fit", remedy: str = "refit with --loss linear"
) -> None:
    """Refuse a fit whose loss is not least squares (``solver.loss``; results written
    before losses existed are least squares): the chain's likelihood is, so such a fit's
    optimum is not the chain's and its noise sandwich is another estimator's spread (see
    the module docstring)."""
    loss = loss_of(fit_json)
    if loss != "linear":
        raise ChainError(
            f"{what} minimised the {loss} loss, but sample's likelihood is least squares: the chain would centre "
            f"on the least-squares optimum, not on the fit's values, and the fit's ± is the spread of the {loss} "
            f"fit, not of the chain; {remedy} (or let sample fit first)"
        )


def _noise_level(sigma: float | None, fit_json: dict[str, Any], problem: Any, x_hat: np.ndarray) -> tuple[float, str]:
    """σ of the likelihood and where it comes from: given; the fit's noise level when it
    knew the target's noise; else estimated from the fit's residual."""
    if sigma is not None:
        return sigma, "given (--sigma)"
    residual = fit_json.get("residual") or {}
    noise = residual.get("noise")
    if (fit_json.get("uncertainty_method") or {}).get("name") == "noise sandwich" and isinstance(noise, list):
        level = np.asarray(noise, dtype=np.float64)
        if level.size and np.all(np.isfinite(level)) and np.all(level > 0):
            return float(np.sqrt(np.mean(level**2))), (
                f"the target's noise as the fit estimated it (source: {residual.get('noise_source', 'unknown')}), "
                "root mean square over the channels"
            )
    return estimate_sigma(problem, x_hat), "estimated from the fit's residual, sqrt(RSS/(N-P))"


def _store_adjustment(chain: Chain) -> None:
    """Compute the affine adjustment's matrix A from the chain's draws after burn-in and
    store it (with the steps and burn-in it was computed from, and the draws it drops) in
    the chain file's metadata; the raw chain is not touched."""
    discard = burn_in(autocorrelation_times(chain.chain), chain.chain.shape[0])
    raw = chain.chain[discard:].reshape(-1, chain.chain.shape[-1])
    info = dict(chain.adjustment)
    try:
        matrix = full_matrix(raw, np.asarray(info["target_covariance"], dtype=np.float64))
    except AdjustmentError as exc:
        raise ChainError(f"cannot adjust the chain {chain.path}: {exc} (too few distinct draws?)") from None
    info.update(matrix=matrix.tolist(), steps=int(chain.chain.shape[0]), burn_in=int(discard))
    chain.meta = dict(chain.meta, adjustment=info)
    chain._adjusted.clear()
    _, dropped = chain.adjusted(discard)
    info["dropped"] = int(dropped)
    write_metadata(chain.path, chain.meta)


@dataclass
class SampleResult:
    """What :func:`sample` did: the chain file, the summary written beside it (the
    document of :func:`strauss_fit.inference.summaries.summarise_chain` with this run's
    timings under ``run``) and the run itself."""

    path: Path
    summary_path: Path
    summary: dict[str, Any]
    run: SampleRun

    @property
    def trustworthy(self) -> bool:
        return bool(self.summary["diagnostics"]["trustworthy"])


class SamplingInterrupted(KeyboardInterrupt):
    """Ctrl-C while :func:`sample` was sampling: ``path`` keeps the ``steps`` stored so far."""

    def __init__(self, path: Path, steps: int):
        super().__init__(f"{path} keeps all {steps} steps sampled so far")
        self.path = path
        self.steps = steps


def stored_steps(path: str | Path) -> int:
    """How many steps the chain file ``path`` holds (0 if it holds none or cannot be read)."""
    try:
        return len(load_chain(path, required=False).chain)
    except StraussFitError:
        return 0


@uses_float64
def sample(
    target: str | Path,
    scene: str | Path,
    output: str | Path,
    *,
    mask: str | Path | None = None,
    encoding: str = "auto",
    fit: str | Path | FitResult | dict[str, Any] | None = None,
    fit_options: FitOptions | None = None,
    sigma: float | None = None,
    priors: dict[str, tuple[float, float]] | list[str] | None = None,
    settings: SampleSettings = SampleSettings(),
    quality: str = DEFAULT_QUALITY,
    adjust: str = "auto",
    resume: bool = False,
    force: bool = False,
    log: Callable[[str], None] | None = None,
    progress: Callable[[Progress], None] | None = None,
) -> SampleResult:
    """Sample the posterior of the Strauss parameters of ``scene`` given the image
    ``target`` into the chain file ``output``, and write its summary beside it
    (``output`` with the suffix ``.json``).

    ``target``, ``scene`` and ``mask`` are file paths, recorded in the chain so that a
    report or ``resume`` can reload them. The walkers start around the least-squares
    optimum of ``fit`` (a fit result, or the path of one's JSON) or, without it, of a fit
    made first with ``fit_options`` (default: the ``quality`` preset; its loss ``"auto"`` is
    least squares here). The fit must be a least-squares one (its loss ``"linear"``): the
    likelihood sampled is, and another loss's optimum and noise sandwich are not the
    chain's (see the module docstring); any other is refused. The noise level is
    ``sigma``; else the target's noise as the fit found it (the root mean square of its
    per-channel level) when the fit knew it (its uncertainty is the noise sandwich), else
    estimated from the fit's residual. The prior is the default box of
    :func:`strauss_fit.inference.posterior.default_prior` narrowed by ``priors`` (a dict
    ``{name: (low, high)}`` or ``NAME=LOW,HIGH`` strings). ``settings`` (see
    :meth:`SampleSettings.preset`) says how long to sample and with how many walkers.

    ``adjust`` (:data:`strauss_fit.inference.adjustment.METHODS`) makes the chain's width
    match the fit's noise sandwich on a target the model cannot reproduce:
    ``"affine"`` maps the draws on read (:meth:`Chain.adjusted`; the raw chain is kept),
    ``"temperature"`` samples with σ√T, ``"none"`` samples the Gaussian likelihood as it is;
    ``"auto"`` is ``"affine"`` when the fit's uncertainty is the noise sandwich and its
    verdict is a mismatch, else ``"none"`` (:mod:`strauss_fit.inference.adjustment`).

    ``resume`` continues the chain in ``output`` (its fit, σ, prior, walkers and adjustment are kept);
    otherwise an existing ``output`` is refused unless ``force``. ``log`` receives short
    status lines and ``progress`` a :class:`Progress` after every check. Ctrl-C while
    sampling raises :class:`SamplingInterrupted` (a KeyboardInterrupt) after every step so
    far is written.
    """
    log = log or (lambda message: None)
    out = Path(output)
    summary_path = out.with_suffix(".json")
    if summary_path == out:
        raise ChainError(f"the chain file needs an extension other than .json (the summary goes to {summary_path})")
    meta: dict[str, Any] = {}
    if resume:
        existing = load_chain(out, required=True)  # a damaged chain is refused before any work
        meta = existing.meta
        check_least_squares(
            meta["fit"],
            f"the fit {out} was started from",
            "start a new chain (--force) from a fit made with --loss linear",
        )
        check_writable(summary_path, True)
    else:
        check_writable(out, force)
        check_writable(summary_path, force)
    if priors is not None and not isinstance(priors, dict):
        priors = parse_priors(list(priors))
    if adjust not in ADJUST_METHODS:
        raise ChainError(f"unknown adjustment {adjust!r}; expected one of {', '.join(ADJUST_METHODS)}")

    loaded_scene = load_scene(scene)
    loaded_target = load_target(target, mask, encoding)
    loaded_scene, message = match_scene(loaded_scene, loaded_target)
    if message:
        log(message)

    if resume:
        problem, x_hat = problem_from_fit(loaded_scene, loaded_target, meta["fit"])
        if target_digest(problem) != meta.get("target_sha256"):
            raise ChainError(f"{out} was sampled for another target (the usable pixels of {target} differ)")
        if problem.layout.labels() != meta["labels"]:
            raise ChainError(f"{out} samples {', '.join(meta['labels'])}, not {', '.join(problem.layout.labels())}")
        sigma = float(meta["sigma"])
        kept = (meta.get("adjustment") or {}).get("method", "none")
        if adjust != "auto" and adjust != kept:
            raise ChainError(f"--adjust cannot change when resuming: {out} was started with --adjust {kept}")
        prior = Prior(
            tuple(meta["labels"]),
            np.array([meta["prior"][k][0] for k in meta["labels"]]),
            np.array([meta["prior"][k][1] for k in meta["labels"]]),
        )
        start = None
        log_posterior = LogPosterior(problem, prior, sigma)
        log(f"resuming {out} at step {len(existing.chain)}")
    else:
        if fit is None:
            options = fit_options or FitOptions.preset(quality)
            if options.loss == "auto":  # the likelihood sampled is least squares: so is the fit it starts from
                options = dataclasses.replace(options, loss="linear")
            if options.loss != "linear":
                raise ChainError(
                    f"sample fits first by least squares, the likelihood it samples; a fit with the {options.loss} "
                    "loss is refused"
                )
            result = run_fit(loaded_scene, loaded_target, options, progress=log)
            if result.solver["status"] != "successful":
                log(f"the fit ended with status '{result.solver['status']}'; sampling from where it stopped")
            fit = result
        if isinstance(fit, FitResult) and fit.problem is not None:
            fit_json = fit.to_json()
            fit_json["target"] = str(target)
            fit_json["scene"] = str(scene)
            check_least_squares(fit_json)
            problem, x_hat = fit.problem.unpadded(), fit.x  # one target: no padding
        else:
            fit_json = read_json(fit, "fit result") if isinstance(fit, (str, Path)) else fit
            if isinstance(fit_json, FitResult):
                fit_json = fit_json.to_json()
            check_least_squares(fit_json)
            problem, x_hat = problem_from_fit(loaded_scene, loaded_target, fit_json)
        method, reason, target_covariance = _adjustment_target(adjust, fit_json, problem.layout.labels())
        sigma, sigma_source = _noise_level(sigma, fit_json, problem, x_hat)
        prior = default_prior(problem.layout, x_hat, priors)
        ndim = problem.layout.size
        walkers = settings.walkers or default_walkers(ndim)
        if walkers < 2 * ndim:
            raise ChainError(f"--walkers must be at least twice the number of parameters ({2 * ndim}), got {walkers}")
        covariance = laplace.laplace_covariance(problem, x_hat, sigma)
        adjustment: dict[str, Any] = {"method": method, "reason": reason}
        if method != "none":
            adjustment.update(target_covariance=target_covariance.tolist(), center=[float(v) for v in x_hat])
        if method == "temperature":
            # the chain's covariance over the entries V covers, the others held as V holds
            # them (the block of the full Laplace covariance lets them move: wider, so T too small)
            use = adjusted_entries(target_covariance) & ~np.asarray(problem.pinned)
            post = laplace.posterior_covariance(problem, x_hat, sigma, use)
            try:
                factor = temperature(post[np.ix_(use, use)], target_covariance[np.ix_(use, use)])
            except AdjustmentError as exc:
                raise ChainError(f"cannot temper the likelihood: {exc}") from None
            adjustment.update(temperature=factor, sigma_untempered=sigma)
            log(f"tempering the likelihood: sigma x sqrt(T) = {sigma:.3g} x {np.sqrt(factor):.3g} (T = {factor:.3g})")
            sigma, covariance = sigma * float(np.sqrt(factor)), covariance * factor
            sigma_source += f", tempered by sqrt(T) = {np.sqrt(factor):.3g} (--adjust temperature)"
        log_posterior = LogPosterior(problem, prior, sigma)
        log("compiling the log-probability and placing the walkers")
        start = initial_walkers(x_hat, covariance, prior, walkers, np.random.default_rng(settings.seed), log_posterior)
        meta = {
            "fit": fit_json,
            "target": str(target),
            "scene": str(scene),
            "mask": None if mask is None else str(mask),
            "encoding": encoding,
            "target_sha256": target_digest(problem),
            "sigma": sigma,
            "sigma_source": sigma_source,
            "prior": prior.as_dict(),
            "x_hat": [float(v) for v in x_hat],
            "seed": settings.seed,
            "laplace_covariance": covariance.tolist(),
            "pixels_used": int(problem.target.shape[0]),
            "quality": quality,
            "adjustment": adjustment,
        }
    return run_and_summarise(
        log_posterior, out, summary_path, summarise_chain, start=start, settings=settings, metadata=meta, resume=resume,
        progress=progress,
    )  # fmt: skip


def run_and_summarise(
    log_posterior: Any,
    out: Path,
    summary_path: Path,
    summarise: Callable[[Chain], dict[str, Any]],
    *,
    start: np.ndarray,
    settings: SampleSettings,
    metadata: dict[str, Any],
    resume: bool,
    progress: Callable[[Progress], None] | None,
) -> SampleResult:
    """Run the sampler into the chain file ``out`` (:func:`run_sampler`), store an affine
    adjustment, and write ``summarise(chain)`` with the run's figures to ``summary_path``:
    the end of ``sample`` for single images and for captures. Ctrl-C raises
    :class:`SamplingInterrupted` after every step so far is written."""
    try:
        run = run_sampler(
            log_posterior,
            out,
            start=start,
            settings=settings,
            metadata=metadata,
            resume=resume,
            progress=progress,
            # --force: the old summary goes when the new chain replaces the old one
            replaces=() if resume else (summary_path,),
        )
    except KeyboardInterrupt:
        raise SamplingInterrupted(out, stored_steps(out)) from None
    chain = load_chain(out, required=True)
    if chain.adjustment.get("method") == "affine":
        _store_adjustment(chain)
    summary = summarise(chain)
    summary["run"] = {
        "stopped": run.stopped,
        "new_steps": run.new_steps,
        "wall_s": run.wall_s,
        "sampling_s": run.sampling_s,
        "steps_per_s": run.steps_per_s,
    }
    with Outputs(force=True) as written:
        written.add_json(summary_path, summary)
        written.commit(final=True)
    return SampleResult(out, summary_path, summary, run)
