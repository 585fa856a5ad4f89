"""``strauss-fit study``: the intuitive-parameter study (Strauss vs Phong) as a report."""

from __future__ import annotations

import argparse

from ._options import add_force_option, add_output_option, add_quiet_option
from .common import progress_printer


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "study",
        help="measure whether Strauss's parameters are more intuitive and consistent than Phong's",
        description="Run the intuitive-parameter study — consistency (energy created by novice settings), "
        "independence (Fisher information on the same images), uniformity (image change per equal step) and "
        "expressiveness (conversions both ways; with --merl-fits and --capture also on measured materials and "
        "real photographs) — and write OUTDIR/study.html (self-contained), study.md with PNG plots, and "
        "study.json with every figure, all or none. See docs/study.md.",
    )
    add_output_option(
        parser, metavar="OUTDIR", help="folder for the report (created if missing; its parent must exist)"
    )
    parser.add_argument(
        "--size",
        choices=("small", "full", "tiny"),
        default="small",
        help="small (default, a few minutes on two cores), full (thorough, much longer), or tiny "
        "(a smoke test; too small to conclude anything)",
    )
    parser.add_argument("--seed", type=int, metavar="N", help="seed of every random draw, >= 0 (default 1990)")
    parser.add_argument(
        "--merl-fits",
        metavar="PATH",
        help="also measure both models on the MERL materials as Ngan et al. (2005) fitted them: bbm's "
        "fits_parsed.json or its folder (read where it is; see docs/study.md, part 5)",
    )
    parser.add_argument(
        "--capture",
        metavar="PATH",
        help="also fit every capture model to these real photographs (a capture folder or manifest, e.g. "
        "DiLiGenT's ballPNG): held-out error and stability over two halves (docs/study.md, part 6)",
    )
    add_force_option(parser, "overwrite an existing report in OUTDIR")
    add_quiet_option(parser, "no progress lines")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from strauss_fit import run_study, study_config
    from strauss_fit.errors import StraussFitError
    from strauss_fit.study.real import read_ngan_fits
    from strauss_fit.study.real_report import (
        CAPTURE_ASPECT,
        MERL_ASPECT,
        all_conclusions,
        check_study_outputs,
        write_study_report,
    )

    if args.seed is not None and args.seed < 0:
        raise StraussFitError(f"--seed must be >= 0, got {args.seed}")
    check_study_outputs(args.output, args.force, merl=args.merl_fits is not None)
    if args.merl_fits is not None:
        read_ngan_fits(args.merl_fits)  # a bad file is refused before the study runs
    if args.capture is not None:
        from strauss_fit.capture import open_capture

        open_capture([args.capture])
    config = study_config(args.size, args.seed)
    log = progress_printer(args.quiet, "study: ")
    log(f"running the '{config.name}' study (seed {config.seed})")
    study = run_study(config, log, merl_fits=args.merl_fits, capture=args.capture)
    written = write_study_report(study, args.output, force=args.force)
    for verdict in all_conclusions(study):
        if verdict["aspect"] in ("expressiveness", MERL_ASPECT, CAPTURE_ASPECT):  # comparisons, not the claim
            print(f"{verdict['aspect']}: {verdict['verdict']}")
        else:
            phrase = {"holds": "holds", "does not hold": "does not hold", "mixed": "is mixed"}[verdict["verdict"]]
            print(f"{verdict['aspect']}: the claim {phrase}")
        print(f"  {verdict['key']}")
    print(f"wrote {', '.join(str(p) for p in written)}")
    return 0
