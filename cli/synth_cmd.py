"""``strauss-fit synth``: generate a synthetic dataset from a TOML dataset spec."""

from __future__ import annotations

import argparse
import sys

from ._options import add_force_option, add_output_option, add_quiet_option
from .common import bounded_int, positive_int


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "synth",
        help="generate a synthetic sphere dataset (Strauss or Phong) with ground truth",
        description="Render every sample of the dataset SPEC (a grid or a seeded random draw over the "
        "Strauss or Phong parameters, in one or more scenes, through an optional sensor model) into "
        "OUTDIR: per sample an image (.exr linear and/or .png sRGB with a clip mask) and a JSON sidecar "
        "with the exact parameters; OUTDIR/index.json lists the complete samples. The same seed gives "
        "byte-identical files; an interrupted run continues with --resume. A sample that cannot be made (its "
        "scene is unusable, its rendering not finite) is reported and skipped, and the exit status is 1.",
    )
    parser.add_argument("spec", metavar="SPEC.toml", help="dataset spec (see docs/datasets.md and docs/formats.md)")
    add_output_option(parser, metavar="OUTDIR", help="dataset folder (created if missing)")
    add_force_option(
        parser,
        "replace the dataset in a non-empty OUTDIR (removes the files its index lists)",
        resume="continue the dataset in OUTDIR, skipping complete samples",
    )
    parser.add_argument(
        "--seed", type=bounded_int(0, 2**63 - 1), metavar="N", help="override the spec's seed (an integer >= 0)"
    )
    parser.add_argument(
        "--limit",
        type=positive_int,
        metavar="N",
        help="write at most N samples in this run (continue later with --resume)",
    )
    add_quiet_option(parser, "no progress lines, only the summary")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from data_synth import generate, load_spec
    from data_synth.generate import Progress, unusable_scenes

    from . import interrupts

    spec = load_spec(args.spec, seed=args.seed)
    for group, error, count in unusable_scenes(spec):
        print(f"synth: warning: group {group}: {count} sample(s) will be skipped: {error}", file=sys.stderr)

    def progress(p: Progress) -> None:
        interrupts.check()
        if p.error is not None:
            print(f"synth: [{p.done}/{p.total}] {p.sample_id} FAILED: {p.error}", file=sys.stderr, flush=True)
        elif not args.quiet:
            print(f"synth: [{p.done}/{p.total}] {p.sample_id} ({p.seconds:.2f} s)", file=sys.stderr, flush=True)

    report = generate(spec, args.output, force=args.force, resume=args.resume, limit=args.limit, progress=progress)
    resumed = f", {report.skipped} already complete" if report.skipped else ""
    failed = f", {len(report.failed)} failed (listed above; not written)" if report.failed else ""
    print(
        f"wrote {report.written} sample(s) to {report.output}{resumed}{failed}; "
        f"{report.complete} of {report.total} complete (index: {report.output / 'index.json'})"
    )
    if report.stopped_by_limit:
        print(f"stopped after --limit {args.limit}; rerun with --resume to continue")
    return 1 if report.failed else 0
