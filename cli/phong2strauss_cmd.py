"""``strauss-fit phong2strauss`` and ``strauss-fit strauss2phong``: convert materials by fitting.

This module registers both subcommands (see `COMMANDS` in ``main.py``: the module's
``add_parser`` adds both). The work is `strauss_fit.convert.converter.convert_files`.
"""

from __future__ import annotations

import argparse
import sys

from strauss_fit.io.table_formats import describe_suffixes, output_suffixes

from ._options import add_force_option, add_output_option, add_quality_option, add_quiet_option
from .common import by_quality, escape, image_side, positive_int, progress_printer

FORMATS_HELP = {
    "phong2strauss": "one Phong material as KEY=VALUE pairs (ka kd ks exponent|n|Ns diffuse_color|Cd "
    "specular_color|Cs blinn opacity|d ior|Ni; RGB as r,g,b) or a JSON object, or a .json, "
    ".csv or Wavefront .mtl file",
    "strauss2phong": "one Strauss material as KEY=VALUE pairs (color|C smoothness|s metalness|m transparency|t "
    "ior|n; RGB as r,g,b) or a JSON object, or a .json (also a 'strauss-fit fit' result or "
    "phong2strauss output) or .csv file",
}


def add_parser(subparsers) -> None:
    for direction, (source, destination) in (
        ("phong2strauss", ("Phong", "Strauss")),
        ("strauss2phong", ("Strauss", "Phong")),
    ):
        outputs = describe_suffixes(output_suffixes(direction))
        parser = subparsers.add_parser(
            direction,
            help=f"convert {source} materials to {destination} parameters (by fitting sphere renders)",
            description=f"Render each {source} material on the conversion scene (a sphere under three lights, "
            f"see docs/conversion.md) and fit {destination}'s parameters to that image, starting from a "
            f"closed-form guess. Writes, per material, the {destination} parameters, the residual of the match "
            "(RMS and CIEDE2000) and Laplace uncertainties; a material that fails is reported and skipped. "
            "Results are saved to OUTPUT.partial as they complete: an interrupted run continues with --resume.",
        )
        parser.add_argument(
            "input", nargs="+", metavar="INPUT", help=FORMATS_HELP[direction] + " (several files are read in turn)"
        )
        add_output_option(parser, metavar="OUTPUT", help=f"results: {outputs} (by extension)")
        parser.add_argument(
            "--scene",
            metavar="SCENE.toml",
            help="conversion scene (lights and camera; rendered at depth 1; default: "
            "data_synth/scenes/conversion_default.toml)",
        )
        parser.add_argument(
            "--size",
            type=image_side,
            metavar="N",
            help="render the conversion image N pixels wide (default: the scene's, 64)",
        )
        parser.add_argument(
            "--starts",
            type=positive_int,
            metavar="N",
            help="starts per material: the closed-form guess plus N-1 fixed points (default: from --quality: "
            f"{by_quality('starts')})",
        )
        add_quality_option(parser)
        if direction == "strauss2phong":
            parser.add_argument("--blinn", action="store_true", help="fit Blinn-Phong (half-vector highlight)")
        add_force_option(
            parser,
            "overwrite an existing OUTPUT (and start again over OUTPUT.partial)",
            resume="continue the interrupted conversion saved in OUTPUT.partial (same inputs and options)",
        )
        add_quiet_option(parser, "no progress lines (warnings are still shown)")
        parser.set_defaults(run=run, direction=direction)


def _table(results: list[dict], direction: str) -> str:
    rows = [("name", "status", "parameters", "RMS", "ΔE2000 mean")]
    for r in results:
        if r["status"] != "ok":
            rows.append((r["name"], "error", r.get("message", ""), "", ""))
            continue
        if direction == "phong2strauss":
            v = r["strauss"]
            text = (
                f"C=({', '.join(f'{c:.3f}' for c in v['color'])}) s={v['smoothness']:.3f} "
                f"m={v['metalness']:.3f} t={v['transparency']:.3g} n={v['ior']:.3g}"
            )
        else:
            v = r["phong"]
            text = (
                f"ka={v['ka']:.3f} kd={v['kd']:.3f} ks={v['ks']:.3f} n={v['exponent']:.4g} "
                f"Cd=({', '.join(f'{c:.3f}' for c in v['diffuse_color'])}) "
                f"Cs=({', '.join(f'{c:.3f}' for c in v['specular_color'])})"
            )
        if r.get("held"):  # what the conversion image does not determine (the JSON says why)
            text += f" (held: {', '.join(r['held'])})"
        res = r["residual"]
        rows.append((r["name"], "ok", text, f"{res['rms']:.3g}", f"{res['delta_e2000_mean']:.3g}"))
    # one line per material, sized on what is printed: names and messages quote input files
    rows = [tuple(escape(cell, newlines=True) for cell in row) for row in rows]
    widths = [min(40, max(len(row[i]) for row in rows)) for i in range(2)]
    return "\n".join(
        f"{row[0]:<{widths[0]}}  {row[1]:<{widths[1]}}  {row[3]:>8}  {row[4]:>11}  {row[2]}" for row in rows
    )


def run(args: argparse.Namespace) -> int:
    from strauss_fit.convert.converter import Settings, convert_files, progress_path

    log = progress_printer(args.quiet)

    def warn(message: str) -> None:
        print(f"{args.direction}: warning: {escape(message, newlines=True)}", file=sys.stderr, flush=True)

    try:
        document = convert_files(
            args.direction,
            args.input,
            args.output,
            scene=args.scene,
            size=args.size,
            settings=Settings.preset(args.quality, starts=args.starts),
            blinn=getattr(args, "blinn", False),
            force=args.force,
            resume=args.resume,
            log=log,
            warn=warn,
        )
    except KeyboardInterrupt:
        partial = progress_path(args.output)
        if partial.exists():
            print(
                f"strauss-fit: {args.direction}: interrupted; the materials converted so far are saved in {partial} "
                "(continue with --resume)",
                file=sys.stderr,
            )
        raise
    results = document["materials"]
    failed = [r for r in results if r["status"] != "ok"]
    print(_table(results, args.direction))
    print(
        f"{len(results) - len(failed)} of {len(results)} material(s) converted"
        f"{f', {len(failed)} failed (see the output)' if failed else ''}; wrote {args.output}"
    )
    return 1 if failed else 0
