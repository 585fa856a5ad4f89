"""``strauss-fit sample``: sample the posterior of a fit with emcee (resumable HDF5 chain)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from strauss_fit.model import DEFAULT_TABLE_SIZE, MODES

from .common import QUALITY_PRESETS, add_quality_option, check_evaluator_options, positive_int, quality_setting

#: Options that only apply when ``sample`` fits first, with their defaults.
_FIT_ONLY = {"free": None, "fix": [], "fit_lights": False, "solver": "lm", "starts": None, "mode": "exact",
             "table_size": DEFAULT_TABLE_SIZE}
#: Options fixed by an existing chain, which --resume refuses to change.
_CHAIN_FIXED = ("fit", "sigma", "walkers", "prior", "seed")


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "sample",
        help="sample the posterior of the parameters with emcee",
        description="Sample the posterior of the Strauss parameters of SCENE given the image TARGET with emcee's "
        "ensemble sampler, started around the least-squares optimum (from --fit, or fitted first). Gaussian noise "
        "of standard deviation sigma (--sigma, or estimated from the fit's residual), uniform priors over the "
        "parameters' ranges. Runs until the chain is --min-tau-multiple autocorrelation times long (or "
        "--max-steps). Writes CHAIN.h5 (emcee's HDF5 format) and a summary CHAIN.json beside it. Ctrl-C keeps "
        "every step sampled; continue with --resume.",
    )
    parser.add_argument("target", metavar="TARGET", help="reference image (.exr/.hdr/.tif linear; .png/.jpg sRGB)")
    parser.add_argument("--scene", required=True, metavar="SCENE.toml", help="the scene the target was taken in")
    parser.add_argument("-o", "--output", required=True, metavar="CHAIN.h5", help="chain file (HDF5)")
    parser.add_argument("--fit", metavar="RESULT.json", help="start from this fit result (strauss-fit fit) instead of fitting first")
    parser.add_argument("--mask", metavar="MASK", help="mask image: pixels where it is non-zero are used")
    parser.add_argument("--encoding", choices=("auto", "linear", "srgb"), default="auto",
                        help="how TARGET's values are encoded (default: sRGB for .png/.jpg, linear otherwise)")
    parser.add_argument("--sigma", type=float, metavar="S",
                        help="noise standard deviation per RGB value, linear units (default: estimated from the "
                        "fit's residual, sqrt(RSS/(N-P)))")
    parser.add_argument("--prior", action="append", default=[], metavar="NAME=LOW,HIGH",
                        help="narrow the uniform prior of a parameter (repeatable; color or color_r, ... ; inside "
                        "the parameter's range)")
    parser.add_argument("--walkers", type=positive_int, metavar="N", help="number of walkers, even, >= 2 x parameters "
                        "(default: max(32, 4 x parameters))")
    parser.add_argument("--max-steps", type=positive_int, metavar="N",
                        help="cap on the chain's total length in steps, earlier runs included (default: from "
                        "--quality, 10000)")
    parser.add_argument("--min-tau-multiple", type=float, metavar="K",
                        help="stop when the chain is K autocorrelation times long (default: from --quality: 10, 50 or 100)")
    parser.add_argument("--check-every", type=positive_int, default=100, metavar="N",
                        help="steps between convergence checks and progress lines (default 100)")
    parser.add_argument("--seed", type=int, default=0, metavar="N", help="random seed of the walkers (default 0)")
    parser.add_argument("--resume", action="store_true", help="continue the chain in CHAIN.h5 up to --max-steps")
    parser.add_argument("--force", action="store_true", help="replace an existing CHAIN.h5 and CHAIN.json")
    parser.add_argument("--quiet", action="store_true", help="no progress output")
    fitting = parser.add_argument_group("fitting first (without --fit)")
    fitting.add_argument("--free", metavar="NAMES", help="comma-separated parameters to fit (as for 'fit')")
    fitting.add_argument("--fix", action="append", default=[], metavar="NAME=VALUE", help="hold a parameter (as for 'fit')")
    fitting.add_argument("--fit-lights", action="store_true", help="also consider the light intensities (as for 'fit')")
    fitting.add_argument("--solver", choices=("lm", "gauss-newton", "bfgs"), default="lm", help="as for 'fit'")
    fitting.add_argument("--starts", type=positive_int, metavar="N", help="as for 'fit'")
    fitting.add_argument("--mode", choices=MODES, default="exact",
                         help="evaluator, as for 'fit' (default exact); a fit result (--fit) brings its own")
    fitting.add_argument("--table-size", type=int, default=DEFAULT_TABLE_SIZE, metavar="N",
                         help=f"table entries for the table modes (default {DEFAULT_TABLE_SIZE})")
    add_quality_option(parser)
    parser.set_defaults(run=run)


def parse_priors(items: list[str]) -> dict[str, tuple[float, float]]:
    from strauss_fit.errors import StraussFitError

    priors = {}
    for item in items:
        name, sep, text = item.partition("=")
        parts = text.split(",")
        if not sep or not name or len(parts) != 2:
            raise StraussFitError(f"--prior expects NAME=LOW,HIGH, got {item!r}")
        try:
            priors[name] = (float(parts[0]), float(parts[1]))
        except ValueError:
            raise StraussFitError(f"--prior {name}: {text!r} is not LOW,HIGH numbers") from None
    return priors


class ProgressBar:
    """Progress on stderr: a bar redrawn in place on a terminal, else a line at most
    every few seconds."""

    def __init__(self, quiet: bool, stream=None):
        self.quiet = quiet
        self.stream = stream or sys.stderr
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.last = 0.0
        self.drawn = False

    def __call__(self, p) -> None:
        if self.quiet:
            return
        goal = min(p.max_steps, max(p.needed_steps, p.steps))
        fraction = min(p.steps / max(goal, 1), 1.0)
        bar = "#" * int(30 * fraction) + "." * (30 - int(30 * fraction))
        text = (f"sample [{bar}] {p.steps}/{goal} steps | tau {p.tau_max:.1f} (x{p.steps / p.tau_max:.0f}) | "
                f"acceptance {p.acceptance:.2f} | {p.steps_per_s:.0f} steps/s")
        if self.tty:
            self.stream.write("\r" + text)
            self.stream.flush()
            self.drawn = True
        elif time.monotonic() - self.last > 3.0 or p.steps >= goal:
            print(text, file=self.stream)
            self.last = time.monotonic()

    def close(self) -> None:
        if self.drawn:
            self.stream.write("\n")
            self.stream.flush()
            self.drawn = False


def _check_options(args: argparse.Namespace) -> None:
    from strauss_fit.errors import StraussFitError
    from strauss_fit.posterior import check_sigma

    check_evaluator_options(args)
    if args.sigma is not None:
        check_sigma(args.sigma)
    args.min_tau_multiple = quality_setting(args, "min_tau_multiple")
    args.max_steps = quality_setting(args, "sample_max_steps", "max_steps")
    if args.min_tau_multiple <= 0:
        raise StraussFitError(f"--min-tau-multiple must be > 0, got {args.min_tau_multiple:g}")
    if args.resume and args.force:
        raise StraussFitError("--resume continues CHAIN.h5 and --force replaces it: give one of them")
    if args.walkers is not None and args.walkers % 2:
        raise StraussFitError(f"--walkers must be even (emcee updates the ensemble in two halves), got {args.walkers}")
    if args.fit or args.resume:
        given = [k for k, default in _FIT_ONLY.items() if getattr(args, k) != default]
        if given:
            where = "--resume (the chain's fit is used)" if args.resume else "--fit"
            raise StraussFitError(f"--{given[0].replace('_', '-')} applies only when sample fits first; not with {where}")
    if args.resume:
        changed = [k for k in _CHAIN_FIXED if getattr(args, k) not in (None, [], 0)]
        if changed:
            raise StraussFitError(f"--{changed[0]} cannot change when resuming: the chain keeps the value it was "
                                  "started with (start a new chain with --force)")


def run(args: argparse.Namespace) -> int:
    _check_options(args)
    import numpy as np

    from strauss_fit import load_scene
    from strauss_fit.errors import StraussFitError
    from strauss_fit.io import check_writable, read_json, write_json
    from strauss_fit.posterior import (
        LogPosterior,
        Prior,
        default_prior,
        estimate_sigma,
        laplace_covariance,
        problem_from_fit,
        target_digest,
    )
    from strauss_fit.sample import (
        ChainError,
        SampleSettings,
        default_walkers,
        initial_walkers,
        load_chain,
        read_metadata,
        run_sampler,
    )
    from strauss_fit.target import load_target, match_scene

    log = (lambda message: None) if args.quiet else (lambda message: print(f"... {message}", file=sys.stderr))
    out = Path(args.output)
    summary_path = out.with_suffix(".json")
    if summary_path == out:
        raise ChainError(f"the chain file needs an extension other than .json (the summary goes to {summary_path})")
    meta: dict[str, Any] = {}
    if args.resume:
        meta = read_metadata(out)
        check_writable(summary_path, True)
    else:
        check_writable(out, args.force)
        check_writable(summary_path, args.force)
    priors = parse_priors(args.prior)

    scene = load_scene(args.scene)
    target = load_target(args.target, args.mask, args.encoding)
    scene, message = match_scene(scene, target)
    if message:
        log(message)

    if args.resume:
        fit_json = meta["fit"]
        problem, x_hat = problem_from_fit(scene, target, fit_json)
        if target_digest(problem) != meta.get("target_sha256"):
            raise ChainError(f"{out} was sampled for another target (the usable pixels of {args.target} differ)")
        if problem.layout.labels() != meta["labels"]:
            raise ChainError(f"{out} samples {', '.join(meta['labels'])}, not {', '.join(problem.layout.labels())}")
        sigma = float(meta["sigma"])
        prior = Prior(tuple(meta["labels"]), np.array([meta["prior"][k][0] for k in meta["labels"]]),
                      np.array([meta["prior"][k][1] for k in meta["labels"]]))
        start = None
        log_posterior = LogPosterior(problem, prior, sigma)
        log(f"resuming {out} at step {len(load_chain(out).chain)}")
    else:
        if args.fit:
            fit_json = read_json(args.fit, "fit result")
            problem, x_hat = problem_from_fit(scene, target, fit_json)
        else:
            fit_json, problem, x_hat = _fit_first(args, scene, target, log)
        sigma_source = "given (--sigma)" if args.sigma is not None else "estimated from the fit's residual, sqrt(RSS/(N-P))"
        sigma = args.sigma if args.sigma is not None else estimate_sigma(problem, x_hat)
        prior = default_prior(problem.layout, x_hat, priors)
        ndim = problem.layout.size
        walkers = quality_setting(args, "walkers") or default_walkers(ndim)
        if walkers < 2 * ndim:
            raise ChainError(f"--walkers must be at least twice the number of parameters ({2 * ndim}), got {walkers}")
        log_posterior = LogPosterior(problem, prior, sigma)
        covariance = laplace_covariance(problem, x_hat, sigma)
        log("compiling the log-probability and placing the walkers")
        start = initial_walkers(x_hat, covariance, prior, walkers, np.random.default_rng(args.seed), log_posterior)
        meta = {
            "fit": fit_json, "target": str(args.target), "scene": str(args.scene),
            "mask": None if args.mask is None else str(args.mask), "encoding": args.encoding,
            "target_sha256": target_digest(problem), "sigma": sigma, "sigma_source": sigma_source,
            "prior": prior.as_dict(), "x_hat": [float(v) for v in x_hat], "seed": args.seed,
            "laplace_covariance": covariance.tolist(), "pixels_used": int(problem.target.shape[0]),
            "quality": args.quality,
        }
        if out.exists():
            out.unlink()  # --force, checked above; only now that every input is valid
    settings = SampleSettings(max_steps=args.max_steps, min_tau_multiple=args.min_tau_multiple,
                              check_every=args.check_every, seed=args.seed)
    bar = ProgressBar(args.quiet)
    try:
        result = run_sampler(log_posterior, out, start=start, settings=settings, metadata=meta,
                             resume=args.resume, progress=bar)
    except KeyboardInterrupt:
        bar.close()
        try:
            steps = len(load_chain(out).chain)
        except StraussFitError:  # interrupted before the first step was stored
            steps = 0
        print(f"strauss-fit: sample: interrupted; {out} keeps all {steps} steps sampled so far "
              "(continue with --resume)", file=sys.stderr)
        raise
    finally:
        bar.close()
    payload = summarise(load_chain(out))
    payload["run"] = {"stopped": result.stopped, "new_steps": result.new_steps, "wall_s": result.wall_s,
                      "sampling_s": result.sampling_s, "steps_per_s": result.steps_per_s}
    write_json(summary_path, payload, force=True)
    print(format_summary(payload))
    print(f"wrote {out}, {summary_path}")
    return 0 if payload["diagnostics"]["trustworthy"] else 1


def _fit_first(args, scene, target, log):
    from strauss_fit.fit import FitOptions, fit

    from .fit_cmd import _check_fixed_ranges, parse_fixed

    fixed = parse_fixed(args.fix)
    _check_fixed_ranges(fixed)
    options = FitOptions(
        solver=args.solver, starts=quality_setting(args, "starts"), max_steps=QUALITY_PRESETS[args.quality]["max_steps"],
        rtol=quality_setting(args, "rtol"), atol=quality_setting(args, "atol"), mode=args.mode, table_size=args.table_size,
        free=tuple(n.strip() for n in args.free.split(",") if n.strip()) if args.free else None,
        fixed=fixed, fit_lights=args.fit_lights,
    )
    result = fit(scene, target, options, progress=log)
    if result.solver["status"] != "successful":
        log(f"the fit ended with status '{result.solver['status']}'; sampling from where it stopped")
    payload = result.to_json()
    payload["target"] = str(args.target)
    payload["scene"] = str(args.scene)
    return payload, result.problem, result.x


def summarise(chain) -> dict[str, Any]:
    """The summary JSON of a chain: diagnostics, posterior percentiles, the Laplace
    estimate, their comparison and the warnings."""
    import numpy as np

    from strauss_fit.uncertainty import Laplace, compare, degeneracy_warnings, posterior_summary

    meta = chain.meta
    diagnostics = chain.diagnostics()
    samples = chain.samples(diagnostics.burn_in)
    summary = posterior_summary(samples, chain.labels)
    laplace = Laplace.from_fit(meta["fit"])
    lower = np.array([meta["prior"][k][0] for k in chain.labels])
    upper = np.array([meta["prior"][k][1] for k in chain.labels])
    rows, notes = compare(laplace, summary, samples, lower, upper)
    covariance = np.atleast_2d(np.cov(samples, rowvar=False))
    warnings = degeneracy_warnings(chain.labels, covariance, meta["fit"].get("held"), values=laplace.x_hat)
    return {
        "chain": chain.path, "target": meta.get("target"), "scene": meta.get("scene"), "labels": chain.labels,
        "sigma": meta["sigma"], "sigma_source": meta.get("sigma_source"), "prior": meta["prior"],
        "walkers": diagnostics.walkers, "steps": diagnostics.steps, "diagnostics": diagnostics.as_dict(),
        "posterior": summary,
        "laplace": {"labels": laplace.labels, "x_hat": laplace.x_hat.tolist(), "sd": laplace.sd.tolist(),
                    "correlation": laplace.correlation.tolist()},
        "comparison": {"rows": [r.as_dict() for r in rows], "notes": notes},
        "warnings": warnings,
    }


def format_summary(payload: dict[str, Any]) -> str:
    d = payload["diagnostics"]
    rows = [("parameter", "fit", "Laplace ±", "median", "16 %", "84 %", "2.5 %", "97.5 %", "tau", "ESS")]
    lap = payload["laplace"]
    for k, label in enumerate(payload["labels"]):
        p = payload["posterior"]["parameters"][label]
        rows.append((label, f"{lap['x_hat'][k]:.4g}", f"{lap['sd'][k]:.2g}", f"{p['median']:.4g}", f"{p['p16']:.4g}",
                     f"{p['p84']:.4g}", f"{p['p2.5']:.4g}", f"{p['p97.5']:.4g}", f"{d['tau'][k]:.1f}",
                     f"{d['ess'][k]:.0f}"))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = ["  ".join(f"{c:<{w}}" for c, w in zip(r, widths)) for r in rows]
    lines.insert(1, "-" * (sum(widths) + 2 * (len(widths) - 1)))
    verdict = "trustworthy" if d["trustworthy"] else "NOT trustworthy"
    lines.append("")
    lines.append(f"chain: {d['steps']} steps x {d['walkers']} walkers, {d['tau_multiple']:.0f} autocorrelation times "
                 f"(needed {d['min_tau_multiple']:.0f}), burn-in {d['burn_in']}, acceptance {d['acceptance_mean']:.2f}; "
                 f"sigma {payload['sigma']:.3g}; {verdict}")
    lines += [f"not trustworthy: {r}" for r in d["reasons"]]
    lines += [f"note: {n}" for n in payload["comparison"]["notes"]]
    lines += [f"warning: {w}" for w in payload["warnings"]]
    return "\n".join(lines)
