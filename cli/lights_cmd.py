"""``strauss-fit lights``: measure light directions on photographs of a mirror ball."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from strauss_fit.io.table_formats import IMAGE_ENCODINGS

from ._options import add_encoding_option, add_force_option, add_output_option, add_quiet_option
from .common import escape, finite_float, progress_printer


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "lights",
        help="measure the lights on photographs of a mirror ball (a lights file for captures)",
        description="Find the highlight on each photograph of a mirror (chrome) ball, one light per image, and "
        "reflect the view ray there: the light's direction, its angular standard deviation and, where the "
        "highlight is not saturated, its relative intensity. Prints a table and writes the lights file "
        "LIGHTS.toml (see docs/captures.md and docs/commands/lights.md).",
    )
    parser.add_argument(
        "images", metavar="CHROME_IMAGE", nargs="+", help="photographs of the mirror ball, one light each"
    )
    add_output_option(parser, metavar="LIGHTS.toml", help="the lights file to write")
    parser.add_argument(
        "--mask",
        metavar="MASK",
        help="mask of the ball (pixels at least half its maximum); default: found in the images",
    )
    parser.add_argument(
        "--circle",
        nargs=3,
        type=finite_float(),
        metavar=("CX", "CY", "R"),
        help="the ball's circle in pixels (centre x, y from the top-left corner, radius), instead of finding it",
    )
    parser.add_argument(
        "--camera",
        choices=("orthographic", "perspective"),
        default="orthographic",
        help="the camera model (default orthographic; perspective needs --focal-px)",
    )
    parser.add_argument(
        "--focal-px", type=finite_float(0.0, open_low=True), metavar="F", help="perspective: the focal length in pixels"
    )
    parser.add_argument(
        "--principal-point",
        nargs=2,
        type=finite_float(),
        metavar=("PX", "PY"),
        help="perspective: the principal point in pixels (default: the image centre)",
    )
    add_encoding_option(
        parser,
        choices=tuple(encoding for encoding in IMAGE_ENCODINGS if encoding != "auto"),  # no auto: as stored unless told
        default="linear",
        help="how the images' values are decoded (default linear: as stored; the highlight's position does not "
        "depend on it, its intensity needs linear values)",
    )
    parser.add_argument(
        "--saturation",
        type=finite_float(0.0, open_low=True),
        metavar="LEVEL",
        help="stored values at or above LEVEL (a fraction of full scale, at most 1) are saturated (default: the "
        "largest code of an integer file, none for a float file)",
    )
    add_force_option(parser, "overwrite an existing output")
    add_quiet_option(parser, "print only the table")
    parser.set_defaults(run=run)


def _camera(args: argparse.Namespace):
    from strauss_fit.capture._sphere import Camera
    from strauss_fit.errors import StraussFitError

    if args.camera == "perspective":
        if args.focal_px is None:
            raise StraussFitError("--camera perspective needs --focal-px (the focal length in pixels)")
        return Camera("perspective", args.focal_px, tuple(args.principal_point) if args.principal_point else None)
    for option, value in (("--focal-px", args.focal_px), ("--principal-point", args.principal_point)):
        if value is not None:
            raise StraussFitError(f"{option} applies to --camera perspective only")
    return Camera("orthographic")


def _listed_name(path: str, output: str) -> str:
    """An image's name in the lights file: relative to the file's folder where possible."""
    try:
        return Path(os.path.relpath(os.path.abspath(path), os.path.abspath(os.path.dirname(output) or "."))).as_posix()
    except ValueError:  # another drive (Windows): no relative path
        return os.path.abspath(path)


def format_table(names: list[str], estimates) -> str:
    """The table the command prints: image, direction, ± degrees, intensity, highlight pixel."""
    rows = [("image", "direction (x, y, z)", "± deg", "intensity (R, G, B)", "highlight (x, y) px")]
    for name, estimate in zip(names, estimates):
        direction = "(" + ", ".join(f"{v:+.4f}" for v in estimate.direction) + ")"
        intensity = (
            "saturated" if estimate.intensity is None else "(" + ", ".join(f"{v:.3f}" for v in estimate.intensity) + ")"
        )
        pixel = f"({estimate.pixel[0]:.2f}, {estimate.pixel[1]:.2f})"
        rows.append((name, direction, f"{estimate.direction_sd_deg:.2f}", intensity, pixel))
    widths = [max(len(row[j]) for row in rows) for j in range(len(rows[0]))]
    return "\n".join("  ".join(cell.ljust(width) for cell, width in zip(row, widths)).rstrip() for row in rows)


def run(args: argparse.Namespace) -> int:
    from strauss_fit.capture._mirror import estimate_lights, lights_toml
    from strauss_fit.capture._sphere import Circle
    from strauss_fit.errors import StraussFitError
    from strauss_fit.io.files import check_distinct, check_input_file, check_writable, write_text

    camera = _camera(args)
    circle = None
    if args.circle is not None:
        cx, cy, radius = args.circle
        if radius <= 0:
            raise StraussFitError(f"--circle: the radius must be > 0, got {radius:g}")
        circle = Circle((cx, cy), radius, source="given")
    if args.saturation is not None and args.saturation > 1:
        raise StraussFitError(f"--saturation must lie in (0, 1] (a fraction of full scale), got {args.saturation:g}")
    # every input and the output checked before any work
    inputs = {f"CHROME_IMAGE {k}": path for k, path in enumerate(args.images, start=1)}
    inputs["--mask"] = args.mask
    check_distinct({"-o": args.output}, inputs)
    for path in args.images:
        check_input_file(path, "image")
    if args.mask:
        check_input_file(args.mask, "mask")
    check_writable(args.output, args.force)

    printer = progress_printer(args.quiet, "lights: ")
    log = lambda message: printer(escape(message, newlines=True))  # the messages quote input paths
    estimates = estimate_lights(
        args.images,
        mask_path=args.mask,
        circle=circle,
        camera=camera,
        saturation=args.saturation,
        encoding=args.encoding,
        progress=log,
    )
    names = [_listed_name(path, args.output) for path in args.images]
    text = lights_toml(estimates, names, estimates[0].circle, camera)
    print(escape(format_table(list(args.images), estimates)))
    for name, estimate in zip(args.images, estimates):
        for note in estimate.notes:
            if estimate.intensity is None and "saturated" in note:
                continue  # the table says so
            print(escape(f"lights: note: {name}: {note}", newlines=True), file=sys.stderr)
    write_text(args.output, text, force=args.force)
    saturated = sum(estimate.intensity is None for estimate in estimates)
    unknown = f", {saturated} without intensity (saturated)" if saturated else ""
    print(escape(f"wrote {args.output} ({len(estimates)} lights{unknown})", newlines=True))
    return 0
