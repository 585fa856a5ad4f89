"""Entry point of the ``strauss-fit`` command: subcommands, error handling, JAX set-up.

Every user error (a :class:`strauss_fit.errors.StraussFitError`) is printed as one line,
``strauss-fit: error: ...``, with exit status 2; an interrupt exits with 130. Nothing else is
caught, so a real bug still shows its traceback.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from . import fit_cmd, phong2strauss_cmd, render_cmd, report_cmd, sample_cmd, study_cmd, synth_cmd

#: Subcommand modules; each has ``add_parser(subparsers)`` and ``run(args)``.
COMMANDS = [render_cmd, fit_cmd, synth_cmd, sample_cmd, report_cmd, phong2strauss_cmd, study_cmd]


def _enable_compilation_cache() -> None:
    """Keep compiled XLA programs between runs, so repeated CLI calls skip compilation."""
    import jax

    cache = os.environ.get("STRAUSS_FIT_CACHE_DIR") or str(Path.home() / ".cache" / "strauss-fit" / "jax")
    if cache.lower() in ("", "off", "none", "0"):
        return
    try:
        Path(cache).mkdir(parents=True, exist_ok=True)
    except OSError:
        return  # an unwritable cache only costs speed
    jax.config.update("jax_compilation_cache_dir", cache)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="strauss-fit",
        description="Render, fit and compare the Strauss (1990) lighting model on sphere images.",
        epilog="Run 'strauss-fit COMMAND --help' for the options of each command. "
        "Set STRAUSS_FIT_CACHE_DIR=off to disable the compilation cache (~/.cache/strauss-fit/jax).",
    )
    parser.add_argument("--version", action="version", version="%(prog)s " + _version())
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module in COMMANDS:
        module.add_parser(subparsers)
    return parser


def _version() -> str:
    from strauss_fit import __version__

    return __version__


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    from strauss_fit.errors import StraussFitError

    try:
        _enable_compilation_cache()
        return int(args.run(args) or 0)
    except StraussFitError as exc:
        print(f"strauss-fit: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("strauss-fit: interrupted", file=sys.stderr)
        return 130
    except OSError as exc:  # a full disk, a vanished folder: still one line
        print(
            f"strauss-fit: error: {exc.strerror or exc}{f': {exc.filename}' if exc.filename else ''}", file=sys.stderr
        )
        return 2


if __name__ == "__main__":
    sys.exit(main())
