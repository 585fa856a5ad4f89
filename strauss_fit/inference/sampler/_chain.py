"""Reading and writing chain files: the metadata (`read_metadata`,
`write_metadata`) and the stored chain (`load_chain`, `Chain`).

Reading checks what it reads (metadata with every key a report or a resume needs, as many
rows as the iteration count says, finite samples), so that a damaged file is a one-line
`ChainError` rather than a traceback further on.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from ..adjustment import AdjustmentError, adjust_samples, full_matrix
from ._backends import BufferedHDFBackend
from ._diagnostics import DEFAULT_MIN_TAU_MULTIPLE, Diagnostics, autocorrelation_times, burn_in, diagnose
from ._format import CHAIN_GROUP, FORMAT, FORMAT_VERSION, META_GROUP, ChainError


def _check_file(path: Path) -> None:
    """One-line errors for a path that is not a readable HDF5 file (before h5py says it worse)."""
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


#: Metadata keys every chain of `sample` holds, and what each must be.
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


def write_metadata(path: str | Path, meta: dict[str, Any]) -> None:
    """Create or replace the ``strauss_fit`` group of the chain file ``path`` (the emcee
    group is left alone), atomically (the file is rewritten, see `strauss_fit.inference.sampler`)."""
    backend = BufferedHDFBackend.load(path) if Path(path).exists() else BufferedHDFBackend(path)
    backend.write_metadata(meta)
    backend.persist()


@dataclass
class Chain:
    """A stored chain: ``chain`` (S, W, P), ``log_prob`` (S, W), ``accepted`` (W,), and
    the metadata written by `run_sampler`."""

    path: str
    chain: np.ndarray
    log_prob: np.ndarray
    accepted: np.ndarray
    meta: dict[str, Any]
    _adjusted: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def labels(self) -> list[str]:
        """The parameters' names, in the order of the chain's last axis."""
        return list(self.meta["labels"])

    def diagnostics(self, min_tau_multiple: float | None = None) -> Diagnostics:
        """`diagnose` of the chain, against ``min_tau_multiple`` (default: the one it was sampled with)."""
        k = (
            min_tau_multiple
            if min_tau_multiple is not None
            else self.meta.get("min_tau_multiple", DEFAULT_MIN_TAU_MULTIPLE)
        )
        return diagnose(self.chain, self.log_prob, self.accepted, self.labels, k)

    def samples(self, discard: int | None = None, *, adjusted: bool = True) -> np.ndarray:
        """The flattened samples (n, P) after the burn-in (`burn_in` unless given):
        with ``adjusted`` (the default) mapped as the chain's adjustment says (see
        `adjusted`), else the raw draws as sampled."""
        if discard is None:
            discard = burn_in(autocorrelation_times(self.chain), self.chain.shape[0])
        if adjusted:
            return self.adjusted(discard)[0]
        return self.chain[discard:].reshape(-1, self.chain.shape[-1])

    @property
    def adjustment(self) -> dict[str, Any]:
        """The chain's adjustment (``method`` "affine", "temperature" or "none"; see
        `strauss_fit.inference.adjustment`); ``{"method": "none"}`` for chains
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
    """Read a chain file written by `run_sampler` (one-line errors otherwise: see
    `read_metadata`, whose ``required`` says whether the metadata must hold what a
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
