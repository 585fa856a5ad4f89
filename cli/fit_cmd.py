"""``strauss-fit fit``: recover the Strauss parameters from a reference image."""

from __future__ import annotations

import argparse
from pathlib import Path

from .common import (
    add_evaluator_options,
    add_quality_option,
    by_quality,
    check_evaluator_options,
    finite_float,
    positive_int,
    progress_printer,
)

PARAMETER_HELP = (
    "color, smoothness, metalness, transparency, ior "
    "(and with --fit-lights: directional_intensity_1, ..., ambient_intensity)"
)


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "fit",
        help="fit the Strauss parameters to a reference image",
        description="Fit the material (C, s, m, t, n) of SCENE to the image TARGET by least squares "
        "(optimistix), in float64, from several starts. Parameters the scene cannot constrain are "
        "held at the scene's [material] values and the result says why. Writes RESULT.json.",
    )
    parser.add_argument("target", metavar="TARGET", help="reference image (.exr/.hdr/.tif linear; .png/.jpg sRGB)")
    parser.add_argument("--scene", required=True, metavar="SCENE.toml", help="the scene the target was taken in")
    parser.add_argument("-o", "--output", required=True, metavar="RESULT.json", help="fit result (JSON)")
    parser.add_argument("--mask", metavar="MASK", help="mask image: pixels where it is non-zero are used")
    parser.add_argument(
        "--encoding",
        choices=("auto", "linear", "srgb"),
        default="auto",
        help="how TARGET's values are encoded (default: sRGB for .png/.jpg, linear otherwise)",
    )
    parser.add_argument(
        "--solver",
        choices=("lm", "gauss-newton", "bfgs"),
        default="lm",
        help="Levenberg-Marquardt (default), Gauss-Newton, or the quasi-Newton minimiser BFGS",
    )
    parser.add_argument(
        "--starts",
        type=positive_int,
        metavar="N",
        help="number of starts: the closed-form guess plus N-1 fixed points (default: from --quality: "
        f"{by_quality('starts')})",
    )
    parser.add_argument(
        "--max-steps",
        type=positive_int,
        metavar="N",
        help=f"solver step limit of the polish (default: from --quality: {by_quality('max_steps')})",
    )
    parser.add_argument(
        "--free",
        metavar="NAMES",
        help=f"comma-separated parameters to fit, overriding the automatic choice: {PARAMETER_HELP}",
    )
    parser.add_argument(
        "--fix",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="hold a parameter at a value (repeatable); color takes R,G,B",
    )
    parser.add_argument("--fit-lights", action="store_true", help="also consider the light intensities as parameters")
    parser.add_argument(
        "--reference-noise",
        type=finite_float(0.0, open_low=True),
        metavar="SIGMA",
        help="noise level used to decide what the image constrains (default: 1%% of the target's 98th percentile)",
    )
    parser.add_argument(
        "--render-fit",
        metavar="OUT",
        help="write the fitted image to OUT and a target | fit | residual PNG beside it (OUT.compare.png)",
    )
    parser.add_argument("--force", action="store_true", help="overwrite existing outputs")
    parser.add_argument("--quiet", action="store_true", help="print only the result table")
    add_evaluator_options(parser)
    add_quality_option(parser)
    parser.set_defaults(run=run)


def parse_fixed(items: list[str]) -> tuple[tuple[str, float | tuple[float, ...]], ...]:
    import math

    from strauss_fit.errors import StraussFitError

    fixed = []
    for item in items:
        name, sep, text = item.partition("=")
        if not sep or not name:
            raise StraussFitError(f"--fix expects NAME=VALUE, got {item!r}")
        try:
            numbers = tuple(float(v) for v in text.split(","))
        except ValueError:
            raise StraussFitError(f"--fix {name}: {text!r} is not a number (or R,G,B for color)") from None
        if not all(math.isfinite(v) for v in numbers):
            raise StraussFitError(f"--fix {name}: {text!r} is not a finite number")
        if name == "color":
            if len(numbers) != 3:
                raise StraussFitError(f"--fix color expects R,G,B, got {text!r}")
            fixed.append((name, numbers))
        else:
            if len(numbers) != 1:
                raise StraussFitError(f"--fix {name} expects one number, got {text!r}")
            fixed.append((name, numbers[0]))
    return tuple(fixed)


def fit_options(args: argparse.Namespace, fixed, **more):
    """The :class:`~strauss_fit.fit.options.FitOptions` of ``--quality`` with the options
    given explicitly (also used by ``sample`` when it fits first)."""
    from strauss_fit import FitOptions

    return FitOptions.preset(
        args.quality,
        solver=args.solver,
        starts=args.starts,
        mode=args.mode,
        table_size=args.table_size,
        free=tuple(n.strip() for n in args.free.split(",") if n.strip()) if args.free else None,
        fixed=fixed,
        fit_lights=args.fit_lights,
        **more,
    )


def check_fixed_ranges(fixed) -> None:
    from strauss_fit import Material

    material_values = {
        k: (list(v) if k == "color" else v)
        for k, v in fixed
        if k in ("color", "smoothness", "metalness", "transparency", "ior")
    }
    Material.from_dict(material_values)  # raises a one-line MaterialError naming field and range
    for name, value in fixed:
        if "intensity" in name and value < 0:
            from strauss_fit.errors import StraussFitError

            raise StraussFitError(f"--fix {name}={value}: an intensity must be >= 0")


def format_table(result: dict) -> str:
    """The human-readable summary: one row per parameter."""
    rows = [("parameter", "value", "± (Laplace)", "status")]
    uncertainty = result.get("uncertainty", {})
    for name in ("color", "smoothness", "metalness", "transparency", "ior", *result.get("lights", {})):
        value = result["color"] if name == "color" else result.get(name, result.get("lights", {}).get(name))
        if value is None:
            continue
        if name in result["free"]:
            sd = uncertainty.get(name)
            status = "fitted"
        elif name in result["held"]:
            sd = None
            status = "held: " + result["held"][name]["reason"]
        else:
            continue
        if isinstance(value, list):
            text = ", ".join(f"{v:.4f}" for v in value)
            sd_text = ", ".join(f"{v:.2g}" for v in sd) if sd is not None else "-"
        else:
            text = f"{value:.4f}"
            sd_text = f"{sd:.2g}" if sd is not None else "-"
        rows.append((name, text, sd_text, status))
    widths = [max(len(r[i]) for r in rows) for i in range(3)]
    lines = [f"{r[0]:<{widths[0]}}  {r[1]:<{widths[1]}}  {r[2]:<{widths[2]}}  {r[3]}" for r in rows]
    lines.insert(1, "-" * min(100, sum(widths) + 6 + 6))
    res = result["residual"]
    lines.append("")
    lines.append(
        f"residual: RMS {res['rms']:.3g} (linear), CIEDE2000 mean {res['delta_e2000_mean']:.3g}, "
        f"95th percentile {res['delta_e2000_p95']:.3g}; {result['pixels_used']} pixels"
    )
    solver = result["solver"]
    lines.append(
        f"solver: {solver['name']}, {solver['steps']} steps, {solver['status']}, "
        f"{len(result['starts'])} start(s); wall time {result['wall_time_s']:.2f} s"
    )
    for note in result.get("notes", []):
        lines.append(f"note: {note}")
    return "\n".join(lines)


def comparison_image(target, fitted, mask):
    """target | fit | |residual| (amplified to fill the range), side by side, linear."""
    import numpy as np

    residual = np.abs(fitted - target) * mask[..., None]
    peak = float(residual.max())
    scale = float(np.percentile(target[mask], 99)) if mask.any() else 1.0
    scale = max(scale, 1e-12)
    residual_view = residual / peak * scale if peak > 0 else residual
    gap = np.ones((target.shape[0], 2, 3)) * scale
    return np.concatenate([target, gap, fitted, gap, residual_view], axis=1) / scale


def check_outputs(args: argparse.Namespace) -> Path | None:
    """Check every output of ``fit`` before any work; returns the comparison image's path."""
    from strauss_fit.io.files import check_distinct, check_writable
    from strauss_fit.io.images import check_image_output

    compare_path = Path(args.render_fit).with_suffix(".compare.png") if args.render_fit else None
    check_distinct(
        {"-o": args.output, "--render-fit": args.render_fit, "--render-fit's comparison": compare_path},
        {"TARGET": args.target, "--scene": args.scene, "--mask": args.mask},
    )
    check_writable(args.output, args.force)
    if args.render_fit:
        check_image_output(args.render_fit, args.force)
        check_image_output(compare_path, args.force)
    return compare_path


def run(args: argparse.Namespace) -> int:
    check_evaluator_options(args)
    compare_path = check_outputs(args)
    fixed = parse_fixed(args.fix)
    check_fixed_ranges(fixed)

    from strauss_fit import fit, load_scene, load_target, match_scene
    from strauss_fit.io.files import Outputs

    log = progress_printer(args.quiet, "... ")
    scene = load_scene(args.scene)
    target = load_target(args.target, args.mask, args.encoding)
    scene, message = match_scene(scene, target)
    if message:
        log(message)
    options = fit_options(args, fixed, max_steps=args.max_steps, reference_noise=args.reference_noise)
    if args.precision != "float64":
        log("fits always run in float64; --precision is ignored")
    result = fit(scene, target, options, progress=log)
    payload = result.to_json()
    payload["target"] = str(args.target)
    payload["scene"] = str(args.scene)
    payload["mask"] = str(args.mask) if args.mask else None
    payload["encoding"] = args.encoding
    payload["settings"]["quality"] = args.quality
    with Outputs(force=args.force) as out:  # all or nothing
        out.add_json(args.output, payload)
        if args.render_fit:
            out.add_image(args.render_fit, result.fitted_image)
            out.add_image(compare_path, comparison_image(target.pixels, result.fitted_image, result.mask))
        written = out.commit(final=True)
    print(format_table(payload))
    print(f"wrote {', '.join(str(p) for p in written)}")
    return 0 if result.solver["status"] == "successful" else 1
