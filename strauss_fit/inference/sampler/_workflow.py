"""The whole sampling workflow, from a target and a scene to a chain file and its summary
(`sample`; `run_and_summarise` is its end, shared with a capture's
`strauss_fit.inference.capture_posterior.sample_capture`), with the checks it makes
first: a least-squares fit only (`check_least_squares`; "Least squares only" in
`strauss_fit.inference.sampler`), the noise level, and the adjustment to the fit's
noise sandwich ("Adjustment" there).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ...errors import StraussFitError
from ...fitting.api import fit as run_fit
from ...fitting.options import DEFAULT_QUALITY, FitOptions
from ...fitting.result import FitResult
from ...io.files import Outputs, check_writable, read_json
from ...io.targets import load_target, match_scene
from ...precision import uses_float64
from ...scene.loading import load_scene
from ...stats import laplace
from ..adjustment import METHODS as ADJUST_METHODS
from ..adjustment import AdjustmentError, adjusted_entries, default_method, full_matrix, loss_of, temperature
from ..posterior import (
    LogPosterior,
    Prior,
    default_prior,
    estimate_sigma,
    parse_priors,
    problem_from_fit,
    target_digest,
)
from ..summaries import Laplace, summarise_chain
from ._chain import Chain, load_chain, write_metadata
from ._diagnostics import autocorrelation_times, burn_in
from ._format import ChainError
from ._run import Progress, SampleRun, SampleSettings, run_sampler
from ._walkers import default_walkers, initial_walkers

if TYPE_CHECKING:
    from ...fitting.problem import Problem
    from ...io.targets import Target
    from ...scene.loading import Scene


def _adjustment_target(adjust: str, fit_json: dict[str, Any], labels: list[str]) -> tuple[str, str, np.ndarray]:
    """The adjustment to make (``adjust``, or the default for ``auto``), why, and the fit's
    covariance V in the chain's label order (the noise sandwich when the fit used it)."""
    default, why = default_method(fit_json)
    if adjust == "auto":
        method, reason = default, why
    elif adjust == "none":
        method, reason = "none", "--adjust none"
    else:
        if (fit_json.get("uncertainty_method") or {}).get("name") != "noise sandwich":
            raise ChainError(
                f"--adjust {adjust} maps the chain to the fit's noise sandwich, but this fit's uncertainty is the "
                "Laplace approximation (the target's noise was unknown to it): give the fit the noise level "
                "(a sidecar, or fit's noise option), or use --adjust none"
            )
        method, reason = adjust, f"--adjust {adjust}: {why}"
    fitted = Laplace.from_fit(fit_json)
    if fitted.labels != list(labels):
        raise ChainError(
            f"the fit result's uncertainties are for {', '.join(fitted.labels)}, not {', '.join(labels)}: "
            "it does not belong to this problem"
        )
    target = fitted.covariance
    if method != "none" and not (np.all(np.isfinite(target)) and np.any(np.diag(target) > 0)):
        raise ChainError("the fit's noise sandwich has no finite, positive variance to adjust the chain to")
    return method, reason, target


def check_least_squares(
    fit_json: dict[str, Any], what: str = "the fit", remedy: str = "refit with --loss linear"
) -> None:
    """Refuse a fit whose loss is not least squares (``solver.loss``; results written
    before losses existed are least squares): the chain's likelihood is, so such a fit's
    optimum is not the chain's and its noise sandwich is another estimator's spread (see
    `strauss_fit.inference.sampler`)."""
    loss = loss_of(fit_json)
    if loss != "linear":
        raise ChainError(
            f"{what} minimised the {loss} loss, but sample's likelihood is least squares: the chain would centre "
            f"on the least-squares optimum, not on the fit's values, and the fit's ± is the spread of the {loss} "
            f"fit, not of the chain; {remedy} (or let sample fit first)"
        )


def _noise_level(sigma: float | None, fit_json: dict[str, Any], problem: Any, x_hat: np.ndarray) -> tuple[float, str]:
    """σ of the likelihood and where it comes from: given; the fit's noise level when it
    knew the target's noise; else estimated from the fit's residual."""
    if sigma is not None:
        return sigma, "given (--sigma)"
    residual = fit_json.get("residual") or {}
    noise = residual.get("noise")
    if (fit_json.get("uncertainty_method") or {}).get("name") == "noise sandwich" and isinstance(noise, list):
        level = np.asarray(noise, dtype=np.float64)
        if level.size and np.all(np.isfinite(level)) and np.all(level > 0):
            return float(np.sqrt(np.mean(level**2))), (
                f"the target's noise as the fit estimated it (source: {residual.get('noise_source', 'unknown')}), "
                "root mean square over the channels"
            )
    return estimate_sigma(problem, x_hat), "estimated from the fit's residual, sqrt(RSS/(N-P))"


def _store_adjustment(chain: Chain) -> None:
    """Compute the affine adjustment's matrix A from the chain's draws after burn-in and
    store it (with the steps and burn-in it was computed from, and the draws it drops) in
    the chain file's metadata; the raw chain is not touched."""
    discard = burn_in(autocorrelation_times(chain.chain), chain.chain.shape[0])
    raw = chain.chain[discard:].reshape(-1, chain.chain.shape[-1])
    info = dict(chain.adjustment)
    try:
        matrix = full_matrix(raw, np.asarray(info["target_covariance"], dtype=np.float64))
    except AdjustmentError as exc:
        raise ChainError(f"cannot adjust the chain {chain.path}: {exc} (too few distinct draws?)") from None
    info.update(matrix=matrix.tolist(), steps=int(chain.chain.shape[0]), burn_in=int(discard))
    chain.meta = dict(chain.meta, adjustment=info)
    chain._adjusted.clear()
    _, dropped = chain.adjusted(discard)
    info["dropped"] = int(dropped)
    write_metadata(chain.path, chain.meta)


@dataclass
class SampleResult:
    """What `sample` did: the chain file, the summary written beside it (the
    document of `strauss_fit.inference.summaries.summarise_chain` with this run's
    timings under ``run``) and the run itself."""

    path: Path
    summary_path: Path
    summary: dict[str, Any]
    run: SampleRun

    @property
    def trustworthy(self) -> bool:
        """Whether the chain passed every diagnostic (`diagnose`)."""
        return bool(self.summary["diagnostics"]["trustworthy"])


class SamplingInterrupted(KeyboardInterrupt):
    """Ctrl-C while `sample` was sampling: ``path`` keeps the ``steps`` stored so far."""

    def __init__(self, path: Path, steps: int):
        super().__init__(f"{path} keeps all {steps} steps sampled so far")
        self.path = path
        self.steps = steps


def stored_steps(path: str | Path) -> int:
    """How many steps the chain file ``path`` holds (0 if it holds none or cannot be read)."""
    try:
        return len(load_chain(path, required=False).chain)
    except StraussFitError:
        return 0


def _summary_path(out: Path) -> Path:
    """Where the summary of the chain file ``out`` goes: beside it, with the suffix ``.json``."""
    summary_path = out.with_suffix(".json")
    if summary_path == out:
        raise ChainError(f"the chain file needs an extension other than .json (the summary goes to {summary_path})")
    return summary_path


def _check_outputs(out: Path, summary_path: Path, resume: bool, force: bool) -> Chain | None:
    """Check before any work that the files can be written: when resuming, the chain to
    continue (returned; a damaged chain, or one of a fit with another loss, is refused),
    else that ``out`` and its summary are new or ``force`` replaces them (None)."""
    if not resume:
        check_writable(out, force)
        check_writable(summary_path, force)
        return None
    existing = load_chain(out, required=True)
    check_least_squares(
        existing.meta["fit"],
        f"the fit {out} was started from",
        "start a new chain (--force) from a fit made with --loss linear",
    )
    check_writable(summary_path, True)
    return existing


def _load_inputs(
    target: str | Path, scene: str | Path, mask: str | Path | None, encoding: str, log: Callable[[str], None]
) -> tuple[Scene, Target]:
    """The scene and the target, the scene matched to the target (its size, its camera)."""
    loaded_scene = load_scene(scene)
    loaded_target = load_target(target, mask, encoding)
    loaded_scene, message = match_scene(loaded_scene, loaded_target)
    if message:
        log(message)
    return loaded_scene, loaded_target


def _resumed_posterior(
    existing: Chain, out: Path, loaded_scene: Scene, loaded_target: Target, target: str | Path, adjust: str
) -> LogPosterior:
    """The log-posterior of the chain ``existing`` continues (its fit, σ and prior), once
    the target and the adjustment are checked to be the ones it was started with."""
    meta = existing.meta
    problem, _ = problem_from_fit(loaded_scene, loaded_target, meta["fit"])
    if target_digest(problem) != meta.get("target_sha256"):
        raise ChainError(f"{out} was sampled for another target (the usable pixels of {target} differ)")
    if problem.layout.labels() != meta["labels"]:
        raise ChainError(f"{out} samples {', '.join(meta['labels'])}, not {', '.join(problem.layout.labels())}")
    sigma = float(meta["sigma"])
    kept = (meta.get("adjustment") or {}).get("method", "none")
    if adjust != "auto" and adjust != kept:
        raise ChainError(f"--adjust cannot change when resuming: {out} was started with --adjust {kept}")
    prior = Prior(
        tuple(meta["labels"]),
        np.array([meta["prior"][k][0] for k in meta["labels"]]),
        np.array([meta["prior"][k][1] for k in meta["labels"]]),
    )
    return LogPosterior(problem, prior, sigma)


def _fit_first(
    loaded_scene: Scene,
    loaded_target: Target,
    fit_options: FitOptions | None,
    quality: str,
    log: Callable[[str], None],
) -> FitResult:
    """The least-squares fit a new chain starts from when none is given (``fit_options``,
    default the ``quality`` preset; its loss ``"auto"`` made least squares)."""
    options = fit_options or FitOptions.preset(quality)
    if options.loss == "auto":  # the likelihood sampled is least squares: so is the fit it starts from
        options = dataclasses.replace(options, loss="linear")
    if options.loss != "linear":
        raise ChainError(
            f"sample fits first by least squares, the likelihood it samples; a fit with the {options.loss} "
            "loss is refused"
        )
    result = run_fit(loaded_scene, loaded_target, options, progress=log)
    if result.solver["status"] != "successful":
        log(f"the fit ended with status '{result.solver['status']}'; sampling from where it stopped")
    return result


def _starting_fit(
    fit: str | Path | FitResult | dict[str, Any],
    loaded_scene: Scene,
    loaded_target: Target,
    target: str | Path,
    scene: str | Path,
) -> tuple[dict[str, Any], Problem, np.ndarray]:
    """The fit a new chain starts from, as JSON (refused unless least squares), its problem
    and its optimum θ̂: taken from a `FitResult` that holds its problem, else rebuilt
    from the result's JSON (given, or read from a path)."""
    if isinstance(fit, FitResult) and fit.problem is not None:
        fit_json = fit.to_json()
        fit_json["target"] = str(target)
        fit_json["scene"] = str(scene)
        check_least_squares(fit_json)
        return fit_json, fit.problem.unpadded(), fit.x  # one target: no padding
    fit_json = read_json(fit, "fit result") if isinstance(fit, (str, Path)) else fit
    if isinstance(fit_json, FitResult):
        fit_json = fit_json.to_json()
    check_least_squares(fit_json)
    problem, x_hat = problem_from_fit(loaded_scene, loaded_target, fit_json)
    return fit_json, problem, x_hat


def _temperature(
    problem: Problem, x_hat: np.ndarray, sigma: float, target_covariance: np.ndarray, log: Callable[[str], None]
) -> float:
    """The temperature T ≥ 1 that widens the likelihood (σ√T) to the fit's noise sandwich."""
    # the chain's covariance over the entries V covers, the others held as V holds
    # them (the block of the full Laplace covariance lets them move: wider, so T too small)
    use = adjusted_entries(target_covariance) & ~np.asarray(problem.pinned)
    post = laplace.posterior_covariance(problem, x_hat, sigma, use)
    try:
        factor = temperature(post[np.ix_(use, use)], target_covariance[np.ix_(use, use)])
    except AdjustmentError as exc:
        raise ChainError(f"cannot temper the likelihood: {exc}") from None
    log(f"tempering the likelihood: sigma x sqrt(T) = {sigma:.3g} x {np.sqrt(factor):.3g} (T = {factor:.3g})")
    return factor


def _new_chain(
    fit_json: dict[str, Any],
    problem: Problem,
    x_hat: np.ndarray,
    *,
    sigma: float | None,
    priors: dict[str, tuple[float, float]] | None,
    settings: SampleSettings,
    adjust: str,
    log: Callable[[str], None],
) -> tuple[LogPosterior, np.ndarray, dict[str, Any], dict[str, Any]]:
    """A new chain's log-posterior, its walkers' starting points, and two parts of its
    metadata: what describes the likelihood and the start (σ and where it comes from, the
    prior, θ̂, the seed, the Laplace covariance), and the adjustment."""
    method, reason, target_covariance = _adjustment_target(adjust, fit_json, problem.layout.labels())
    sigma, sigma_source = _noise_level(sigma, fit_json, problem, x_hat)
    prior = default_prior(problem.layout, x_hat, priors)
    ndim = problem.layout.size
    walkers = settings.walkers or default_walkers(ndim)
    if walkers < 2 * ndim:
        raise ChainError(f"--walkers must be at least twice the number of parameters ({2 * ndim}), got {walkers}")
    covariance = laplace.laplace_covariance(problem, x_hat, sigma)
    adjustment: dict[str, Any] = {"method": method, "reason": reason}
    if method != "none":
        adjustment.update(target_covariance=target_covariance.tolist(), center=[float(v) for v in x_hat])
    if method == "temperature":
        factor = _temperature(problem, x_hat, sigma, target_covariance, log)
        adjustment.update(temperature=factor, sigma_untempered=sigma)
        sigma, covariance = sigma * float(np.sqrt(factor)), covariance * factor
        sigma_source += f", tempered by sqrt(T) = {np.sqrt(factor):.3g} (--adjust temperature)"
    log_posterior = LogPosterior(problem, prior, sigma)
    log("compiling the log-probability and placing the walkers")
    start = initial_walkers(x_hat, covariance, prior, walkers, np.random.default_rng(settings.seed), log_posterior)
    meta = {
        "sigma": sigma,
        "sigma_source": sigma_source,
        "prior": prior.as_dict(),
        "x_hat": [float(v) for v in x_hat],
        "seed": settings.seed,
        "laplace_covariance": covariance.tolist(),
    }
    return log_posterior, start, meta, adjustment


@uses_float64
def sample(
    target: str | Path,
    scene: str | Path,
    output: str | Path,
    *,
    mask: str | Path | None = None,
    encoding: str = "auto",
    fit: str | Path | FitResult | dict[str, Any] | None = None,
    fit_options: FitOptions | None = None,
    sigma: float | None = None,
    priors: dict[str, tuple[float, float]] | list[str] | None = None,
    settings: SampleSettings = SampleSettings(),
    quality: str = DEFAULT_QUALITY,
    adjust: str = "auto",
    resume: bool = False,
    force: bool = False,
    log: Callable[[str], None] | None = None,
    progress: Callable[[Progress], None] | None = None,
) -> SampleResult:
    """Sample the posterior of the Strauss parameters of ``scene`` given the image
    ``target`` into the chain file ``output``, and write its summary beside it
    (``output`` with the suffix ``.json``).

    ``target``, ``scene`` and ``mask`` are file paths, recorded in the chain so that a
    report or ``resume`` can reload them. The walkers start around the least-squares
    optimum of ``fit`` (a fit result, or the path of one's JSON) or, without it, of a fit
    made first with ``fit_options`` (default: the ``quality`` preset; its loss ``"auto"`` is
    least squares here). The fit must be a least-squares one (its loss ``"linear"``): the
    likelihood sampled is, and another loss's optimum and noise sandwich are not the
    chain's (see `strauss_fit.inference.sampler`); any other is refused. The noise level is
    ``sigma``; else the target's noise as the fit found it (the root mean square of its
    per-channel level) when the fit knew it (its uncertainty is the noise sandwich), else
    estimated from the fit's residual. The prior is the default box of
    `strauss_fit.inference.posterior.default_prior` narrowed by ``priors`` (a dict
    ``{name: (low, high)}`` or ``NAME=LOW,HIGH`` strings). ``settings`` (see
    `SampleSettings.preset`) says how long to sample and with how many walkers.

    ``adjust`` (`strauss_fit.inference.adjustment.METHODS`) makes the chain's width
    match the fit's noise sandwich on a target the model cannot reproduce:
    ``"affine"`` maps the draws on read (`Chain.adjusted`; the raw chain is kept),
    ``"temperature"`` samples with σ√T, ``"none"`` samples the Gaussian likelihood as it is;
    ``"auto"`` is ``"affine"`` when the fit's uncertainty is the noise sandwich and its
    verdict is a mismatch, else ``"none"`` (`strauss_fit.inference.adjustment`).

    ``resume`` continues the chain in ``output`` (its fit, σ, prior, walkers and adjustment are kept);
    otherwise an existing ``output`` is refused unless ``force``. ``log`` receives short
    status lines and ``progress`` a `Progress` after every check. Ctrl-C while
    sampling raises `SamplingInterrupted` (a KeyboardInterrupt) after every step so
    far is written.
    """
    log = log or (lambda message: None)
    out = Path(output)
    summary_path = _summary_path(out)
    existing = _check_outputs(out, summary_path, resume, force)
    if priors is not None and not isinstance(priors, dict):
        priors = parse_priors(list(priors))
    if adjust not in ADJUST_METHODS:
        raise ChainError(f"unknown adjustment {adjust!r}; expected one of {', '.join(ADJUST_METHODS)}")
    loaded_scene, loaded_target = _load_inputs(target, scene, mask, encoding, log)
    if existing is not None:
        log_posterior = _resumed_posterior(existing, out, loaded_scene, loaded_target, target, adjust)
        start, meta = None, existing.meta
        log(f"resuming {out} at step {len(existing.chain)}")
    else:
        if fit is None:
            fit = _fit_first(loaded_scene, loaded_target, fit_options, quality, log)
        fit_json, problem, x_hat = _starting_fit(fit, loaded_scene, loaded_target, target, scene)
        log_posterior, start, likelihood, adjustment = _new_chain(
            fit_json, problem, x_hat, sigma=sigma, priors=priors, settings=settings, adjust=adjust, log=log
        )
        meta = {  # this order is the order of the stored JSON
            "fit": fit_json,
            "target": str(target),
            "scene": str(scene),
            "mask": None if mask is None else str(mask),
            "encoding": encoding,
            "target_sha256": target_digest(problem),
            **likelihood,
            "pixels_used": int(problem.target.shape[0]),
            "quality": quality,
            "adjustment": adjustment,
        }
    return run_and_summarise(
        log_posterior, out, summary_path, summarise_chain, start=start, settings=settings, metadata=meta, resume=resume,
        progress=progress,
    )  # fmt: skip


def run_and_summarise(
    log_posterior: Any,
    out: Path,
    summary_path: Path,
    summarise: Callable[[Chain], dict[str, Any]],
    *,
    start: np.ndarray,
    settings: SampleSettings,
    metadata: dict[str, Any],
    resume: bool,
    progress: Callable[[Progress], None] | None,
) -> SampleResult:
    """Run the sampler into the chain file ``out`` (`run_sampler`), store an affine
    adjustment, and write ``summarise(chain)`` with the run's figures to ``summary_path``:
    the end of ``sample`` for single images and for captures. Ctrl-C raises
    `SamplingInterrupted` after every step so far is written."""
    try:
        run = run_sampler(
            log_posterior,
            out,
            start=start,
            settings=settings,
            metadata=metadata,
            resume=resume,
            progress=progress,
            # --force: the old summary goes when the new chain replaces the old one
            replaces=() if resume else (summary_path,),
        )
    except KeyboardInterrupt:
        raise SamplingInterrupted(out, stored_steps(out)) from None
    chain = load_chain(out, required=True)
    if chain.adjustment.get("method") == "affine":
        _store_adjustment(chain)
    summary = summarise(chain)
    summary["run"] = {
        "stopped": run.stopped,
        "new_steps": run.new_steps,
        "wall_s": run.wall_s,
        "sampling_s": run.sampling_s,
        "steps_per_s": run.steps_per_s,
    }
    with Outputs(force=True) as written:
        written.add_json(summary_path, summary)
        written.commit(final=True)
    return SampleResult(out, summary_path, summary, run)
