"""Writing files safely, and reading JSON with one-line errors.

Every output goes through `Outputs`: each file is first written in full to a
temporary sibling (``.NAME.XXXXXXXX.tmp.EXT`` in the same folder), every write and the
final ``fsync`` checked, and only `Outputs.commit` renames the temporaries into
place, all of them together. Until then no output exists or is changed; if anything fails
before the commit — a full disk, a bad value, Ctrl-C — every temporary is removed and
the error names the file (``cannot write out.png: No space left on device``). An
existing file is never overwritten unless ``force`` is true.

Ctrl-C is honoured at the commit even when it was swallowed earlier (a
``KeyboardInterrupt`` raised inside a callback that ignores exceptions, such as JAX's
garbage-collection hook): a SIGINT handler that records the interrupt in a true
``pending`` attribute (the command line installs one, `strauss_fit_cli.interrupts`)
makes `raise_if_interrupted` raise. The renames themselves run with SIGINT deferred,
so an interrupt never leaves half of a command's outputs renamed.

`write_bytes`, `write_text` and `write_json` are one-file shorthands;
the image writer (`strauss_fit.io.images.write_image`) stages its encoded bytes the
same way.
"""

from __future__ import annotations

import errno
import json
import os
import signal
import stat
import tempfile
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from ..errors import ImageError, OutputExistsError, StraussFitError


class WriteError(StraussFitError):
    """An output could not be written (a full disk, a vanished folder, no permission)."""


def os_error_message(exc: OSError, path: str | Path | None = None) -> str:
    """``cannot write PATH: REASON`` for an OSError met while writing ``path``."""
    reason = exc.strerror or str(exc) or type(exc).__name__
    where = path if path is not None else exc.filename
    return f"cannot write {where}: {reason}" if where is not None else f"cannot write: {reason}"


def _kind(mode: int) -> str:
    """What a file that is neither a regular file nor a folder is, in words."""
    return "a FIFO" if stat.S_ISFIFO(mode) else "a socket" if stat.S_ISSOCK(mode) else "a device"


def check_replaceable(path: str | Path) -> Path:
    """Refuse, with or without ``--force``, an output path where something other than a
    regular file (or a link to one) stands: a folder, a device, a FIFO, a socket, a broken
    or looping symbolic link. Replacing ``/dev/null`` by a result, as root, would break the
    system; a folder is never a file's place."""
    path = Path(path)
    if not os.path.lexists(path):
        return path
    try:
        mode = os.stat(path).st_mode
    except OSError as exc:
        what = "a symbolic link loop" if exc.errno == errno.ELOOP else "a broken symbolic link"
        raise StraussFitError(
            f"output {path} is {what}: refusing to replace it; remove it or choose another name"
        ) from None
    if stat.S_ISDIR(mode):
        raise ImageError(f"output path is a directory: {path}")
    if not stat.S_ISREG(mode):
        raise StraussFitError(f"output {path} is {_kind(mode)}, not a regular file: strauss-fit never replaces it")
    return path


def check_writable(path: str | Path, force: bool) -> Path:
    """Refuse an existing output without ``force``, a path no output may replace
    (`check_replaceable`) and a missing parent folder."""
    path = check_replaceable(path)
    if path.exists() and not force:
        raise OutputExistsError(f"output {path} exists; pass --force to overwrite it")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise ImageError(f"output folder does not exist: {parent}")
    if not os.access(parent, os.W_OK):
        raise ImageError(f"output folder is not writable: {parent}")
    return path


def check_input_file(path: str | Path, what: str = "input", error: type[StraussFitError] = StraussFitError) -> Path:
    """``path`` if it is a regular file that can be opened for reading; otherwise a
    one-line ``error`` naming the problem: not found, a broken or looping symbolic link,
    a folder, or not a regular file at all (a FIFO, a socket, a device).

    Called before every input is opened: opening a FIFO blocks until something writes to
    it, inside an image library's C++ code where Ctrl-C cannot reach, and a device can
    stream forever. A folder scan already skips such files; a path named on the command
    line, in a list or in a manifest is checked here."""
    path = Path(path)
    try:
        status = os.stat(path)  # follows symbolic links
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise error(f"{what} {path} is a symbolic link loop") from None
        if exc.errno in (errno.ENOENT, errno.ENOTDIR):
            if os.path.islink(path):
                raise error(f"{what} {path} is a broken symbolic link (to {os.readlink(path)})") from None
            raise error(f"{what} not found: {path}") from None
        raise error(f"cannot read {what} {path}: {exc.strerror or exc}") from None
    if stat.S_ISDIR(status.st_mode):
        raise error(f"{what} path is a directory: {path}")
    if not stat.S_ISREG(status.st_mode):
        raise error(f"{what} {path} is not a regular file ({_kind(status.st_mode)})")
    return path


def _same_file(a: str | Path, b: str | Path) -> bool:
    try:
        if os.path.exists(a) and os.path.exists(b):
            return os.path.samefile(a, b)
    except OSError:
        pass
    return os.path.normcase(os.path.abspath(os.fspath(a))) == os.path.normcase(os.path.abspath(os.fspath(b)))


def check_distinct(paths: dict[str, str | Path | None], inputs: dict[str, str | Path | None] | None = None) -> None:
    """Refuse, before any work, two outputs of one command that name the same file
    (``{"-o": ..., "--mask": ...}``; None entries are skipped: the second would overwrite
    the first), and an output that names one of the command's ``inputs`` (``--force``
    would overwrite the input)."""
    named = [(option, path) for option, path in paths.items() if path is not None]
    for k, (option, path) in enumerate(named):
        for other, earlier in named[:k]:
            if _same_file(path, earlier):
                raise StraussFitError(f"{other} and {option} name the same file {path}: give two different names")
        for what, source in (inputs or {}).items():
            if source is not None and _same_file(path, source):
                raise StraussFitError(f"{option} {path} is the input {what}: give the output another name")


def check_outside(folder: str | Path, option: str, inputs: dict[str, str | Path | None]) -> None:
    """Refuse, before any work, an input that lies inside ``folder``, an output folder the
    command fills (``option`` names it): with ``--force`` it would be overwritten."""
    root = os.path.normcase(os.path.realpath(os.fspath(folder)))
    for what, source in inputs.items():
        if source is None:
            continue
        path = os.path.normcase(os.path.realpath(os.fspath(source)))
        if os.path.commonpath([root, path]) == root:
            raise StraussFitError(
                f"the input {what} {source} lies in {folder}, which {option} writes: move it or give {option} "
                "another name"
            )


# --- interrupts -------------------------------------------------------------------------------


def interrupt_pending() -> bool:
    """Whether the current SIGINT handler recorded an interrupt (see the module docstring)."""
    try:
        handler = signal.getsignal(signal.SIGINT)
    except (ValueError, OSError):  # pragma: no cover - no signals on this platform
        return False
    return bool(getattr(handler, "pending", False))


def raise_if_interrupted() -> None:
    """Raise KeyboardInterrupt if an interrupt was recorded but not acted on."""
    if interrupt_pending():
        raise KeyboardInterrupt


@contextmanager
def deferred_sigint(final: bool = False) -> Iterator[None]:
    """Run the block with SIGINT deferred: an interrupt during it is raised at its end (in
    the main thread; elsewhere a no-op). With ``final`` (the block finishes the command's
    work), it is not raised, and a handler that has an ``armed`` attribute (the command
    line's) is disarmed and marked ``finished``: the command is complete and exits as if
    Ctrl-C had come a moment later."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []
    previous = signal.getsignal(signal.SIGINT)

    def record(signum, frame):
        received.append(signum)
        if hasattr(previous, "calls"):  # handled, for the command line's watchdog
            previous.calls += 1
        if hasattr(previous, "pending") and not final:
            previous.pending = True

    signal.signal(signal.SIGINT, record)
    try:
        yield
        if final and hasattr(previous, "armed"):
            previous.armed = False
            previous.finished = True
    finally:
        signal.signal(signal.SIGINT, previous)
    if received and not final:
        raise KeyboardInterrupt


# --- writing ----------------------------------------------------------------------------------


def _write_file(path: Path, data: bytes | memoryview) -> None:
    """Write ``data`` to the new file ``path`` and fsync it; every step checked (this is the
    one function through which every output's bytes reach the disk)."""
    with open(path, "wb") as handle:
        handle.write(data)
        handle.flush()
        os.fsync(handle.fileno())


def _append_file(path: Path, data: bytes) -> None:
    """Append ``data`` to ``path`` (created if missing) and fsync; on any failure the file
    is truncated back to its length before (an append is all or nothing)."""
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o666)
    try:
        size = os.fstat(fd).st_size
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view) :]
            os.fsync(fd)
        except BaseException:
            try:
                os.ftruncate(fd, size)
            except OSError:
                pass
            raise
    finally:
        os.close(fd)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _fsync_folder(folder: Path) -> None:
    """Make the renames in ``folder`` durable (best effort: not every system allows it)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


#: Every temporary that an `Outputs` has staged and not yet renamed or removed, in
#: this process: what `remove_staged_temporaries` removes when the process must end
#: at once (the command line's Ctrl-C watchdog, `strauss_fit_cli.interrupts`).
_STAGED_TEMPORARIES: set[Path] = set()


def remove_staged_temporaries() -> None:
    """Remove every staged temporary of this process (safe from any thread)."""
    for tmp in list(_STAGED_TEMPORARIES):
        try:
            os.unlink(tmp)
        except OSError:
            pass
        _STAGED_TEMPORARIES.discard(tmp)


class Outputs:
    """Outputs written together: `add` writes each to a temporary sibling at once,
    `commit` renames them all into place; leaving the ``with`` block by an exception
    (or without a commit) removes every temporary and touches no output.

    .. code-block:: python

        with Outputs(force=args.force) as out:
            out.add_json("result.json", payload)
            out.add_bytes("fit.png", png)
            out.commit()
    """

    def __init__(self, *, force: bool = False):
        self.force = force
        self._staged: list[tuple[Path, Path]] = []
        self.committed: list[Path] = []

    def __enter__(self) -> Outputs:
        return self

    def __exit__(self, *exc_info: Any) -> None:
        self.discard()

    def add_bytes(self, path: str | Path, data: bytes | memoryview) -> Path:
        """Write ``data`` to a temporary sibling of ``path`` (renamed at `commit`)."""
        path = check_writable(path, self.force)
        if any(final == path for _, final in self._staged):
            raise StraussFitError(f"{path} is written twice by one command")
        folder = path.parent if str(path.parent) else Path(".")
        try:
            fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=f".tmp{path.suffix}", dir=folder)
        except OSError as exc:
            raise WriteError(os_error_message(exc, path)) from None
        os.close(fd)
        tmp = Path(name)
        _STAGED_TEMPORARIES.add(tmp)
        try:
            _write_file(tmp, data)
        except BaseException as exc:
            tmp.unlink(missing_ok=True)
            _STAGED_TEMPORARIES.discard(tmp)
            if isinstance(exc, OSError):
                raise WriteError(os_error_message(exc, path)) from None
            raise
        self._staged.append((tmp, path))
        return path

    def add_text(self, path: str | Path, text: str) -> Path:
        return self.add_bytes(path, text.encode("utf-8"))

    def add_json(self, path: str | Path, data: Any) -> Path:
        """JSON, indented; NaN and infinity are refused (they are not JSON)."""
        return self.add_text(path, json.dumps(data, indent=2, allow_nan=False) + "\n")

    def commit(self, *, final: bool = False) -> list[Path]:
        """Rename every temporary into place (SIGINT deferred meanwhile) and return the
        outputs. An interrupt recorded before is raised first, and nothing is renamed; one
        during the renames is raised after them, unless ``final`` says that these outputs
        complete the command (see `deferred_sigint`)."""
        raise_if_interrupted()
        mode = 0o666 & ~_umask()
        folders = []
        try:
            with deferred_sigint(final):
                while self._staged:
                    tmp, final = self._staged[0]
                    os.chmod(tmp, mode)  # mkstemp made it owner-only
                    os.replace(tmp, final)
                    _STAGED_TEMPORARIES.discard(tmp)
                    self._staged.pop(0)
                    self.committed.append(final)
                    if final.parent not in folders:
                        folders.append(final.parent)
        except OSError as exc:
            raise WriteError(os_error_message(exc, self._staged[0][1] if self._staged else None)) from None
        for folder in folders:
            _fsync_folder(folder if str(folder) else Path("."))
        return list(self.committed)

    def discard(self) -> None:
        """Remove every temporary not yet committed."""
        while self._staged:
            tmp, _ = self._staged.pop()
            try:
                tmp.unlink(missing_ok=True)
            except OSError:
                pass
            _STAGED_TEMPORARIES.discard(tmp)


def write_bytes(path: str | Path, data: bytes, *, force: bool = False) -> Path:
    """Write bytes (e.g. an encoded PNG) atomically (refusing to overwrite without ``force``)."""
    with Outputs(force=force) as out:
        out.add_bytes(path, data)
        return out.commit()[0]


def write_text(path: str | Path, text: str, *, force: bool = False) -> Path:
    """Write a text file atomically (refusing to overwrite without ``force``)."""
    return write_bytes(path, text.encode("utf-8"), force=force)


def write_json(path: str | Path, data: Any, *, force: bool = False) -> Path:
    """Write JSON atomically; NaN/inf are refused (they are not JSON)."""
    return write_text(path, json.dumps(data, indent=2, allow_nan=False) + "\n", force=force)


def read_json(path: str | Path, what: str = "JSON file") -> Any:
    """Read a JSON file, with one-line errors."""
    path = check_input_file(path, what)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:  # JSONDecodeError, UnicodeDecodeError, an integer of > 4300 digits
        raise StraussFitError(f"cannot read {what} {path}: {exc}") from None
    except RecursionError:
        raise StraussFitError(f"cannot read {what} {path}: nested too deeply") from None


def no_space(path: str | Path) -> OSError:
    """The OSError of a full disk for ``path`` (for tests and fault injection)."""
    return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
