"""The chain file held in memory while sampling: `BufferedHDFBackend`.

Why: HDF5 cannot survive a full disk (a failed write inside it can crash the process and
leave a file that no longer opens), so HDF5 never writes to the disk here; the whole file
image is written atomically instead (see "Writing the chain safely" in
`strauss_fit.inference.sampler`).
"""

from __future__ import annotations

import io
import time
from pathlib import Path
from typing import Any

import emcee
import h5py
import numpy as np

from ...io.files import Outputs, WriteError
from ._format import CHAIN_GROUP, ChainError, write_metadata_group

#: The chain file is written at least this often (seconds) while sampling ...
FLUSH_SECONDS = 2.0
#: ... or less often, so that writing it takes at most this share of the time.
PERSIST_SHARE = 0.1
#: Steps per HDF5 chunk of the chain and log-probability datasets.
CHUNK_STEPS = 64


class BufferedHDFBackend(emcee.backends.HDFBackend):
    """emcee's HDF5 backend, same file layout, but the HDF5 file lives in memory: steps are
    buffered until `flush` adds them to the in-memory file, and only `persist`
    writes the file to ``filename`` (atomically, every write checked; see
    `strauss_fit.inference.sampler`). ``image`` is the bytes of an existing chain file (to resume it)."""

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
        """emcee's layout, with chunks of `CHUNK_STEPS` whole steps (h5py's automatic
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
            write_metadata_group(f, meta)

    def persist_due(self) -> bool:
        """Whether the file is due to be written (see `FLUSH_SECONDS`)."""
        interval = max(FLUSH_SECONDS, self.persist_seconds / PERSIST_SHARE)
        return time.perf_counter() - self.last_persist >= interval

    def persist(self) -> None:
        """Flush, then write the whole file to ``filename``: a temporary file, every write
        and the fsync checked, renamed over the chain. A failure (a full disk) leaves the
        chain on disk as it was and raises a `ChainError` saying how many steps it
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
