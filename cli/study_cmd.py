"""``strauss-fit study``: the intuitive-parameter study (Strauss vs Phong) as a report."""

from __future__ import annotations

import argparse

from .common import progress_printer


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "study",
        help="measure whether Strauss's parameters are more intuitive and consistent than Phong's",
        description="Run the intuitive-parameter study — consistency (energy created by novice settings), "
        "independence (Fisher information on the same images), uniformity (image change per equal step) and "
        "expressiveness (conversions both ways) — and write OUTDIR/study.html (self-contained), study.md with "
        "PNG plots, and study.json with every figure, all or none. See docs/study.md.",
    )
    parser.add_argument(
        "-o",
        "--output",
        required=True,
        metavar="OUTDIR",
        help="folder for the report (created if missing; its parent must exist)",
    )
    parser.add_argument(
        "--size",
        choices=("small", "full", "tiny"),
        default="small",
        help="small (default, a few minutes on two cores), full (thorough, much longer), or tiny "
        "(a smoke test; too small to conclude anything)",
    )
    parser.add_argument("--seed", type=int, metavar="N", help="seed of every random draw, >= 0 (default 1990)")
    parser.add_argument("--force", action="store_true", help="overwrite an existing report in OUTDIR")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from strauss_fit import run_study, study_config
    from strauss_fit.errors import StraussFitError
    from strauss_fit.reporting.study_report import check_outputs, conclusions, write_report

    if args.seed is not None and args.seed < 0:
        raise StraussFitError(f"--seed must be >= 0, got {args.seed}")
    check_outputs(args.output, args.force)
    config = study_config(args.size, args.seed)
    log = progress_printer(args.quiet, "study: ")
    log(f"running the '{config.name}' study (seed {config.seed})")
    study = run_study(config, log)
    written = write_report(study, args.output, force=args.force)
    for verdict in conclusions(study):
        if verdict["aspect"] == "expressiveness":
            print(f"{verdict['aspect']}: {verdict['verdict']}")
        else:
            phrase = {"holds": "holds", "does not hold": "does not hold", "mixed": "is mixed"}[verdict["verdict"]]
            print(f"{verdict['aspect']}: the claim {phrase}")
        print(f"  {verdict['key']}")
    print(f"wrote {', '.join(str(p) for p in written)}")
    return 0
