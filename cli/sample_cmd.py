"""``strauss-fit sample``: sample the posterior of a fit with emcee (resumable HDF5 chain).

The work is `strauss_fit.inference.sampler.sample`; this module parses the options,
shows the progress and prints the summary.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from typing import Any

from strauss_fit.fitting.options import QUALITY_PRESETS
from strauss_fit.models.modes import DEFAULT_TABLE_SIZE

from ._options import (
    add_evaluator_options,
    add_fitting_options,
    add_force_option,
    add_image_inputs,
    add_output_option,
    add_quality_option,
    add_quiet_option,
)
from .common import (
    bounded_int,
    by_quality,
    check_evaluator_options,
    finite_float,
    positive_int,
    progress_printer,
)

#: Options that only apply when ``sample`` fits first, with their defaults.
_FIT_ONLY = {
    "free": None,
    "fix": [],
    "fit_lights": False,
    "solver": "lm",
    "starts": None,
    "mode": "exact",
    "table_size": DEFAULT_TABLE_SIZE,
}
#: Largest --walkers (each walker holds a parameter vector in every stored step).
MAX_WALKERS = 100_000
#: Options fixed by an existing chain, which --resume refuses to change.
_CHAIN_FIXED = ("fit", "sigma", "walkers", "prior", "seed", "adjust", "values")
#: A capture's likelihood: values evaluated by default
#: (`strauss_fit.inference.capture_posterior.DEFAULT_VALUES`, not imported here: the
#: command line starts without JAX).
_DEFAULT_VALUES = 100_000
#: The single image's inputs, which a capture's fit result does not take.
_IMAGE_INPUTS = (("target", "TARGET"), ("scene", "--scene"), ("mask", "--mask"), ("encoding", "--encoding"))


def _values_option(text: str) -> int | str:
    """``--values``: a positive number of values, or ``all``."""
    if text.strip().lower() == "all":
        return "all"
    return positive_int(text)


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "sample",
        help="sample the posterior of the parameters with emcee",
        description="Sample the posterior of the Strauss parameters of SCENE given the image TARGET with emcee's "
        "ensemble sampler, started around the least-squares optimum (from --fit, a fit made with --loss linear, "
        "or fitted first by least squares). Gaussian noise of standard deviation sigma (--sigma; else the "
        "target's noise as the fit found it when the fit knew it; else estimated from the fit's residual), "
        "uniform priors over the parameters' ranges. Runs until the chain is --min-tau-multiple autocorrelation "
        "times long and its estimate has settled (or --max-steps). Writes CHAIN.h5 (emcee's HDF5 format) and a "
        "summary CHAIN.json beside it. Ctrl-C keeps every step sampled; continue with --resume. With --fit "
        "CAPTURE_RESULT.json (strauss-fit fit --capture), samples the capture's material instead: the capture it "
        "records is read again, and TARGET, --scene, --mask and --encoding do not apply.",
    )
    add_image_inputs(
        parser,
        target=dict(
            nargs="?",
            help="reference image (.exr/.hdr/.tif linear; .png/.jpg sRGB); with --fit, default: the one the fit "
            "result records",
        ),
        scene="the scene the target was taken in; with --fit, default: the one the fit result records",
        mask="mask image: pixels where it is non-zero are used (with --fit, default: the one the fit result records)",
        encoding="how TARGET's values are encoded (default: as the fit result records, with --fit; else auto: sRGB "
        "for .png/.jpg, linear otherwise)",
        encoding_default=None,
    )
    add_output_option(parser, metavar="CHAIN.h5", help="chain file (HDF5)")
    parser.add_argument(
        "--fit",
        metavar="RESULT.json",
        help="start from this fit result (strauss-fit fit) instead of fitting first; it must be a least-squares "
        "fit (fit --loss linear): the likelihood sampled is least squares. TARGET, --scene, --mask and "
        "--encoding default to the ones it records",
    )
    _add_sampling_options(parser)
    parser.add_argument("--resume", action="store_true", help="continue the chain in CHAIN.h5 up to --max-steps")
    add_force_option(parser, "replace an existing CHAIN.h5 and CHAIN.json")
    add_quiet_option(parser, "no progress output")
    fitting = parser.add_argument_group("fitting first (without --fit)")
    add_fitting_options(fitting, as_for_fit=True)
    add_evaluator_options(
        fitting,
        mode="evaluator, as for 'fit' (default exact); a fit result (--fit) brings its own",
        table_size=f"table entries for the table modes (default {DEFAULT_TABLE_SIZE})",
        precision=False,
    )
    add_quality_option(parser)
    parser.set_defaults(run=run)


def _add_sampling_options(parser: argparse.ArgumentParser) -> None:
    """The sampler's own options: the likelihood (``--sigma``, ``--adjust``, ``--prior``,
    ``--values``), the ensemble and when it stops."""
    parser.add_argument(
        "--sigma",
        type=finite_float(0.0, open_low=True),
        metavar="S",
        help="noise standard deviation per RGB value, linear units (default: the target's noise as the fit "
        "found it, root mean square over the channels; without one, estimated from the fit's residual, "
        "sqrt(RSS/(N-P)))",
    )
    parser.add_argument(
        "--adjust",
        choices=("affine", "temperature", "none"),
        metavar="{affine,temperature,none}",
        help="make the posterior's width match the fit's noise sandwich on a target the model cannot "
        "reproduce: affine maps the draws (theta' = theta_hat + A (theta - theta_hat), A Sigma_post A^T = V; "
        "the raw chain is kept and A stored with it), temperature samples with sigma x sqrt(T) (T = max(1, the "
        "largest generalised eigenvalue): conservative, never narrower), none samples the Gaussian likelihood as "
        "it is (default: affine when the fit's uncertainty is the noise sandwich and its verdict is 'mismatch', "
        "else none)",
    )
    parser.add_argument(
        "--prior",
        action="append",
        default=[],
        metavar="NAME=LOW,HIGH",
        help="narrow the uniform prior of a parameter (repeatable; color or color_r, ... ; inside "
        "the parameter's range)",
    )
    parser.add_argument(
        "--walkers",
        type=bounded_int(1, MAX_WALKERS),
        metavar="N",
        help="number of walkers, even, >= 2 x parameters (default: from --quality: "
        + ", ".join(
            f"{name} {'max(32, 4 x parameters)' if values['walkers'] is None else values['walkers']}"
            for name, values in QUALITY_PRESETS.items()
        )
        + ")",
    )
    parser.add_argument(
        "--max-steps",
        type=positive_int,
        metavar="N",
        help="cap on the chain's total length in steps, earlier runs included (default: from --quality: "
        f"{by_quality('sample_max_steps')})",
    )
    parser.add_argument(
        "--min-tau-multiple",
        type=finite_float(0.0, open_low=True),
        metavar="K",
        help=f"stop when the chain is K autocorrelation times long (default: from --quality: "
        f"{by_quality('min_tau_multiple')})",
    )
    parser.add_argument(
        "--check-every",
        type=positive_int,
        default=100,
        metavar="N",
        help="steps between convergence checks and progress lines (default 100)",
    )
    parser.add_argument(
        "--seed",
        type=bounded_int(0, 2**32 - 1),
        default=0,
        metavar="N",
        help="random seed of the walkers, 0 to 2^32 - 1 (default 0)",
    )
    parser.add_argument(
        "--values",
        type=_values_option,
        metavar="N|all",
        help="a capture's fit result only: the values (image x pixel x channel) the likelihood evaluates, a fixed "
        f"random subsample of sphere pixels through the difference estimator (default {_DEFAULT_VALUES}; all: "
        "every value, exact)",
    )


class ProgressBar:
    """Progress on stderr: a bar redrawn in place on a terminal, else a line at most
    every few seconds.

    The goal shown is the length the stopping rule needs (``min_tau_multiple`` times τ̂)
    while the chain is shorter. Once it is that long the run still goes on until τ̂ has
    settled (`strauss_fit.inference.sampler.TAU_STABILITY`), at a step nobody knows
    in advance: the goal is then the cap, ``max_steps``, and the line says what it waits
    for — rather than a goal equal to the steps done, a full bar on every line while
    sampling goes on."""

    def __init__(self, quiet: bool, stream=None):
        self.quiet = quiet
        self.stream = stream or sys.stderr
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.last = 0.0
        self.drawn = False
        self.width = 0  # of the line drawn last on a terminal (a shorter one pads it out)

    def __call__(self, p) -> None:
        if self.quiet:
            return
        waiting = p.needed_steps <= p.steps < p.max_steps  # long enough; tau not yet settled
        goal = p.max_steps if waiting else min(p.max_steps, max(p.needed_steps, p.steps))
        fraction = min(p.steps / max(goal, 1), 1.0)
        bar = "#" * int(30 * fraction) + "." * (30 - int(30 * fraction))
        wait = f" (needed {p.needed_steps}: waiting for tau to settle)" if waiting else ""
        text = (
            f"sample [{bar}] {p.steps}/{goal} steps{wait} | tau {p.tau_max:.1f} (x{p.steps / p.tau_max:.0f}) | "
            f"acceptance {p.acceptance:.2f} | {p.steps_per_s:.0f} steps/s"
        )
        if self.tty:
            self.stream.write("\r" + text.ljust(self.width))
            self.stream.flush()
            self.drawn = True
            self.width = len(text)
        elif time.monotonic() - self.last > 3.0 or p.steps >= goal:
            print(text, file=self.stream)
            self.last = time.monotonic()

    def close(self) -> None:
        if self.drawn:
            self.stream.write("\n")
            self.stream.flush()
            self.drawn = False


def _sampling_settings(args: argparse.Namespace):
    """The checks a single image and a capture share; returns the sampling settings
    (``--quality`` with the options given explicitly)."""
    from strauss_fit import SampleSettings
    from strauss_fit.errors import StraussFitError
    from strauss_fit.inference.posterior import check_sigma

    check_evaluator_options(args)
    if args.sigma is not None:
        check_sigma(args.sigma, "--sigma")  # > 0, and σ² and 1/σ² within float64's range
    settings = SampleSettings.preset(
        args.quality,
        max_steps=args.max_steps,
        min_tau_multiple=args.min_tau_multiple,
        check_every=args.check_every,
        seed=args.seed,
        walkers=args.walkers,
    )
    if settings.min_tau_multiple <= 0:
        raise StraussFitError(f"--min-tau-multiple must be > 0, got {settings.min_tau_multiple:g}")
    if args.resume and args.force:
        raise StraussFitError("--resume continues CHAIN.h5 and --force replaces it: give one of them")
    if args.walkers is not None and args.walkers % 2:
        raise StraussFitError(f"--walkers must be even (emcee updates the ensemble in two halves), got {args.walkers}")
    if args.fit or args.resume:
        given = [k for k, default in _FIT_ONLY.items() if getattr(args, k) != default]
        if given:
            where = "--resume (the chain's fit is used)" if args.resume else "--fit"
            raise StraussFitError(
                f"--{given[0].replace('_', '-')} applies only when sample fits first; not with {where}"
            )
    if args.resume:
        changed = [k for k in _CHAIN_FIXED if getattr(args, k) not in (None, [], 0)]
        if changed:
            raise StraussFitError(
                f"--{changed[0]} cannot change when resuming: the chain keeps the value it was "
                "started with (start a new chain with --force)"
            )
    return settings


def _check_priors(args: argparse.Namespace) -> dict[str, tuple[float, float]]:
    from strauss_fit.errors import StraussFitError
    from strauss_fit.inference.posterior import parse_priors

    priors = parse_priors(args.prior)
    for name, (low, high) in priors.items():  # checked here, before any work
        if not (math.isfinite(low) and math.isfinite(high)) or not low < high:
            raise StraussFitError(f"--prior {name}={low:g},{high:g}: expected finite LOW < HIGH")
    return priors


def _check_options(args: argparse.Namespace):
    """Validate the options; returns the sampling settings (``--quality`` with the options
    given explicitly), the prior ranges and, when sample fits first, the fit options."""
    from pathlib import Path

    from strauss_fit.errors import StraussFitError
    from strauss_fit.io.files import check_distinct

    from .fit_cmd import check_fixed_ranges, fit_options, parse_fixed
    from .report_cmd import RECORDED_INPUTS, recorded_inputs

    settings = _sampling_settings(args)
    if args.values is not None:
        raise StraussFitError("--values applies only to a capture's fit result (--fit from strauss-fit fit --capture)")
    if args.fit and not args.resume:  # the inputs the fit records, as report reads them
        inputs = recorded_inputs(
            args.fit,
            {"target": args.target, "scene": args.scene, "mask": args.mask, "encoding": args.encoding},
            {"target": "TARGET", "scene": "--scene", "mask": "--mask", "encoding": "--encoding"},
        )
        args.target, args.scene, args.mask, args.encoding = (inputs[name] for name in RECORDED_INPUTS)
    missing = [name for name, value in (("TARGET", args.target), ("--scene", args.scene)) if value is None]
    if missing and args.fit and not args.resume:
        what = "target" if missing[0] == "TARGET" else "scene"
        raise StraussFitError(f"the fit result {args.fit} does not record its {what}: give {missing[0]}")
    if missing:
        where = (
            "those the chain was sampled for" if args.resume else "or --fit RESULT.json, a fit result that records them"
        )
        raise StraussFitError(f"give {' and '.join(missing)} ({where})")
    args.encoding = args.encoding or "auto"
    check_distinct(
        {"-o": args.output, "-o's summary": Path(args.output).with_suffix(".json")},
        {"TARGET": args.target, "--scene": args.scene, "--mask": args.mask, "--fit": args.fit},
    )
    priors = _check_priors(args)
    options = None
    if not (args.fit or args.resume):
        fixed = parse_fixed(args.fix)
        check_fixed_ranges(fixed)
        options = fit_options(args, fixed)
    return settings, priors, options


def _is_capture(args: argparse.Namespace) -> bool:
    """Whether the run samples a capture: ``--fit`` is a capture's fit result, or
    ``--resume`` continues a capture's chain. A file that cannot be read says no here: the
    single image's checks then report it."""
    from strauss_fit.errors import StraussFitError

    try:
        if args.fit and not args.resume:
            from strauss_fit.fitting.capture_result import is_capture_result
            from strauss_fit.io.files import read_json

            return is_capture_result(read_json(args.fit, "fit result"))
        if args.resume and not args.fit:
            from strauss_fit.inference.sampler import read_metadata

            return read_metadata(args.output, required=False).get("kind") == "capture"
    except (StraussFitError, OSError):
        return False
    return False


def _check_capture_options(args: argparse.Namespace):
    """The options of a capture's chain: the single image's inputs refused; returns the
    sampling settings and the prior ranges."""
    from pathlib import Path

    from strauss_fit.errors import StraussFitError
    from strauss_fit.io.files import check_distinct

    settings = _sampling_settings(args)
    given = [spelled for name, spelled in _IMAGE_INPUTS if getattr(args, name) is not None]
    if given:
        what = f"the capture's fit result {args.fit}" if args.fit else f"the capture's chain {args.output}"
        only = "--fit and -o" if args.fit else "-o and --resume"
        raise StraussFitError(
            f"{given[0]} does not apply to {what}: the capture it records is read again (give only {only})"
        )
    check_distinct({"-o": args.output, "-o's summary": Path(args.output).with_suffix(".json")}, {"--fit": args.fit})
    return settings, _check_priors(args)


def _run_capture(args: argparse.Namespace) -> int:
    settings, priors = _check_capture_options(args)
    from strauss_fit.inference.capture_posterior import DEFAULT_VALUES, sample_capture

    values = None if args.values == "all" else (args.values or DEFAULT_VALUES)
    log = progress_printer(args.quiet, "... ")
    bar = ProgressBar(args.quiet)
    return _sample_and_print(
        bar,
        lambda: sample_capture(
            args.fit,
            args.output,
            sigma=args.sigma,
            priors=priors,
            settings=settings,
            values=values,
            adjust=args.adjust or "auto",
            quality=args.quality,
            force=args.force,
            resume=args.resume,
            log=log,
            progress=bar,
        ),
    )


def run(args: argparse.Namespace) -> int:
    if _is_capture(args):
        return _run_capture(args)
    settings, priors, options = _check_options(args)
    from strauss_fit import sample

    log = progress_printer(args.quiet, "... ")
    bar = ProgressBar(args.quiet)
    return _sample_and_print(
        bar,
        lambda: sample(
            args.target,
            args.scene,
            args.output,
            mask=args.mask,
            encoding=args.encoding,
            fit=args.fit,
            fit_options=options,
            sigma=args.sigma,
            priors=priors,
            settings=settings,
            quality=args.quality,
            adjust=args.adjust or "auto",
            resume=args.resume,
            force=args.force,
            log=log,
            progress=bar,
        ),
    )


def _sample_and_print(bar: ProgressBar, sampling) -> int:
    """Run ``sampling`` (a call of ``sample`` or ``sample_capture``), then print its
    summary; Ctrl-C says what the chain keeps."""
    from strauss_fit.inference.sampler import SamplingInterrupted

    try:
        result = sampling()
    except SamplingInterrupted as interrupted:
        bar.close()
        print(
            f"strauss-fit: sample: interrupted; {interrupted.path} keeps all {interrupted.steps} steps sampled "
            "so far (continue with --resume)",
            file=sys.stderr,
        )
        raise
    finally:
        bar.close()
    print(format_summary(result.summary))
    print(f"wrote {result.path}, {result.summary_path}")
    return 0 if result.trustworthy else 1


#: Significant digits of the summary's values: at least, and at most.
MIN_DIGITS = 4
MAX_DIGITS = 10


def separating_digits(values: tuple[float, ...]) -> int:
    """The fewest significant digits, from `MIN_DIGITS` to `MAX_DIGITS`, that
    print the distinct ``values`` (a row's 16 %, median and 84 %) as distinct strings. A
    narrow posterior (a deviation of 10⁻⁵ on a value near 0.2) needs more than four digits,
    or its interval collapses to one number in every column; a wide one keeps four."""
    finite = [float(v) for v in values if math.isfinite(v)]
    distinct = len(set(finite))
    for digits in range(MIN_DIGITS, MAX_DIGITS + 1):
        if len({f"{v:.{digits}g}" for v in finite}) == distinct:
            return digits
    return MAX_DIGITS


def format_summary(payload: dict[str, Any]) -> str:
    d = payload["diagnostics"]
    method = payload.get("uncertainty_method", "laplace")
    rows = [
        (
            "parameter",
            "fit",
            {"noise sandwich": "sandwich ±", "image-cluster sandwich": "cluster ±"}.get(method, "Laplace ±"),
            "median",
            "16 %",
            "84 %",
            "2.5 %",
            "97.5 %",
            "tau",
            "ESS",
        )
    ]
    lap = payload["laplace"]
    for k, label in enumerate(payload["labels"]):
        p = payload["posterior"]["parameters"][label]
        digits = separating_digits((p["p16"], p["median"], p["p84"]))
        rows.append(
            (
                label,
                f"{lap['x_hat'][k]:.{digits}g}",
                f"{lap['sd'][k]:.2g}",
                f"{p['median']:.{digits}g}",
                f"{p['p16']:.{digits}g}",
                f"{p['p84']:.{digits}g}",
                f"{p['p2.5']:.{digits}g}",
                f"{p['p97.5']:.{digits}g}",
                f"{d['tau'][k]:.1f}",
                f"{d['ess'][k]:.0f}",
            )
        )
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = ["  ".join(f"{c:<{w}}" for c, w in zip(r, widths)) for r in rows]
    lines.insert(1, "-" * (sum(widths) + 2 * (len(widths) - 1)))
    verdict = "trustworthy" if d["trustworthy"] else "NOT trustworthy"
    lines.append("")
    lines.append(
        f"chain: {d['steps']} steps x {d['walkers']} walkers, {d['tau_multiple']:.0f} autocorrelation times "
        f"(needed {d['min_tau_multiple']:.0f}), burn-in {d['burn_in']}, acceptance {d['acceptance_mean']:.2f}; "
        f"sigma {payload['sigma']:.3g}; {verdict}"
    )
    lines += [f"not trustworthy: {r}" for r in d["reasons"]]
    likelihood = payload.get("likelihood") or {}
    if likelihood.get("method"):  # a capture's chain
        lines.append(f"likelihood: {likelihood['method']}")
    adjustment = payload.get("adjustment") or {}
    if adjustment.get("method") == "affine":
        target = "image-cluster sandwich" if payload.get("kind") == "capture" else "noise sandwich"
        lines.append(
            f"adjusted (affine) to the fit's {target}: the percentiles above are of the mapped draws "
            f"(theta' = theta_hat + A (theta - theta_hat)); {adjustment.get('dropped', 0)} of "
            f"{adjustment.get('dropped', 0) + adjustment.get('kept', 0)} fell outside the prior and were dropped"
        )
    elif adjustment.get("method") == "temperature":
        factor = adjustment.get("temperature", float("nan"))
        lines.append(
            "tempered: T = 1, the chain as sampled is already at least as wide as the fit's noise sandwich in every "
            "direction (tempering only widens)"
            if factor == 1
            else f"tempered: sampled with sigma x sqrt(T), T = {factor:.3g}, so that every interval is at least as "
            "wide as the fit's noise sandwich"
        )
    if adjustment.get("reason"):
        lines.append(f"adjustment: {adjustment['method']} ({adjustment['reason']})")
    verdict = payload.get("fit_verdict")
    if verdict:
        lines.append(f"fit verdict: {verdict}")
    lines += [f"fit warning [{w.get('code', '?')}]: {w.get('message', '')}" for w in payload.get("fit_warnings", [])]
    lines += [f"note: {n}" for n in payload["comparison"]["notes"]]
    lines += [f"warning: {w}" for w in payload["warnings"]]
    return "\n".join(lines)
