"""Ctrl-C from the first instant: record every interrupt, raise it where it can be handled.

Python turns SIGINT into a ``KeyboardInterrupt`` at the next bytecode, wherever that is.
During the first seconds of a run (imports, JAX start-up) that can be a callback whose
exceptions are printed and ignored (JAX's ``_xla_gc_callback``: "Exception ignored in ...
KeyboardInterrupt"), after which the run went on and wrote its outputs; or module code
outside ``main``'s ``try``, which gave a raw traceback.

This module needs nothing but the standard library, and the package's ``__init__``
installs `HANDLER` before anything heavy is imported:

- before `arm` (imports), an interrupt is only recorded (``HANDLER.pending``);
  ``main`` arms the handler inside its ``try`` and then raises what was recorded;
- after it, an interrupt is recorded *and* raised at once;
- a ``KeyboardInterrupt`` that a callback swallowed is recorded silently (through
  `sys.unraisablehook`), and raised at the next safe point: `check` (called by
  the commands' progress lines) or, at the latest, when the outputs are committed
  (`strauss_fit.io.files.raise_if_interrupted` reads ``HANDLER.pending``).

A Python signal handler runs only when the main thread executes Python code. Inside a
blocking call of compiled code that never returns to Python (an image library opening a
FIFO, a read from a hung network file system) the handler never runs, and Ctrl-C seemed
lost. `watch` starts a *watchdog* thread for that: the C-level signal handler writes
every signal's number to a pipe (`signal.set_wakeup_fd`) even while the main thread
is stuck, and when a SIGINT has not reached the Python handler within
`WATCHDOG_GRACE_S`, the watchdog removes every staged temporary output
(`strauss_fit.io.files.remove_staged_temporaries`), prints "strauss-fit:
interrupted" and ends the process with status 130. Nothing is half-renamed: the commit's
renames run in Python with SIGINT deferred, which counts as handled.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time


class InterruptHandler:
    """The SIGINT handler: ``pending`` is true once Ctrl-C was pressed; ``armed`` says
    whether it also raises KeyboardInterrupt at once; ``finished`` is set by the final
    commit of the command's outputs (`strauss_fit.io.files.Outputs.commit` with
    ``final=True``): the work is done and written, and a later Ctrl-C changes nothing."""

    def __init__(self) -> None:
        self.pending = False
        self.armed = False
        self.finished = False
        #: SIGINTs that reached Python (this handler, or the commit's deferral, which
        #: counts here too): what the watchdog compares with the signals that arrived.
        self.calls = 0

    def __call__(self, signum, frame) -> None:
        self.calls += 1
        if self.finished:
            return
        self.pending = True
        if self.armed:
            raise KeyboardInterrupt


HANDLER = InterruptHandler()
_default_unraisablehook = sys.unraisablehook


def _unraisable(info) -> None:
    """A KeyboardInterrupt that could not be raised (inside a callback) is recorded, not printed."""
    if info.exc_type is not None and issubclass(info.exc_type, KeyboardInterrupt):
        HANDLER.pending = True
        return
    _default_unraisablehook(info)


def install() -> tuple | None:
    """Install the recording handler (main thread only; a no-op if SIGINT is ignored, as
    for a background job started by a non-interactive shell). Returns what it replaced,
    for `restore`."""
    if threading.current_thread() is not threading.main_thread():
        return None
    try:
        previous = signal.getsignal(signal.SIGINT)
        if previous is signal.SIG_IGN:
            return None
        signal.signal(signal.SIGINT, HANDLER)
    except (ValueError, OSError):  # pragma: no cover - no signals here
        return None
    global _default_unraisablehook
    hook = sys.unraisablehook
    if hook is not _unraisable:
        _default_unraisablehook = hook  # what other unraisable exceptions still go to
    sys.unraisablehook = _unraisable
    return previous, hook


def restore(previous: tuple | None) -> None:
    """Put back the SIGINT handler and unraisable hook `install` replaced."""
    if previous is None or threading.current_thread() is not threading.main_thread():
        return
    handler, hook = previous
    try:
        signal.signal(signal.SIGINT, handler if handler is not None else signal.SIG_DFL)
    except (ValueError, OSError):  # pragma: no cover
        pass
    sys.unraisablehook = hook


def arm() -> None:
    """From now on raise at once (a new command starts: not finished); first raise an
    interrupt recorded so far."""
    HANDLER.finished = False
    HANDLER.armed = True
    check()


def check() -> None:
    """Raise KeyboardInterrupt if an interrupt was recorded (a safe point)."""
    if HANDLER.pending and not HANDLER.finished:
        raise KeyboardInterrupt


def reset() -> None:
    """Forget a recorded interrupt (for in-process callers such as tests)."""
    HANDLER.pending = False


def interrupted_exit(code: int) -> None:
    """Leave the process at once with ``code`` after flushing the standard streams.

    Used after Ctrl-C in the ``strauss-fit`` process itself: the interrupt may have
    abandoned a JAX computation whose threads still run, and the interpreter's normal
    shutdown can then crash (a segmentation fault after "interrupted"). Nothing is left to
    write: the outputs were committed or discarded before."""
    import os

    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)


def leave_process(code: int) -> None:
    """Leave the ``strauss-fit`` process with ``code`` once its command has finished:
    the exit handlers run (``atexit``: logging, temporary folders, JAX's own), the standard
    streams are flushed, and the process ends without the interpreter's teardown of every
    module and of JAX's compiled programs — 0.2-0.3 s of a 1.5 s cached command on a
    2-core machine (docs/benchmarks.md#single-fit-speed), with nothing left to do: every
    output was written, closed and renamed into place before. A standard stream that
    cannot be flushed gives status 120, as Python's own exit does: quietly for a closed
    pipe (``| head``), with one line on stderr for anything else (a full disk)."""
    import atexit
    import contextlib

    atexit._run_exitfuncs()  # CPython's own exit runs these the same way
    for name, stream in (("output", sys.stdout), ("error", sys.stderr)):
        try:
            stream.flush()
        except BrokenPipeError:
            code = code or 120
        except (OSError, ValueError) as exc:
            code = code or 120
            why = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
            with contextlib.suppress(OSError):  # stderr may be the stream that failed
                os.write(2, f"strauss-fit: error: cannot write the standard {name}: {why}\n".encode())
    os._exit(code)


#: Seconds a SIGINT may wait for the Python handler before the watchdog ends the process:
#: longer than any pure-Python stretch between two bytecodes, short enough for a person.
WATCHDOG_GRACE_S = 3.0
_WATCHDOG: list[threading.Thread] = []


def watch(grace_s: float = WATCHDOG_GRACE_S) -> bool:
    """Start the watchdog for SIGINTs that cannot reach Python (see the module docstring);
    once per process, in the ``strauss-fit`` process only (it ends the process). Returns
    whether it runs. A no-op where SIGINT is not `HANDLER`'s (ignored, say)."""
    if _WATCHDOG:
        return True
    if threading.current_thread() is not threading.main_thread():
        return False
    if signal.getsignal(signal.SIGINT) is not HANDLER:
        return False
    read_end, write_end = os.pipe()
    os.set_blocking(write_end, False)
    try:
        signal.set_wakeup_fd(write_end, warn_on_full_buffer=False)
    except (ValueError, OSError):  # pragma: no cover - no wakeup fd on this platform
        os.close(read_end)
        os.close(write_end)
        return False
    thread = threading.Thread(
        target=_watchdog, args=(read_end, grace_s, HANDLER.calls), name="strauss-fit-sigint-watchdog", daemon=True
    )
    thread.start()
    _WATCHDOG.append(thread)
    return True


def _watchdog(read_end: int, grace_s: float, handled_before: int) -> None:
    """Count the SIGINTs the pipe reports (from ``handled_before``, the handler's count
    when the pipe was set up) and end the process when the handler falls behind."""
    arrived = handled_before
    while True:
        try:
            data = os.read(read_end, 64)
        except OSError:  # pragma: no cover
            return
        if not data:
            return
        count = data.count(signal.SIGINT)
        if not count:
            continue
        arrived += count
        # the Python handler (or the commit's deferral) runs at the main thread's next
        # bytecode: give it the grace period to catch up with every SIGINT so far
        deadline = time.monotonic() + grace_s
        while HANDLER.calls < arrived and time.monotonic() < deadline:
            time.sleep(0.05)
        if HANDLER.calls >= arrived or HANDLER.finished:
            arrived = max(arrived, HANDLER.calls)
            continue
        _force_exit()


def _force_exit() -> None:
    """The main thread is stuck in compiled code: leave no output behind and exit 130."""
    files = sys.modules.get("strauss_fit.io.files")
    if files is not None:
        files.remove_staged_temporaries()
    try:
        os.write(2, b"strauss-fit: interrupted\n")
    except OSError:  # pragma: no cover
        pass
    os._exit(130)
