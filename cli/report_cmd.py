"""``strauss-fit report``: a self-contained HTML (and Markdown) uncertainty report
(`strauss_fit.reporting.fit_report.report_from_files`; for a capture's fit result,
`strauss_fit.reporting.capture_report.capture_report_from_files`)."""

from __future__ import annotations

import argparse
import sys

from ._options import add_capture_inputs, add_force_option, add_image_inputs, add_output_option


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "report",
        help="write an HTML and Markdown report of a fit's uncertainty",
        description="Write REPORT.html (self-contained: images embedded, no network), REPORT.md and the PNGs in "
        "REPORT_files/: the target, fit and residual images, the parameter table (fit, the fit's ± headed by its "
        "kind, noise sandwich or Laplace, posterior median and 16/84, 2.5/97.5 percentiles), "
        "the correlation matrix, a corner plot, trace plots, the sampler's diagnostics, the fit's ± against the "
        "posterior and plain-language warnings about degeneracies. Give a fit result (--fit), a chain (--chain), "
        "or both; without a chain the intervals are the fit's Gaussian ones (x +/- sd, x +/- 1.96 sd). "
        "For a capture's fit result (fit --capture) the report reads the capture again and shows, per light, the "
        "target, the fit and the residual, the held-out images with their prediction last; with a capture's chain "
        "(sample --fit of such a result; alone, it uses the fit stored in it) also its posterior, corner plot and "
        "diagnostics.",
    )
    parser.add_argument(
        "--fit", metavar="RESULT.json", help="fit result of 'strauss-fit fit' (default: the fit stored in --chain)"
    )
    parser.add_argument("--chain", metavar="CHAIN.h5", help="chain of 'strauss-fit sample'")
    parser.add_argument(
        "--target", metavar="TARGET", help="the reference image (default: the one recorded in the fit or chain)"
    )
    add_image_inputs(
        parser,
        target=None,  # an option here (--target): the fit result or chain records it
        scene="the scene file (default: the one recorded in the fit or chain)",
        mask="mask image, as given to fit/sample (default: the chain's, if any)",
        encoding="how TARGET's values are encoded (default: as recorded, else auto)",
        encoding_default=None,
    )
    add_output_option(
        parser,
        metavar="REPORT.html",
        help="the HTML page; REPORT.md and the folder REPORT_files/ are written beside it",
    )
    add_capture_inputs(
        parser,
        capture="for a capture's fit result: read the capture from here (a manifest, a folder or image files) "
        "instead of the paths the result records",
        lights="for a capture's fit result: the lights file instead of the recorded one",
    )
    parser.add_argument("--title", help="the report's title")
    add_force_option(parser, "overwrite an existing report")
    parser.set_defaults(run=run)


#: The inputs a fit result records (``strauss-fit fit`` writes them beside its figures).
RECORDED_INPUTS = ("target", "scene", "mask", "encoding")


def recorded_inputs(fit: str, given: dict[str, str | None], spelled: dict[str, str]) -> dict[str, str | None]:
    """The inputs (`RECORDED_INPUTS`) of a command given the fit result ``fit`` (the
    path of its JSON): each one ``given`` (not None) as it is, else the one the result
    records, a recorded path tried as written and then relative to the result's folder
    (`strauss_fit.reporting.fit_report.recorded_path`, as ``report`` reads a fit or a
    chain), else None. A recorded path found in neither place is a one-line error naming it
    and the option to give instead (``spelled``: how the command writes each input,
    ``TARGET`` or ``--target``). The one rule of ``report --fit`` and ``sample --fit``."""
    from pathlib import Path

    from strauss_fit.errors import StraussFitError
    from strauss_fit.io.files import read_json
    from strauss_fit.reporting.fit_report import recorded_path

    data = read_json(fit, "fit result")
    if not isinstance(data, dict) or "free" not in data:
        raise StraussFitError(f"{fit} is not a strauss-fit fit result (no 'free' list)")
    inputs = dict(given)
    for name in RECORDED_INPUTS:
        value = data.get(name)
        if inputs.get(name) is not None or value is None:
            continue
        if not isinstance(value, str) or not value:
            raise StraussFitError(f"the fit result {fit} records no usable {name} ({value!r}): give {spelled[name]}")
        if name == "encoding":
            inputs[name] = value
            continue
        path = recorded_path(value, Path(fit).parent)
        if not Path(path).exists():
            raise StraussFitError(
                f"the fit result {fit} records the {name} {value}, which no longer exists (tried from here and "
                f"from the result's folder): give {spelled[name]} explicitly"
            )
        inputs[name] = path
    return inputs


def _print_report(report, written) -> int:
    from .common import escape

    if report.data.get("verdict"):
        print(f"fit verdict: {report.data['verdict']}", file=sys.stderr)
    for warning in report.data.get("warnings", []):
        print(f"warning: {escape(warning, newlines=True)}", file=sys.stderr)  # they quote the fit's file
    print(escape(f"wrote {', '.join(str(p) for p in written)}", newlines=True))
    return 0


def _is_capture_result(fit: str | None) -> bool:
    from strauss_fit.fitting.capture_result import is_capture_result
    from strauss_fit.io.files import read_json

    return bool(fit) and is_capture_result(read_json(fit, "fit result"))


def _is_capture_chain(chain: str) -> bool:
    """Whether ``chain`` is a capture's chain (``sample --fit`` of a capture's result); a file
    that cannot be read says no here: the report's own checks then say why."""
    from strauss_fit.errors import StraussFitError

    try:
        from strauss_fit.inference.sampler import read_metadata

        return read_metadata(chain, required=False).get("kind") == "capture"
    except (StraussFitError, OSError):
        return False


def run_capture(args: argparse.Namespace) -> int:
    """The report of a capture's fit result, its chain, or both
    (`strauss_fit.reporting.capture_report.capture_report_from_files`; with --chain
    alone, the fit its metadata holds)."""
    from strauss_fit.errors import StraussFitError
    from strauss_fit.io.files import check_distinct, check_outside
    from strauss_fit.reporting.capture_report import capture_report_from_files
    from strauss_fit.reporting.fit_report import report_paths

    for option in ("target", "scene", "encoding"):
        if getattr(args, option) is not None:
            raise StraussFitError(
                f"--{option} is for the fit of one image; a capture's fit result records its capture "
                "(give --capture to read it from elsewhere)"
            )
    page, markdown, folder = report_paths(args.output)
    inputs = {"--fit": args.fit, "--chain": args.chain, "--lights": args.lights, "--mask": args.mask}
    inputs.update({f"--capture {path}": path for path in args.capture or []})
    check_distinct({"-o": page, "-o's Markdown": markdown}, inputs)
    check_outside(folder, "-o", inputs)
    report, written = capture_report_from_files(
        args.fit,
        args.output,
        chain=args.chain,
        capture=args.capture,
        lights=args.lights,
        mask=args.mask,
        title=args.title,
        force=args.force,
    )
    return _print_report(report, written)


def run(args: argparse.Namespace) -> int:
    from strauss_fit import report_from_files
    from strauss_fit.errors import StraussFitError
    from strauss_fit.io.files import check_distinct, check_outside
    from strauss_fit.reporting.fit_report import report_paths

    if _is_capture_result(args.fit):
        return run_capture(args)
    if args.chain and _is_capture_chain(args.chain):
        if args.fit:
            raise StraussFitError(
                f"the chain {args.chain} is a capture's but {args.fit} is the fit result of one image: they belong "
                "to different fits (give the capture's fit result the chain was sampled from, or --chain alone)"
            )
        return run_capture(args)
    if args.capture or args.lights:
        raise StraussFitError("--capture and --lights are for a capture's fit result (--fit of 'fit --capture')")
    if args.fit and not args.chain:  # with a chain, its recorded inputs come first (report_from_files)
        inputs = recorded_inputs(
            args.fit,
            {"target": args.target, "scene": args.scene, "mask": args.mask, "encoding": args.encoding},
            {"target": "--target", "scene": "--scene", "mask": "--mask", "encoding": "--encoding"},
        )
        args.target, args.scene, args.mask, args.encoding = (inputs[name] for name in RECORDED_INPUTS)
    page, markdown, folder = report_paths(args.output)
    inputs = {
        "--fit": args.fit,
        "--chain": args.chain,
        "--target": args.target,
        "--scene": args.scene,
        "--mask": args.mask,
    }
    check_distinct({"-o": page, "-o's Markdown": markdown}, inputs)
    check_outside(folder, "-o", inputs)

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
    return _print_report(report, written)
