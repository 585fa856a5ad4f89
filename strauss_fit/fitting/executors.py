r"""Where `strauss_fit.fit_many` runs its chunks of targets.

An executor has one method, ``run(jobs, chunks, arrived)``: fit the
`FitJob` s of every chunk (a list of indices into
``jobs``) and call ``arrived(index, result)`` in this process for each result as it comes.

- `InProcessExecutor` — here, chunk after chunk (`fit_chunk`);
  defined in `strauss_fit.fitting.batch`, beside that work, and re-exported here.
- `DaskExecutor` — on a ``dask.distributed`` cluster: a local one of ``workers``
  processes (one JAX runtime each), or an existing one at ``scheduler``. Each chunk is one
  task; a worker fits its chunk exactly as this process would and sends back the results
  as JSON documents plus the fitted images, which are rebuilt here into
  `FitResult` s (without the solved problem, which does not
  cross processes). Results are handed on as their chunk completes; a task whose worker
  dies is run again on another (``retries``), so a dead worker loses only its chunk's
  time. Targets and scenes given as paths are read by the workers: on a cluster of several
  machines they must see the same files. Needs ``pip install 'strauss-fit[dask]'``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from ..errors import StraussFitError
from .batch import FitFailure, FitJob, fit_chunk
from .batch import InProcessExecutor as InProcessExecutor  # the default, defined beside the work it runs
from .result import FitResult


def _portable(result: FitResult | FitFailure) -> dict[str, Any]:
    """A result as plain data that crosses processes (JSON document, images)."""
    if isinstance(result, FitFailure):
        return {"failure": result.target, "message": result.message}
    return {
        "json": result.to_json(),
        "fitted_image": None if result.fitted_image is None else np.asarray(result.fitted_image, dtype=np.float32),
        "mask": None if result.mask is None else np.asarray(result.mask),
        "used_index": None if result.used_index is None else np.asarray(result.used_index),
        "standardized_residual": None
        if result.standardized_residual is None
        else np.asarray(result.standardized_residual, dtype=np.float32),
        "target_image": None if result.target_image is None else np.asarray(result.target_image, dtype=np.float32),
    }


def _rebuilt(data: dict[str, Any]) -> FitResult | FitFailure:
    if "failure" in data:
        return FitFailure(data["failure"], data["message"])
    result = FitResult.from_json(data["json"])
    result.fitted_image = data["fitted_image"]
    result.mask = data["mask"]
    result.used_index = data["used_index"]
    result.standardized_residual = data["standardized_residual"]
    result.target_image = data["target_image"]
    return result


def fit_chunk_portable(jobs: Sequence[FitJob]) -> list[dict[str, Any]]:
    """`fit_chunk` on a worker, results as plain data (the
    worker uses the persistent compilation cache: a new worker loads what others compiled)."""
    from ..runtime import enable_compilation_cache

    enable_compilation_cache()
    return [_portable(result) for result in fit_chunk(jobs)]


#: Seconds to wait for a TCP connection to a scheduler before calling it unreachable.
CONNECT_TIMEOUT_S = 5.0


def check_reachable(address: str, timeout: float = CONNECT_TIMEOUT_S) -> None:
    """Fail fast, in one line, when nothing listens at a ``tcp://host:port`` scheduler
    address (a refused connection answers at once; Dask's client would retry for its whole
    timeout first). Other protocols are left to Dask."""
    import socket
    from urllib.parse import urlsplit

    parts = urlsplit(address if "://" in address else f"tcp://{address}")
    if parts.scheme != "tcp":
        return
    try:
        host, port = parts.hostname, parts.port
    except ValueError:
        raise StraussFitError(f"the Dask scheduler address {address} has no valid port") from None
    if not host or port is None:
        raise StraussFitError(f"the Dask scheduler address {address} needs a host and a port (tcp://host:8786)")
    try:
        with socket.create_connection((host, port), timeout=timeout):
            pass
    except OSError as error:
        reason = "timed out" if isinstance(error, TimeoutError) else (error.strerror or str(error))
        raise StraussFitError(f"cannot reach the Dask scheduler at {address}: {reason}") from None


#: Seconds for the whole handshake with a scheduler (Dask's own connect timeout covers the
#: connection, not a peer that accepts it and then says nothing).
HANDSHAKE_TIMEOUT_S = 20.0


def connect(address: str, timeout: float = HANDSHAKE_TIMEOUT_S) -> Any:
    """A ``dask.distributed.Client`` of the scheduler at ``address``, or a one-line error
    when what answers there is not a Dask scheduler: a program speaking another protocol
    (Dask then fails in its message decoder, even asking for exabytes of memory) or one
    that accepts the connection and never answers (Dask would wait for ever). The client
    is made in a daemon thread so that a peer that never answers cannot hold the command."""
    import threading

    from dask.distributed import Client

    outcome: dict[str, Any] = {}

    def make() -> None:
        try:
            outcome["client"] = Client(address, timeout=f"{min(timeout, 10.0):g}s")
        except BaseException as error:  # anything a foreign peer provokes
            outcome["error"] = error

    thread = threading.Thread(target=make, name="strauss-fit-dask-connect", daemon=True)
    thread.start()
    thread.join(timeout)
    if thread.is_alive():
        raise StraussFitError(
            f"the Dask scheduler at {address} did not answer within {timeout:g} s: is a Dask scheduler listening there?"
        )
    if "error" in outcome:
        error = outcome["error"]
        reason = (str(error).splitlines() or [type(error).__name__])[0]
        raise StraussFitError(f"{address} did not answer as a Dask scheduler: {reason}")
    return outcome["client"]


class DaskExecutor:
    """Fit the chunks on a Dask cluster (see the module docstring): ``workers`` local
    worker processes, or the cluster at ``scheduler`` (an address such as
    ``tcp://host:8786``), or an existing ``client``."""

    def __init__(
        self,
        workers: int | None = None,
        *,
        scheduler: str | None = None,
        client: Any = None,
        retries: int = 2,
    ):
        if sum(x is not None for x in (workers, scheduler, client)) != 1:
            raise StraussFitError("give the Dask executor one of: a number of workers, a scheduler address, a client")
        if workers is not None and workers < 1:
            raise StraussFitError(f"the number of Dask workers must be at least 1, got {workers}")
        self.workers, self.scheduler, self.client, self.retries = workers, scheduler, client, retries

    def _client(self):
        try:
            from dask.distributed import Client, LocalCluster
        except ImportError:
            raise StraussFitError("running on Dask needs dask.distributed: pip install 'strauss-fit[dask]'") from None
        if self.client is not None:
            return self.client, None
        if self.scheduler is not None:
            check_reachable(self.scheduler)
            return connect(self.scheduler), None
        # processes, one thread each: every worker has its own JAX runtime and compiles once
        cluster = None
        try:
            cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=True, dashboard_address=None)
            return Client(cluster), cluster
        except Exception as error:  # no threads or processes left, no memory, no port: one line
            if cluster is not None:
                try:
                    cluster.close()
                except Exception:
                    pass
            reason = str(error).splitlines()[0] if str(error) else type(error).__name__
            raise StraussFitError(
                f"cannot start a local Dask cluster of {self.workers} worker(s): {reason} (try fewer --workers)"
            ) from None

    def run(self, jobs: Sequence[FitJob], chunks: list[list[int]], arrived: Callable[[int, Any], None]) -> None:
        from dask.distributed import as_completed

        client, cluster = self._client()
        try:
            futures = {}
            for chunk in chunks:
                future = client.submit(fit_chunk_portable, [jobs[i] for i in chunk], retries=self.retries, pure=False)
                futures[future] = chunk
            for future in as_completed(futures):
                chunk = futures[future]
                try:
                    portable = future.result()
                except Exception as error:  # the chunk failed on every try: its targets fail
                    for index in chunk:
                        arrived(index, FitFailure(jobs[index].name, f"the Dask task failed: {error}", error))
                    continue
                for index, data in zip(chunk, portable):
                    arrived(index, _rebuilt(data))
        finally:
            if cluster is not None:
                client.close()
                cluster.close()
