"""Options and helpers shared by several subcommands (the quality presets themselves live in
the library: :data:`strauss_fit.fit.options.QUALITY_PRESETS`)."""

from __future__ import annotations

import argparse

from strauss_fit.errors import StraussFitError
from strauss_fit.fit.options import DEFAULT_QUALITY, QUALITY_PRESETS
from strauss_fit.models.strauss import DEFAULT_TABLE_SIZE, MODES


def add_evaluator_options(parser: argparse.ArgumentParser) -> None:
    """--mode, --table-size and --precision."""
    parser.add_argument(
        "--mode",
        choices=MODES,
        default="exact",
        help="evaluator: closed-form F and G (exact), tabulated F and G (table), "
        "or a 2-D table of j (j-table); default: exact",
    )
    parser.add_argument(
        "--table-size",
        type=int,
        default=DEFAULT_TABLE_SIZE,
        metavar="N",
        help=f"entries of the F/G tables, or per axis of the j table (default {DEFAULT_TABLE_SIZE})",
    )
    parser.add_argument(
        "--precision",
        choices=("float32", "float64"),
        default="float64",
        help="floating-point precision of the computation (default float64)",
    )


def check_evaluator_options(args: argparse.Namespace) -> None:
    if args.table_size < 2:
        raise StraussFitError(f"--table-size must be at least 2, got {args.table_size}")


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def add_quality_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--quality",
        choices=tuple(QUALITY_PRESETS),
        default=DEFAULT_QUALITY,
        help="speed/accuracy preset (default balanced); options given explicitly override it",
    )
