"""``strauss-fit report``: a self-contained HTML (and Markdown) uncertainty report
(:func:`strauss_fit.reporting.fit_report.report_from_files`)."""

from __future__ import annotations

import argparse
import sys


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "report",
        help="write an HTML and Markdown report of a fit's uncertainty",
        description="Write REPORT.html (self-contained: images embedded, no network), REPORT.md and the PNGs in "
        "REPORT_files/: the target, fit and residual images, the parameter table (fit, the fit's ± headed by its "
        "kind, noise sandwich or Laplace, posterior median and 16/84, 2.5/97.5 percentiles), "
        "the correlation matrix, a corner plot, trace plots, the sampler's diagnostics, the fit's ± against the "
        "posterior and plain-language warnings about degeneracies. Give a fit result (--fit), a chain (--chain), "
        "or both; without a chain the intervals are the fit's Gaussian ones (x +/- sd, x +/- 1.96 sd).",
    )
    parser.add_argument(
        "--fit", metavar="RESULT.json", help="fit result of 'strauss-fit fit' (default: the fit stored in --chain)"
    )
    parser.add_argument("--chain", metavar="CHAIN.h5", help="chain of 'strauss-fit sample'")
    parser.add_argument(
        "--target", metavar="TARGET", help="the reference image (default: the one recorded in the fit or chain)"
    )
    parser.add_argument(
        "--scene", metavar="SCENE.toml", help="the scene file (default: the one recorded in the fit or chain)"
    )
    parser.add_argument(
        "--mask", metavar="MASK", help="mask image, as given to fit/sample (default: the chain's, if any)"
    )
    parser.add_argument(
        "--encoding",
        choices=("auto", "linear", "srgb"),
        default=None,
        help="how TARGET's values are encoded (default: as recorded, else auto)",
    )
    parser.add_argument(
        "-o",
        "--output",
        required=True,
        metavar="REPORT.html",
        help="the HTML page; REPORT.md and the folder REPORT_files/ are written beside it",
    )
    parser.add_argument("--title", help="the report's title")
    parser.add_argument("--force", action="store_true", help="overwrite an existing report")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from strauss_fit import report_from_files
    from strauss_fit.io.files import check_distinct
    from strauss_fit.reporting.fit_report import report_paths

    page, markdown, _ = report_paths(args.output)
    check_distinct(
        {"-o": page, "-o's Markdown": markdown},
        {"--fit": args.fit, "--chain": args.chain, "--target": args.target, "--scene": args.scene, "--mask": args.mask},
    )

    report, written = report_from_files(
        args.output,
        fit=args.fit,
        chain=args.chain,
        target=args.target,
        scene=args.scene,
        mask=args.mask,
        encoding=args.encoding,
        title=args.title,
        force=args.force,
    )
    if report.data.get("verdict"):
        print(f"fit verdict: {report.data['verdict']}", file=sys.stderr)
    for warning in report.data.get("warnings", []):
        print(f"warning: {warning}", file=sys.stderr)
    print(f"wrote {', '.join(str(p) for p in written)}")
    return 0
