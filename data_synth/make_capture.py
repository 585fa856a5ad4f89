"""``python -m data_synth.make_capture KIND OUTDIR``: write one of the example synthetic
captures of `data_synth.capture` (images, ``mask.png``, ``capture.toml``, ``truth.json``).

A module of its own so that running it does not import `data_synth.capture` twice
(once by the package, once as ``__main__``).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from strauss_fit.errors import StraussFitError

from .capture import EXAMPLES, MANIFEST_NAME, TRUTH_NAME, example_capture_spec, write_capture


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m data_synth.make_capture KIND OUTDIR [--force] [--seed N]``: write an example capture."""
    parser = argparse.ArgumentParser(
        prog="python -m data_synth.make_capture",
        description="Write a synthetic capture (images, mask.png, capture.toml, truth.json) with known truth.",
    )
    parser.add_argument("kind", choices=EXAMPLES, help="which example spec")
    parser.add_argument("outdir", type=Path, help="output folder (created if missing)")
    parser.add_argument("--force", action="store_true", help="replace existing files")
    parser.add_argument("--seed", type=int, help="the noise seed (default: the spec's, 0)")
    args = parser.parse_args(argv)
    try:
        overrides = {} if args.seed is None else {"seed": args.seed}
        spec = example_capture_spec(args.kind, **overrides)
        truth = write_capture(spec, args.outdir, force=args.force)
    except StraussFitError as exc:
        print(f"capture: error: {exc}", file=sys.stderr)
        return 2
    saturated = sum(1 for count in truth["saturated_pixels"] if count)
    print(
        f"wrote {len(truth['files'])} images ({saturated} with saturated pixels), "
        f"{MANIFEST_NAME} and {TRUTH_NAME} to {args.outdir}",
        file=sys.stderr,
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
