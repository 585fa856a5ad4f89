"""The option groups several subcommands share, each added by one function here, so that an
option means, accepts and defaults to the same in every command that has it.

The names an option accepts come from the library's registries (plain data, imported
without NumPy or JAX, so that ``strauss-fit --help`` stays fast): the losses
(`strauss_fit.fitting.losses.LOSS_REGISTRY`), the starts' searches and edge-pixel rules
(`strauss_fit.fitting.options`), the solvers, the image encodings and the evaluators. A
function takes the help texts that differ between commands (what ``-o`` writes, what
``--quiet`` leaves out) as arguments; the rest is written once, here.
"""

from __future__ import annotations

import argparse
from typing import Any

from strauss_fit.fitting.losses import AUTO, LEAST_SQUARES, LOSS_CHOICES, LOSS_REGISTRY
from strauss_fit.fitting.options import DEFAULT_QUALITY, EDGE_PIXELS, MISMATCH_LOSS, QUALITY_PRESETS, SEARCHES, SOLVERS
from strauss_fit.io.table_formats import IMAGE_ENCODINGS
from strauss_fit.models.modes import DEFAULT_TABLE_SIZE, MODES

from .common import bounded_int, by_quality, finite_float, positive_int

#: Where options are added: a parser, or one of its argument groups.
Container = argparse.ArgumentParser | argparse._ArgumentGroup

#: ``--force``'s help where a command writes several outputs.
FORCE_HELP = "overwrite existing outputs"

#: The fitted parameters, for ``--free``'s help.
PARAMETER_HELP = (
    "color, smoothness, metalness, transparency, ior "
    "(and with --fit-lights: directional_intensity_1, ..., ambient_intensity)"
)


# --- outputs and progress ----------------------------------------------------------------------


def add_output_option(parser: Container, *, metavar: str, help: str) -> None:
    """``-o``/``--output`` (required): what the command writes."""
    parser.add_argument("-o", "--output", required=True, metavar=metavar, help=help)


def add_force_option(parser: Container, help: str = FORCE_HELP, *, resume: str | None = None) -> None:
    """``--force``; with ``resume`` (its help), also ``--resume``, the two mutually exclusive
    (a command that continues an interrupted run: replacing it and continuing it contradict)."""
    if resume is None:
        parser.add_argument("--force", action="store_true", help=help)
        return
    either = parser.add_mutually_exclusive_group()
    either.add_argument("--force", action="store_true", help=help)
    either.add_argument("--resume", action="store_true", help=resume)


def add_quiet_option(parser: Container, help: str) -> None:
    """``--quiet``: no progress lines (``help`` says what is still printed)."""
    parser.add_argument("--quiet", action="store_true", help=help)


# --- the target and its scene ------------------------------------------------------------------


def add_image_inputs(
    parser: Container,
    *,
    target: dict[str, Any] | None,
    scene: str,
    mask: str = "mask image: pixels where it is non-zero are used",
    encoding: str,
    encoding_default: str | None = "auto",
) -> None:
    """TARGET (``target``: the positional's ``nargs`` and ``help``; None: none), ``--scene``,
    ``--mask`` and ``--encoding`` (`IMAGE_ENCODINGS`;
    ``encoding_default`` None where the default comes from a fit result)."""
    if target is not None:
        parser.add_argument("target", metavar="TARGET", **target)
    parser.add_argument("--scene", metavar="SCENE.toml", help=scene)
    parser.add_argument("--mask", metavar="MASK", help=mask)
    add_encoding_option(parser, default=encoding_default, help=encoding)


def add_encoding_option(
    parser: Container, *, help: str, default: str | None = "auto", choices: tuple[str, ...] = IMAGE_ENCODINGS
) -> None:
    """``--encoding``: how an input image's values are decoded."""
    parser.add_argument("--encoding", choices=choices, default=default, help=help)


def add_capture_inputs(parser: Container, *, capture: str, lights: str) -> None:
    """``--capture PATH ...`` (a manifest, a folder, or image files) and ``--lights``."""
    parser.add_argument("--capture", nargs="+", metavar="PATH", help=capture)
    parser.add_argument("--lights", metavar="LIGHTS.toml", help=lights)


def add_noise_options(
    parser: Container,
    *,
    metavar: str = "SIGMA",
    help: str = "the target's noise (standard deviation, linear; one value or R,G,B) when known; default: from "
    "the target's sidecar, else estimated from the image",
    reference: bool = True,
) -> None:
    """``--noise``: the target's noise (one value or R,G,B) when known; with ``reference``,
    also ``--reference-noise``, the level that decides what a fit's image constrains."""
    if reference:
        parser.add_argument(
            "--reference-noise",
            type=finite_float(0.0, open_low=True),
            metavar="SIGMA",
            help="noise level used to decide what the image constrains (default: 1%% of the target's 98th percentile)",
        )
    parser.add_argument("--noise", metavar=metavar, help=help)


# --- fitting -----------------------------------------------------------------------------------


def add_fitting_options(parser: Container, *, as_for_fit: bool = False) -> None:
    """What a least-squares fit of one target takes: ``--solver``, ``--starts``, ``--free``,
    ``--fix`` and ``--fit-lights``. ``as_for_fit``: short help texts that point to ``fit``'s
    (``sample``, which fits first)."""
    brief = "as for 'fit'"
    parser.add_argument(
        "--solver",
        choices=SOLVERS,
        default="lm",
        help=brief if as_for_fit else "Levenberg-Marquardt (default), Gauss-Newton, or the quasi-Newton minimiser BFGS",
    )
    parser.add_argument(
        "--starts",
        type=positive_int,
        metavar="N",
        help=brief
        if as_for_fit
        else "number of starts: the N best distinct minima of the global search, or the closed-form guess plus "
        f"N-1 fixed points (--search; default: from --quality: {by_quality('starts')})",
    )
    parser.add_argument(
        "--free",
        metavar="NAMES",
        help="comma-separated parameters to fit (as for 'fit')"
        if as_for_fit
        else f"comma-separated parameters to fit, overriding the automatic choice: {PARAMETER_HELP}",
    )
    parser.add_argument(
        "--fix",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="hold a parameter (as for 'fit')"
        if as_for_fit
        else "hold a parameter at a value (repeatable); color takes R,G,B",
    )
    parser.add_argument(
        "--fit-lights",
        action="store_true",
        help="also consider the light intensities (as for 'fit')"
        if as_for_fit
        else "also consider the light intensities as parameters",
    )


def loss_help() -> str:
    """``--loss``'s help: every loss of `strauss_fit.fitting.losses.LOSS_REGISTRY` with its
    description, then ``auto``, the default."""
    losses = "; ".join(f"{name}, {loss.description}" for name, loss in LOSS_REGISTRY.items())
    return (
        f"what the fit minimises: {losses}; {AUTO}, the default: {LEAST_SQUARES}, then {MISMATCH_LOSS} when the "
        "model visibly cannot reproduce the target (docs/mismatch.md#the-loss)"
    )


def add_search_options(parser: Container) -> None:
    """What a fit minimises and where it looks: ``--loss``, ``--edge-pixels`` and ``--search``."""
    parser.add_argument("--loss", choices=LOSS_CHOICES, default=AUTO, help=loss_help())
    parser.add_argument(
        "--edge-pixels",
        choices=EDGE_PIXELS,
        default="auto",
        help="silhouette pixels the sphere covers only partly: fit them as sphere pixels when the target is "
        "point-sampled there (auto, the default: checked against the scene's background), leave them out, or "
        "always include them",
    )
    parser.add_argument(
        "--search",
        choices=SEARCHES,
        default="auto",
        help="where the solves start: grid, a global search over smoothness and metalness with the colour solved "
        "in closed form (an opaque material fitted by least squares, no light or exposure free; the multi-start "
        "elsewhere); starts, the closed-form guess and fixed points; auto, the default: the grid wherever it "
        "applies (docs/fitting.md#starts)",
    )


def add_equivalence_options(parser: Container) -> None:
    """``--equivalence`` and its threshold ``--equivalence-de``."""
    parser.add_argument(
        "--equivalence",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="also compute each parameter's range that looks the same (default: on with --quality accurate; "
        "--no-equivalence turns it off)",
    )
    parser.add_argument(
        "--equivalence-de",
        type=finite_float(0.0, open_low=True),
        default=None,
        metavar="DE",
        help="the mean CIEDE2000 within which images look the same (default 1, one just-noticeable difference); "
        "implies --equivalence",
    )


# --- evaluation and presets --------------------------------------------------------------------


def add_evaluator_options(
    parser: Container,
    *,
    mode: str = "evaluator: closed-form F and G (exact), tabulated F and G (table), or a 2-D table of j (j-table); "
    "default: exact",
    table_size: str = f"entries of the F/G tables, or per axis of the j table (default {DEFAULT_TABLE_SIZE})",
    precision: bool = True,
) -> None:
    """``--mode``, ``--table-size`` and (``precision``) ``--precision``."""
    parser.add_argument("--mode", choices=MODES, default="exact", help=mode)
    parser.add_argument(
        "--table-size", type=bounded_int(-(2**31), 2**31), default=DEFAULT_TABLE_SIZE, metavar="N", help=table_size
    )
    if precision:
        parser.add_argument(
            "--precision",
            choices=("float32", "float64"),
            default="float64",
            help="floating-point precision of the computation (default float64)",
        )


def add_quality_option(parser: Container) -> None:
    """``--quality``: a preset of `QUALITY_PRESETS`."""
    parser.add_argument(
        "--quality",
        choices=tuple(QUALITY_PRESETS),
        default=DEFAULT_QUALITY,
        help=f"speed/accuracy preset (default {DEFAULT_QUALITY}; see docs/benchmarks.md#quality-presets); "
        "options given explicitly override it",
    )
