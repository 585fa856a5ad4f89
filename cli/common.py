"""Options and helpers shared by several subcommands."""

from __future__ import annotations

import argparse

from strauss_fit.errors import StraussFitError
from strauss_fit.model import DEFAULT_TABLE_SIZE, MODES


def add_evaluator_options(parser: argparse.ArgumentParser) -> None:
    """--mode, --table-size and --precision."""
    parser.add_argument("--mode", choices=MODES, default="exact",
                        help="evaluator: closed-form F and G (exact), tabulated F and G (table), "
                        "or a 2-D table of j (j-table); default: exact")
    parser.add_argument("--table-size", type=int, default=DEFAULT_TABLE_SIZE, metavar="N",
                        help=f"entries of the F/G tables, or per axis of the j table (default {DEFAULT_TABLE_SIZE})")
    parser.add_argument("--precision", choices=("float32", "float64"), default="float64",
                        help="floating-point precision of the computation (default float64)")


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


#: ``--quality`` presets: settings for fits (``starts``, ``max_steps``, ``rtol``, ``atol``)
#: and sampling (``walkers``, ``min_tau_multiple``, ``sample_max_steps``). How they were
#: chosen, with the measurements, is in README.md ("Quality presets"). ``None``: automatic.
QUALITY_PRESETS: dict[str, dict[str, float | int | None]] = {
    # derived by benchmarks/tradeoff.py (2026-11-29); the numbers that picked each value
    # are in README.md, "Quality presets"
    "fast": dict(starts=2, max_steps=20, rtol=1e-2, atol=1e-4, walkers=None, min_tau_multiple=10.0,
                 sample_max_steps=2000),
    "balanced": dict(starts=2, max_steps=320, rtol=1e-4, atol=1e-6, walkers=None, min_tau_multiple=50.0,
                     sample_max_steps=10000),
    "accurate": dict(starts=4, max_steps=610, rtol=1e-8, atol=1e-10, walkers=128, min_tau_multiple=100.0,
                     sample_max_steps=50000),
}


def add_quality_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quality", choices=tuple(QUALITY_PRESETS), default="balanced",
                        help="speed/accuracy preset (default balanced); options given explicitly override it")


def quality_setting(args: argparse.Namespace, name: str, attribute: str | None = None):
    """The explicit command-line value of ``attribute`` (default: ``name``) if given, else
    the ``--quality`` preset's ``name``."""
    value = getattr(args, attribute or name, None)
    return value if value is not None else QUALITY_PRESETS[args.quality][name]
