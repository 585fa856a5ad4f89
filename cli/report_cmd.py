"""``strauss-fit report``: a self-contained HTML (and Markdown) uncertainty report."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "report",
        help="write an HTML and Markdown report of a fit's uncertainty",
        description="Write REPORT.html (self-contained: images embedded, no network), REPORT.md and the PNGs in "
        "REPORT_files/: the target, fit and residual images, the parameter table (fit, Laplace ±, posterior median "
        "and 16/84, 2.5/97.5 percentiles), the correlation matrix, a corner plot, trace plots, the sampler's "
        "diagnostics, the Laplace-versus-posterior comparison and plain-language warnings about degeneracies. "
        "Give a fit result (--fit), a chain (--chain), or both; without a chain the intervals are the Laplace ones.",
    )
    parser.add_argument("--fit", metavar="RESULT.json", help="fit result of 'strauss-fit fit' (default: the fit stored in --chain)")
    parser.add_argument("--chain", metavar="CHAIN.h5", help="chain of 'strauss-fit sample'")
    parser.add_argument("--target", metavar="TARGET", help="the reference image (default: the one recorded in the fit or chain)")
    parser.add_argument("--scene", metavar="SCENE.toml", help="the scene file (default: the one recorded in the fit or chain)")
    parser.add_argument("--mask", metavar="MASK", help="mask image, as given to fit/sample (default: the chain's, if any)")
    parser.add_argument("--encoding", choices=("auto", "linear", "srgb"), default=None,
                        help="how TARGET's values are encoded (default: as recorded, else auto)")
    parser.add_argument("-o", "--output", required=True, metavar="REPORT.html",
                        help="the HTML page; REPORT.md and the folder REPORT_files/ are written beside it")
    parser.add_argument("--title", help="the report's title")
    parser.add_argument("--force", action="store_true", help="overwrite an existing report")
    parser.set_defaults(run=run)


def _recorded(path: str | None, base: Path | None) -> str | None:
    """A path recorded in a result: as written if it exists from here, else relative to
    the folder of the file that recorded it."""
    if path is None:
        return None
    if Path(path).exists() or base is None or Path(path).is_absolute():
        return path
    candidate = base / path
    return str(candidate) if candidate.exists() else path


def run(args: argparse.Namespace) -> int:
    from strauss_fit import load_scene
    from strauss_fit.errors import StraussFitError
    from strauss_fit.io import read_json
    from strauss_fit.report import build_report, check_report_outputs, render_fit, write_report
    from strauss_fit.sample import load_chain
    from strauss_fit.target import load_target, match_scene

    if not args.fit and not args.chain:
        raise StraussFitError("give a fit result (--fit RESULT.json), a chain (--chain CHAIN.h5), or both")
    if Path(args.output).suffix.lower() not in (".html", ".htm"):
        raise StraussFitError(f"the report is HTML: give -o a .html name, got {args.output}")
    check_report_outputs(args.output, args.force)
    chain = load_chain(args.chain) if args.chain else None
    meta = chain.meta if chain is not None else {}
    chain_base = Path(args.chain).parent if args.chain else None
    if args.fit:
        fit = read_json(args.fit, "fit result")
        fit_base = Path(args.fit).parent
        if not isinstance(fit, dict) or "free" not in fit:
            raise StraussFitError(f"{args.fit} is not a strauss-fit fit result (no 'free' list)")
    else:
        fit, fit_base = meta["fit"], chain_base
    target_path = args.target or _recorded(meta.get("target"), chain_base) or _recorded(fit.get("target"), fit_base)
    scene_path = args.scene or _recorded(meta.get("scene"), chain_base) or _recorded(fit.get("scene"), fit_base)
    if not target_path:
        raise StraussFitError("the fit result does not record its target: give --target")
    if not scene_path:
        raise StraussFitError("the fit result does not record its scene: give --scene")
    # the fit result records its mask and encoding only if 'fit' wrote them (older results do not)
    mask = args.mask or _recorded(meta.get("mask"), chain_base) or _recorded(fit.get("mask"), fit_base)
    encoding = args.encoding or meta.get("encoding") or fit.get("encoding") or "auto"
    scene = load_scene(scene_path)
    target = load_target(target_path, mask, encoding)
    scene, _ = match_scene(scene, target)
    fitted, used = render_fit(scene, target, fit)
    if fit.get("pixels_used") is not None and int(used.sum()) != int(fit["pixels_used"]):
        raise StraussFitError(f"the fit used {fit['pixels_used']} pixels but {target_path} has {int(used.sum())} "
                              "usable sphere pixels: give the target (and --mask) the fit was made with")
    out = Path(args.output)
    report = build_report(fit, target.pixels, fitted, used, chain=chain, title=args.title,
                          assets=f"{out.stem}_files", sources={"target": str(target_path), "scene": str(scene_path)})
    written = write_report(report, out, force=args.force)
    for warning in report.data.get("warnings", []):
        print(f"warning: {warning}", file=sys.stderr)
    print(f"wrote {', '.join(str(p) for p in written)}")
    return 0
