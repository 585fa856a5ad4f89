"""Ctrl-C from the first instant: record every interrupt, raise it where it can be handled.

Python turns SIGINT into a ``KeyboardInterrupt`` at the next bytecode, wherever that is.
During the first seconds of a run (imports, JAX start-up) that can be a callback whose
exceptions are printed and ignored (JAX's ``_xla_gc_callback``: "Exception ignored in ...
KeyboardInterrupt"), after which the run went on and wrote its outputs; or module code
outside ``main``'s ``try``, which gave a raw traceback.

This module needs nothing but the standard library, and the package's ``__init__``
installs :data:`HANDLER` before anything heavy is imported:

- before :func:`arm` (imports), an interrupt is only recorded (``HANDLER.pending``);
  ``main`` arms the handler inside its ``try`` and then raises what was recorded;
- after it, an interrupt is recorded *and* raised at once;
- a ``KeyboardInterrupt`` that a callback swallowed is recorded silently (through
  :data:`sys.unraisablehook`), and raised at the next safe point: :func:`check` (called by
  the commands' progress lines) or, at the latest, when the outputs are committed
  (:func:`strauss_fit.io.files.raise_if_interrupted` reads ``HANDLER.pending``).
"""

from __future__ import annotations

import signal
import sys
import threading


class InterruptHandler:
    """The SIGINT handler: ``pending`` is true once Ctrl-C was pressed; ``armed`` says
    whether it also raises KeyboardInterrupt at once; ``finished`` is set by the final
    commit of the command's outputs (:meth:`strauss_fit.io.files.Outputs.commit` with
    ``final=True``): the work is done and written, and a later Ctrl-C changes nothing."""

    def __init__(self) -> None:
        self.pending = False
        self.armed = False
        self.finished = False

    def __call__(self, signum, frame) -> None:
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
    for :func:`restore`."""
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
    """Put back the SIGINT handler and unraisable hook :func:`install` replaced."""
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
