"""Entry point of the ``strauss-fit`` command: subcommands, error handling, JAX set-up.

Every user error (a `strauss_fit.errors.StraussFitError`) is printed as one line,
``strauss-fit: error: ...``, with exit status 2; an interrupt (Ctrl-C, at any moment,
see `strauss_fit_cli.interrupts`) exits with 130 and leaves no output behind. A full
disk or another OSError is one line too. Nothing else is caught, so a real bug still shows
its traceback. Text the commands print passes through `strauss_fit_cli.common.escape`
(control characters from input files, such as terminal escape sequences, are shown as
``\\x1b``, never sent to the terminal).
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from . import interrupts

#: Names of the subcommand modules; each has ``add_parser(subparsers)`` and ``run(args)``.
COMMAND_MODULES = (
    "render_cmd",
    "fit_cmd",
    "synth_cmd",
    "sample_cmd",
    "report_cmd",
    "phong2strauss_cmd",
    "study_cmd",
    "lights_cmd",
    "compare_cmd",
)


def _load_numeric_libraries() -> None:
    """Import NumPy and JAX while an interrupt is only recorded: raised inside their
    compiled modules' imports, it would come back wrapped in an ImportError with a
    traceback in its message. First, the CPU devices: the command's process is its own, so it
    asks JAX for one per core before JAX starts (docs/commands/index.md#cpu-devices)."""
    from strauss_fit.runtime import keep_freed_memory, use_cpu_cores

    use_cpu_cores()
    keep_freed_memory()
    import jax.numpy  # noqa: F401
    import numpy  # noqa: F401


def _enable_compilation_cache() -> None:
    """Keep compiled XLA programs between runs (`strauss_fit.runtime.enable_compilation_cache`)."""
    from strauss_fit.runtime import enable_compilation_cache

    enable_compilation_cache()


class OneLineParser(argparse.ArgumentParser):
    """argparse, with a usage error as one line like every other error (exit status 2), and
    a help or version text that cannot be written an error too."""

    def error(self, message: str):
        from .common import escape

        self.exit(2, f"strauss-fit: error: {escape(message, newlines=True)} (see '{self.prog} --help')\n")

    def _print_message(self, message: str, file: Any = None) -> None:
        # argparse's own swallows an OSError of the write: `--help` or `--version` into a
        # full disk exited 0 with nothing written. Written and flushed here, a failure is
        # the command's one-line error (status 2); a closed pipe (`| head`) stays quiet, as
        # Python's own exit keeps it (`interrupts.leave_process`).
        if not message:
            return
        file = file or sys.stderr
        try:
            file.write(message)
            file.flush()
        except BrokenPipeError:
            pass
        except OSError as exc:
            name = "output" if file is sys.stdout else "error"
            raise OSError(exc.errno, f"cannot write the standard {name}: {exc.strerror or exc}") from None


def build_parser() -> argparse.ArgumentParser:
    import importlib

    parser = OneLineParser(
        prog="strauss-fit",
        description="Render, fit and compare the Strauss (1990) lighting model on sphere images.",
        epilog="Run 'strauss-fit COMMAND --help' for the options of each command. "
        "Set STRAUSS_FIT_CACHE_DIR=off to disable the compilation cache (~/.cache/strauss-fit/jax) "
        "and the traced kernels kept beside it.",
    )
    parser.add_argument("--version", action="version", version="%(prog)s " + _version())
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMAND_MODULES:
        importlib.import_module(f"{__package__}.{name}").add_parser(subparsers)
    return parser


def _version() -> str:
    from strauss_fit import __version__

    return __version__


def _error(message: str) -> None:
    from .common import escape

    print(f"strauss-fit: error: {escape(message, newlines=True)}", file=sys.stderr)


def console_main() -> None:
    """The ``strauss-fit`` command (the console script): `main` on the process's arguments,
    then the process ends with its status (`interrupts.leave_process`)."""
    interrupts.leave_process(main())


def main(argv: list[str] | None = None) -> int:
    """Run the command in ``argv`` (default: the process's arguments) and return its exit
    status. Without ``argv`` the call is taken for the ``strauss-fit`` process itself: Ctrl-C
    is watched for also inside blocking compiled code, and an interrupt ends the process."""
    from .common import EscapingStream

    previous = interrupts.install()
    if argv is None:  # the strauss-fit process itself: Ctrl-C also inside blocking compiled code
        interrupts.watch()
    stdout, stderr = sys.stdout, sys.stderr
    sys.stdout, sys.stderr = EscapingStream(stdout), EscapingStream(stderr)
    try:
        try:
            parser = build_parser()
            args = parser.parse_args(argv)  # --help ends here, having loaded no JAX
            _load_numeric_libraries()  # a Ctrl-C meanwhile is only recorded ...
            interrupts.arm()  # ... and raised here, as one recorded while Python was starting
            interrupts.check()
            _enable_compilation_cache()
            code = int(args.run(args) or 0)
            interrupts.check()
            return code
        except KeyboardInterrupt:
            raise
        except SystemExit as exc:  # argparse: --help, --version, usage errors (one line, status 2)
            if interrupts.HANDLER.pending:
                raise KeyboardInterrupt from None
            return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
        except BaseException as exc:
            # an interrupt that surfaced as another exception (raised inside a library
            # callback and re-wrapped) is still an interrupt
            if interrupts.HANDLER.pending:
                raise KeyboardInterrupt from None
            errors = sys.modules.get("strauss_fit.errors")
            if errors is not None and isinstance(exc, errors.StraussFitError):
                _error(str(exc))
                return 2
            if isinstance(exc, OSError):  # a full disk, a vanished folder: still one line
                _error(f"{exc.strerror or exc}{f': {exc.filename}' if exc.filename else ''}")
                return 2
            raise  # anything else is a bug: its traceback is shown
    except KeyboardInterrupt:
        interrupts.reset()
        print("strauss-fit: interrupted", file=sys.stderr)
        if argv is None:  # the strauss-fit process itself (tests call main with a list)
            interrupts.interrupted_exit(130)
        return 130
    finally:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):
                pass
        sys.stdout, sys.stderr = stdout, stderr
        if argv is not None:  # called from Python (tests, scripts): leave the process as it was
            interrupts.restore(previous)


if __name__ == "__main__":
    sys.exit(main())
