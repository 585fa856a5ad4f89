"""Kernels traced and lowered once, kept on disk with `jax.export`.

JAX's persistent compilation cache (`strauss_fit.runtime`) spares a new process the
XLA compilation of a kernel, but not its *tracing* (running the Python of the solvers,
renders and Jacobians to build a jaxpr) nor the lowering of that jaxpr to StableHLO: for a
single 64² fit, several seconds per process. Here each kernel call's traced and lowered
program is serialised with `jax.export.export` the first time, and later processes
deserialise it and run ``exported.call`` inside ``jax.jit`` (tracing that is one
primitive; the XLA compilation of the result then hits the compilation cache).

Where: beside the compilation cache, in the folder ``<cache folder>-export`` (by default
``~/.cache/strauss-fit/jax-export``; ``STRAUSS_FIT_CACHE_DIR=PATH`` moves both,
``STRAUSS_FIT_CACHE_DIR=off`` turns both off). ``STRAUSS_FIT_EXPORT_CACHE=off`` turns
only this one off; ``STRAUSS_FIT_EXPORT_CACHE=PATH`` moves it. It is on only where the
compilation cache was enabled (`strauss_fit.runtime.enable_compilation_cache`: the
command line, Dask workers), never for the library used directly.

One file per program, named by a SHA-256 digest of: the kernel's identity (module-level
functions of `strauss_fit` only), the static (non-array) part of its arguments (its
tree structure and the ``repr`` of its leaves, which must be plain: numbers, strings,
None; `strauss_fit.engine.StaticPart.describe`), the tree structure, shapes,
dtypes and weak types of the array leaves, JAX's tracing context (the ``jax_enable_x64``
scope and the other settings that key ``jax.jit``'s own cache, less the default device:
one program serves every device), the versions of jax, jaxlib, equinox, lineax,
optimistix and numpy, equinox's ``EQX_*`` environment settings, and a hash of the source
files of `strauss_fit`. A static part whose ``repr`` is not stable between
processes (it shows an address, ``0x…``) is not kept on disk. The file holds the
serialised program, the output's structure and its non-array part (pickled), or a marker
saying that the program cannot be exported (host callbacks: ``eqx.error_if``,
``jax.debug.print``), so that later processes do not try again. Files are written to a
temporary name and renamed (``os.replace``), so that a reader never sees half a file and
two processes writing the same entry leave one whole one. Nothing is ever evicted.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import pickle
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import numpy as np

from ._environment import turned_off

#: Bump when the file layout changes.
FORMAT = 2

_folder: Path | None = None
_environment: str | None = None


def configure(compilation_cache: Path | None) -> Path | None:
    """Turn the export cache on beside ``compilation_cache`` (None: off); returns its folder."""
    global _folder
    setting = os.environ.get("STRAUSS_FIT_EXPORT_CACHE")
    if compilation_cache is None or turned_off(setting):
        _folder = None
        return None
    try:  # jax.export's serialisation needs it (not a dependency of jax itself)
        import flatbuffers  # noqa: F401
    except ImportError:
        _folder = None
        return None
    folder = Path(setting) if setting else compilation_cache.with_name(compilation_cache.name + "-export")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        folder = None
    _folder = folder
    return folder


def folder() -> Path | None:
    """The folder programs are kept in, or None when the export cache is off."""
    return _folder


def kernel_identity(fn: Callable[..., Any]) -> str | None:
    """The name under which ``fn``'s programs are kept, or None where they must not be:
    only module-level functions of `strauss_fit`, whose source is in the digest (a
    lambda, a closure or a function of other code may change, or capture values, unseen)."""
    module, qualname = getattr(fn, "__module__", None) or "", getattr(fn, "__qualname__", None) or "<"
    if not module.startswith("strauss_fit.") or "<" in qualname or getattr(fn, "__closure__", None):
        return None
    return f"{module}.{qualname}"


def _source_digest() -> str:
    root = Path(__file__).resolve().parent
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(str(path.relative_to(root)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def _environment_digest() -> str:
    global _environment
    if _environment is None:
        from importlib import metadata

        versions = []
        for name in ("jax", "jaxlib", "equinox", "lineax", "optimistix", "numpy"):
            try:
                versions.append((name, metadata.version(name)))
            except metadata.PackageNotFoundError:
                versions.append((name, None))
        # equinox reads EQX_ON_ERROR & co. at import, and they change what is traced
        settings = sorted((k, v) for k, v in os.environ.items() if k.startswith("EQX_"))
        _environment = repr((FORMAT, versions, settings, jax.default_backend(), _source_digest()))
    return _environment


def _trace_context() -> tuple:
    """JAX's tracing context (what keys ``jax.jit``'s own cache) and the float64 scope,
    without the default device: a program does not depend on it (``jax.jit`` places each
    call), and a batch on another CPU device would otherwise keep its own copy. Cheap and
    hashable: it keys every call's lookup in memory (`ExportedKernel.call`)."""
    try:
        from jax._src import config

        items = tuple(None if isinstance(item, jax.Device) else item for item in config.trace_context())
    except Exception:  # a private API: fall back to the one setting known to matter
        items = ()
    return items + (jax.dtypes.canonicalize_dtype(np.float64),)


def _context_text(context: tuple) -> str:
    """`_trace_context` as text for the digest (parts that show an address left out)."""
    return repr([part for part in map(repr, context) if " at 0x" not in part])


#: Static leaves whose ``repr`` tells any two different values apart.
_PLAIN = (bool, int, float, complex, str, bytes, type(None))


class ExportedKernel:
    """``fn(arrays, static)`` through exported programs kept on disk; one per
    `strauss_fit.engine._DispatchingJit`, whose ``fn`` rebuilds a kernel's
    arguments from their arrays and their `strauss_fit.engine.StaticPart`.
    `call` returns None where the call cannot go this way (the caller then runs its
    ``jax.jit``)."""

    def __init__(self, fn: Callable[..., Any], identity: str):
        self.fn = fn
        self.identity = identity
        # in this process: (folder, static, structure, shapes, context) -> (jitted call, output
        # structure, output rest), or False where the call must go through plain jax.jit
        self._memo: dict[Any, Any] = {}

    def call(self, dynamic: Any, static: Any) -> Any:
        where = _folder
        if where is None:
            return None
        leaves, treedef = jax.tree.flatten(dynamic)
        avals = tuple((np.shape(x), np.dtype(x.dtype).str, bool(getattr(x, "weak_type", False))) for x in leaves)
        context = _trace_context()
        memo_key = (where, static, treedef, avals, context)
        entry = self._memo.get(memo_key)
        if entry is None:
            entry = self._load_or_export(where, leaves, treedef, avals, static, context)
            self._memo[memo_key] = entry
        if entry is False:
            return None
        run, out_treedef, rest = entry
        try:
            outputs = run(*leaves)
        except Exception:  # a kept program that will not lower or compile here: trace instead
            # (errors inside the running program surface later, when results are read)
            self._memo[memo_key] = False
            return None
        arrays = jax.tree.unflatten(out_treedef, outputs)
        return eqx.combine(arrays, rest) if rest is not None else arrays

    def _digest(self, treedef: Any, avals: tuple, static: Any, context: tuple) -> str | None:
        static_text = static.describe(_PLAIN)
        if static_text is None:  # a leaf whose repr may not tell two values apart
            return None
        described = repr((self.identity, static_text, str(treedef), avals))
        if " at 0x" in described:  # an address: not the same in the next process
            return None
        text = described + _context_text(context) + _environment_digest()
        return hashlib.sha256(text.encode()).hexdigest()

    def _load_or_export(
        self, where: Path, leaves: list, treedef: Any, avals: tuple, static: Any, context: tuple
    ) -> Any:
        digest = self._digest(treedef, avals, static, context)
        if digest is None:
            return False
        path = where / f"{self.identity.rsplit('.', 1)[-1]}-{digest[:40]}.pkl"
        try:
            return _loaded(pickle.loads(path.read_bytes()))
        except Exception:  # missing, damaged or foreign: export (again) and overwrite it
            pass
        stored = self._export(leaves, treedef, static)
        _write_atomically(path, pickle.dumps(stored, protocol=pickle.HIGHEST_PROTOCOL))
        try:
            return _loaded(stored)
        except Exception:  # exported, but not loadable here: trace instead
            return False

    def _export(self, leaves: list, treedef: Any, static: Any) -> dict[str, Any]:
        found: list[Any] = []

        def flat(*flat_leaves):
            out = self.fn(jax.tree.unflatten(treedef, flat_leaves), static)
            arrays, rest = eqx.partition(out, eqx.is_array)
            out_leaves, out_treedef = jax.tree.flatten(arrays)
            found[:] = [out_treedef, rest]
            return out_leaves

        flat.__name__ = self.identity.rsplit(".", 1)[-1]
        specs = [
            jax.ShapeDtypeStruct(np.shape(x), x.dtype, weak_type=bool(getattr(x, "weak_type", False))) for x in leaves
        ]
        try:
            # custom calls (LAPACK's ormqr in lineax's QR solve) are allowed: their lack of
            # compatibility guarantees does not matter, the file is read by this jaxlib only
            # (its version is in the digest). Host callbacks are still refused by jax.export.
            # ("ALL": undocumented, see jax/_src/export/_export.py _check_module; were it
            # to go, the export fails and the kernel is marked unsupported: only time lost)
            allow = [jax.export.DisabledSafetyCheck.custom_call("ALL")]
            exported = jax.export.export(jax.jit(flat), disabled_checks=allow)(*specs)
            stored = {
                "exported": bytes(exported.serialize()),
                # the output with 0 for its arrays: a PyTreeDef does not pickle faithfully
                # (equinox's Modules compare a sentinel in their aux data by identity)
                "out_template": jax.tree.unflatten(found[0], [0] * found[0].num_leaves),
                "rest": found[1] if jax.tree.leaves(found[1]) else None,
            }
            pickle.dumps(stored)  # the output's structure and rest must pickle
        except Exception as error:  # host callbacks, unstable custom calls, unpicklable output
            return {"unsupported": True, "why": f"{type(error).__name__}: {error}"[:2000]}
        return stored


def _loaded(stored: Any) -> Any:
    """A stored entry ready to call: (jitted call, output structure, output rest), or False
    for a kernel marked as not exportable. Raises on anything else."""
    if stored.get("unsupported"):
        return False
    exported = jax.export.deserialize(bytearray(stored["exported"]))
    return jax.jit(exported.call), jax.tree.structure(stored["out_template"]), stored["rest"]


def _write_atomically(path: Path, data: bytes) -> None:
    try:
        handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=path.name + ".", suffix=".tmp")
        try:
            with os.fdopen(handle, "wb") as file:
                file.write(data)
            os.replace(temporary, path)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(temporary)
            raise
    except OSError:  # a full disk, a read-only folder: only costs time
        pass
