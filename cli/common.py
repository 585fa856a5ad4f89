"""Helpers shared by several subcommands: argparse types, checks, escaping what input files
bring to the terminal, progress lines. The option groups themselves are added by
`strauss_fit_cli._options`; the quality presets live in the library
(`strauss_fit.fitting.options.QUALITY_PRESETS`)."""

from __future__ import annotations

import argparse
import sys

from strauss_fit._escaping import escape as escape  # the one escaping, shared with the reports
from strauss_fit.errors import StraussFitError
from strauss_fit.fitting.options import QUALITY_PRESETS


def check_evaluator_options(args: argparse.Namespace) -> None:
    """Refuse a ``--table-size`` outside what ``--mode`` can hold (below 2, or above the
    tables' limits), before any work."""
    if args.table_size < 2:
        raise StraussFitError(f"--table-size must be at least 2, got {args.table_size}")
    limit = MAX_J_TABLE_SIZE if getattr(args, "mode", None) == "j-table" else MAX_TABLE_SIZE
    if args.table_size > limit:
        raise StraussFitError(
            f"--table-size must be at most {limit}{' with --mode j-table' if limit == MAX_J_TABLE_SIZE else ''}, "
            f"got {args.table_size}"
        )


#: Largest integer any count option takes (steps, starts, walkers, ...): beyond it the
#: values overflow the solvers' int32/int64 counters and mean nothing anyway.
MAX_COUNT = 10**9
#: Largest --table-size: entries of the F/G tables, and per axis of the j table (N² entries).
MAX_TABLE_SIZE = 1 << 20
MAX_J_TABLE_SIZE = 4096
#: Largest image side, as in scene files (`strauss_fit.scene.loading.MAX_IMAGE_SIDE`).
MAX_IMAGE_SIDE = 8192


def bounded_int(low: int, high: int):
    """argparse type: an integer in [low, high]."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {escape(text)!r}") from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"expected an integer from {low} to {high}, got {value}")
        return value

    parse.__name__ = "integer"
    return parse


#: argparse type: an integer >= 1 (and at most `MAX_COUNT`).
positive_int = bounded_int(1, MAX_COUNT)
positive_int.__name__ = "positive integer"
#: argparse type: an image side in pixels, 1 to `MAX_IMAGE_SIDE`.
image_side = bounded_int(1, MAX_IMAGE_SIDE)


def finite_float(low: float | None = None, *, open_low: bool = False):
    """argparse type: a finite number, at least ``low`` (above it with ``open_low``)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {escape(text)!r}") from None
        if value != value or value in (float("inf"), float("-inf")):
            raise argparse.ArgumentTypeError(f"expected a finite number, got {text}")
        if low is not None and (value <= low if open_low else value < low):
            raise argparse.ArgumentTypeError(f"expected a number {'>' if open_low else '>='} {low:g}, got {value:g}")
        return value

    parse.__name__ = "number"
    return parse


# --- escaping what input files bring to the terminal -------------------------------------------


class EscapingStream:
    """A text stream that escapes control characters (`escape`) except tab, LF and
    CR (the progress bar's), so nothing quoted from an input file reaches the terminal raw."""

    def __init__(self, stream):
        self._stream = stream

    def write(self, text: str) -> int:
        self._stream.write(escape(text))
        return len(text)

    def __getattr__(self, name):
        return getattr(self._stream, name)


def progress_printer(quiet: bool, prefix: str = "", stream=None):
    """A log function for the library's progress lines: prints ``PREFIX message`` on stderr
    (nothing with ``quiet``) and is a safe point for a recorded Ctrl-C."""
    from . import interrupts

    def log(message: str) -> None:
        interrupts.check()
        if not quiet:  # one line each, whatever the names it quotes hold
            print(f"{prefix}{escape(message, newlines=True)}", file=stream or sys.stderr, flush=True)

    return log


def by_quality(setting: str) -> str:
    """``fast 2, balanced 2, accurate 4``: a setting of every quality preset, read from
    `QUALITY_PRESETS` (for help texts, which so always say
    what the presets use)."""
    return ", ".join(f"{name} {values[setting]:g}" for name, values in QUALITY_PRESETS.items())
