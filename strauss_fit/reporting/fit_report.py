"""The uncertainty report: one self-contained HTML page (images embedded as base64 PNG, no
scripts, no network) and the same content as Markdown with the PNGs in a folder beside it.

Contents: the fit's verdict and warnings first (its warning codes and messages, the
degeneracies, an untrustworthy chain, the fit's notes); the target, fit and residual
images; the parameter table (least-squares value, the statistical ± — the noise sandwich,
valid for the best Strauss approximation, or the Laplace estimate, conditional on the
model, as the fit computed it — the perceptual equivalence band beside it when the fit
computed one, posterior median and 16/84 and 2.5/97.5 percentiles, prior), one sentence on
what each kind of interval means and a figure of both per parameter; parameters held and
why; the fit's ± against the posterior (`strauss_fit.inference.summaries.compare`);
the correlation matrix; a corner plot; trace plots and sampler diagnostics. Without a chain
the intervals are the fit's Gaussian ones and say so.

The page is built with `strauss_fit.reporting.document.Document` and the plots with
`strauss_fit.reporting.figures` (matplotlib's object API and the Agg canvas: building a
report never touches pyplot's global state or needs a display). `report_from_files`
is the whole workflow of ``strauss-fit report``: it finds and loads the inputs a fit result
or chain recorded, builds the report and writes it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..color import srgb_encode
from ..errors import StraussFitError
from ..fitting.losses import ROBUST_LOSSES
from ..fitting.result import FitResult
from ..inference.sampler import Chain, Diagnostics, load_chain
from ..inference.summaries import ChainPosterior, Laplace, chain_posterior, degeneracy_warnings, loss_warning
from ..io.files import Outputs, check_distinct, check_outside, check_writable, read_json
from ..io.targets import Target, load_target, match_scene
from ..models.material import FRACTION_NAMES
from ..models.strauss import DEFAULT_TABLE_SIZE
from ..precision import uses_float64
from ..scene.loading import Scene, load_scene
from ..stats import laplace as _laplace
from .document import (
    Document,
    check_html_name,
    correlation_table,
    fmt,
    generated_by,
    held_parameters,
    posterior_cells,
    posterior_header,
    prior_text,
    range_text,
    untrustworthy_chain,
    verdict_and_warnings,
)
from .figures import new_figure, png_bytes

#: At most this many samples go into the corner plot and the comparison statistics.
MAX_PLOT_SAMPLES = 20000
#: At most this many walkers are drawn in the trace plots.
MAX_TRACE_WALKERS = 48


class ReportError(StraussFitError):
    """A report cannot be built from the inputs given."""


@dataclass
class Report:
    """A built report: the HTML page, the Markdown text (image links relative to
    ``assets``), the PNGs by file name, and the numbers behind them."""

    html: str
    markdown: str
    images: dict[str, bytes]
    assets: str
    data: dict[str, Any] = field(default_factory=dict)


# --- images -------------------------------------------------------------------------------


def _display(image: np.ndarray, exposure: float) -> np.ndarray:
    """Linear radiance to displayable sRGB in [0, 1] (exposure, clip, encode)."""
    return srgb_encode(np.asarray(image) * exposure)


def images_figure(target: np.ndarray, fitted: np.ndarray, used: np.ndarray, sigma: float | None) -> bytes:
    """Target | fit | residual (fit − target, mean over RGB, at the pixels used)."""
    values = target[used]
    exposure = 1.0 / max(float(np.percentile(values, 99)) if values.size else 1.0, 1e-12)
    residual = np.where(used, (fitted - target).mean(axis=-1), np.nan)
    finite = np.abs(residual[used]) if used.any() else np.zeros(1)
    limit = max(float(np.percentile(finite, 99.5)), 1e-12)
    fig = new_figure(figsize=(11, 3.8))
    axes = fig.subplots(1, 3)
    axes[0].imshow(_display(target, exposure), interpolation="nearest")
    axes[0].set_title("target")
    axes[1].imshow(_display(fitted, exposure), interpolation="nearest")
    axes[1].set_title("fit")
    import matplotlib

    cmap = matplotlib.colormaps["RdBu_r"].with_extremes(bad="0.85")
    shown = axes[2].imshow(residual, cmap=cmap, vmin=-limit, vmax=limit, interpolation="nearest")
    rms = float(np.sqrt(np.nanmean((fitted - target)[used] ** 2))) if used.any() else 0.0
    axes[2].set_title(f"fit − target (RMS {rms:.2g}" + (f", σ {sigma:.2g})" if sigma else ")"))
    fig.colorbar(shown, ax=axes[2], fraction=0.046, pad=0.04)
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    return png_bytes(fig)


def correlation_figure(labels: Sequence[str], corr: np.ndarray, title: str) -> bytes:
    k = len(labels)
    fig = new_figure(figsize=(1.0 + 0.75 * k, 0.6 + 0.7 * k))
    ax = fig.subplots()
    shown = ax.imshow(corr, cmap="RdBu_r", vmin=-1, vmax=1)
    ax.set_xticks(range(k), labels, rotation=45, ha="right")
    ax.set_yticks(range(k), labels)
    if k <= 12:
        for i in range(k):
            for j in range(k):
                ax.text(
                    j,
                    i,
                    f"{corr[i, j]:+.2f}",
                    ha="center",
                    va="center",
                    fontsize=8,
                    color="white" if abs(corr[i, j]) > 0.6 else "black",
                )
    ax.set_title(title)
    fig.colorbar(shown, ax=ax, fraction=0.046, pad=0.04)
    return png_bytes(fig)


def corner_figure(samples: np.ndarray, labels: Sequence[str], truths: np.ndarray | None, title: str) -> bytes | None:
    """corner's plot of ``samples``; columns without spread (a pinned entry) are left out."""
    import corner

    spread = np.ptp(samples, axis=0) > 0
    if spread.sum() < 1:
        return None
    samples = samples[:, spread]
    labels = [label for label, keep in zip(labels, spread) if keep]
    k = len(labels)
    fig = new_figure(figsize=(max(2.2 * k, 4), max(2.2 * k, 4)))
    corner.corner(
        samples,
        labels=labels,
        quantiles=[0.16, 0.5, 0.84],
        show_titles=True,
        title_fmt=".3g",
        truths=None if truths is None else np.asarray(truths)[spread],
        truth_color="C1",
        fig=fig,
        plot_datapoints=samples.shape[0] <= 5000,
    )
    fig.suptitle(title, y=1.02)
    return png_bytes(fig)


def intervals_figure(
    labels: Sequence[str],
    x_hat: np.ndarray,
    sd: np.ndarray,
    bands: dict[str, tuple[float, float]],
    lower: np.ndarray,
    upper: np.ndarray,
    statistical: str,
    threshold: float,
) -> bytes:
    """One row per parameter: the perceptual equivalence band (light), the statistical
    ±1.96σ interval (dark) and the fit (dot), over the parameter's range."""
    k = len(labels)
    fig = new_figure(figsize=(8, 0.55 * k + 1.0))
    shared = bool(np.all(lower == lower[0]) and np.all(upper == upper[0]))
    axes = np.atleast_1d(fig.subplots(k, 1, sharex=shared, gridspec_kw={"hspace": 0.15 if shared else 0.9}))
    for row, (ax, label) in enumerate(zip(axes, labels)):
        if label in bands:
            low, high = bands[label]
            ax.barh(0, high - low, left=low, height=0.8, color="C0", alpha=0.25, lw=0)
        ax.barh(0, max(2 * 1.96 * sd[row], 1e-12), left=x_hat[row] - 1.96 * sd[row], height=0.35, color="C3")
        ax.plot([x_hat[row]], [0], "o", color="k", ms=3)
        ax.set_xlim(lower[row], upper[row])
        ax.set_yticks([0], [label])
        ax.set_ylim(-0.6, 0.6)
        ax.tick_params(axis="x", labelsize=8)
    axes[0].set_title(
        f"light: looks the same (mean CIEDE2000 ≤ {threshold:g}); dark: {statistical} ±1.96σ; dot: the fit",
        fontsize=9,
    )
    return png_bytes(fig)


def trace_figure(chain: np.ndarray, log_prob: np.ndarray, labels: Sequence[str], burn: int) -> bytes:
    """Every parameter (and the log-probability) against step, one line per walker."""
    steps, walkers, k = chain.shape
    shown = np.linspace(0, walkers - 1, min(walkers, MAX_TRACE_WALKERS)).astype(int)
    stride = max(1, steps // 4000)  # at most ~4000 points per line
    fig = new_figure(figsize=(10, 1.5 * (k + 1)))
    axes = fig.subplots(k + 1, 1, sharex=True)
    x = np.arange(0, steps, stride)
    for row, ax in enumerate(axes):
        values = chain[::stride, shown, row] if row < k else log_prob[::stride, shown]
        ax.plot(x, values, color="k", alpha=0.25, lw=0.5)
        ax.set_ylabel(labels[row] if row < k else "log p", fontsize=9)
        if burn:
            ax.axvspan(0, burn, color="C1", alpha=0.15, lw=0)
    axes[-1].set_xlabel("step (shaded: burn-in, discarded)")
    return png_bytes(fig)


# --- the report ------------------------------------------------------------------------------


_STYLE = (
    "\n"
    "body{font-family:system-ui,-apple-system,'Segoe UI',sans-serif;max-width:1100px;margin:2em auto;"
    "padding:0 1em;color:#222}\n"
    "table{border-collapse:collapse;margin:0.8em 0;font-size:0.9em}th,td{border:1px solid #ccc;padding:3px 8px;"
    "text-align:right}\n"
    "th{background:#f2f2f2}td:first-child,th:first-child{text-align:left}figure{margin:1em 0}img{max-width:100%}\n"
    "figcaption{color:#555;font-size:0.85em}.warn li{color:#8a3b00}.ok{color:#1a6b1a}"
    ".bad{color:#a00000;font-weight:bold}\n"
    "code{background:#f4f4f4;padding:0 3px}\n"
)


@uses_float64
def build_report(
    fit: FitResult | dict[str, Any],
    target_pixels: np.ndarray,
    fitted: np.ndarray,
    used: np.ndarray,
    *,
    chain: Chain | None = None,
    title: str | None = None,
    assets: str = "report_files",
    sources: dict[str, str] | None = None,
) -> Report:
    """Assemble the report from a fit result (a `FitResult`
    or its JSON), the target and fitted images (H, W, 3), the mask of pixels the fit used
    (H, W), and optionally a chain."""
    fit = FitResult.from_json(fit)
    laplace = Laplace.from_fit(fit)
    sources = sources or {}
    doc = Document(assets)
    data: dict[str, Any] = {"labels": laplace.labels}
    posterior = _chain_posterior(chain, laplace, data) if chain is not None else None
    heading = title or f"strauss-fit uncertainty report: {sources.get('target', 'target')}"
    _introduction(doc, heading, fit, sources, chain)
    _warnings_section(doc, fit, laplace, chain, posterior, data)
    _images_section(doc, fit, target_pixels, fitted, used, chain)
    _parameters_section(doc, fit, laplace, chain, posterior, data)
    if posterior is not None:
        _comparison_section(doc, fit, posterior, data)
    _correlation_section(doc, fit, laplace, posterior)
    _corner_section(doc, fit, laplace, posterior)
    if chain is not None and posterior is not None:
        doc.heading("Sampler diagnostics")
        sampler_diagnostics(doc, chain, posterior.diagnostics)
    _how_to_read(doc)
    return Report(html=doc.html(heading, _STYLE), markdown=doc.markdown(), images=doc.images, assets=assets, data=data)


def _chain_posterior(chain: Chain, laplace: Laplace, data: dict[str, Any]) -> ChainPosterior:
    """The chain's posterior set against the fit (its summary and diagnostics go into
    ``data``); a chain of other parameters than the fit's is a one-line error."""
    if chain.labels != laplace.labels:
        raise ReportError(
            f"the chain {chain.path} samples {', '.join(chain.labels)} but the fit frees "
            f"{', '.join(laplace.labels)}: they belong to different fits"
        )
    posterior = chain_posterior(chain, laplace, MAX_PLOT_SAMPLES)
    data.update(posterior=posterior.summary, diagnostics=posterior.diagnostics.as_dict())
    return posterior


def _introduction(doc: Document, heading: str, fit: FitResult, sources: dict[str, str], chain: Chain | None) -> None:
    """The title and one line of what was fitted to what: target, scene, pixels, the
    parameters fitted, the chain, and when and by which version the report was built."""
    doc.heading(heading, 1)
    facts = [
        f"target {sources.get('target', '?')}",
        f"scene {sources.get('scene', '?')}",
        f"{'?' if fit.pixels_used is None else fit.pixels_used} pixels used",
        f"fitted: {', '.join(fit.free)}",
    ]
    if chain is not None:
        facts.append(f"chain {chain.path}")
    doc.para("; ".join(facts) + ". " + generated_by())


def _warnings_section(
    doc: Document,
    fit: FitResult,
    laplace: Laplace,
    chain: Chain | None,
    posterior: ChainPosterior | None,
    data: dict[str, Any],
) -> None:
    """The verdict and every warning, first because they are what a reader must not miss:
    a loss the chain's likelihood does not share, an untrustworthy chain, the fit's warning
    codes, the degeneracies (from the posterior, else the fit's ±) and the fit's notes."""
    labels = laplace.labels
    covariance = posterior.covariance if posterior is not None and len(labels) > 1 else laplace.covariance
    covariance = np.atleast_2d(covariance)
    warnings = degeneracy_warnings(
        labels,
        covariance,
        fit.held,
        source="posterior"
        if posterior is not None
        else ("noise sandwich" if _statistical_name(fit) == "noise sandwich" else "Laplace estimate"),
        values=laplace.x_hat,
    )
    if posterior is not None and not posterior.diagnostics.trustworthy:
        warnings.insert(0, untrustworthy_chain(posterior.diagnostics.reasons))
    fit_warnings = [w for w in fit.warnings if isinstance(w, dict)]
    warnings = [f"[{w.get('code', '?')}] {w.get('message', '')}" for w in fit_warnings] + warnings
    other_loss = loss_warning(fit) if chain is not None else None
    if other_loss:  # first: every comparison with the chain below depends on it
        warnings.insert(0, other_loss[0].upper() + other_loss[1:] + ".")
    warnings += [f"fit: {note}" for note in fit.notes]
    data["warnings"] = warnings
    data["fit_warnings"] = fit_warnings
    data["verdict"] = fit.verdict
    verdict_and_warnings(
        doc,
        "Warnings",
        fit.verdict,
        _verdict_text(fit) if fit.verdict else "",
        warnings,
        "None: every fitted parameter is constrained on its own and the diagnostics pass.",
    )


def _images_section(
    doc: Document, fit: FitResult, target_pixels: np.ndarray, fitted: np.ndarray, used: np.ndarray, chain: Chain | None
) -> None:
    """The target, the fit and their difference side by side, and the residual in numbers
    (with the chain's noise σ when it has one)."""
    sigma = chain.meta.get("sigma") if chain is not None else None
    doc.heading("Target, fit and residual")
    doc.image(
        "images.png",
        images_figure(target_pixels, fitted, used, sigma),
        "target | least-squares fit | residual (fit − target, mean over R, G, B; grey: pixels not used)",
    )
    res = fit.residual
    doc.para(
        f"Residual RMS {fmt(res.get('rms'), 3)} (linear), CIEDE2000 mean {fmt(res.get('delta_e2000_mean'), 3)}, "
        f"95th percentile {fmt(res.get('delta_e2000_p95'), 3)}."
        + (f" Noise σ = {sigma:.3g} ({chain.meta.get('sigma_source', '')})." if sigma else "")
    )


def _parameters_section(
    doc: Document,
    fit: FitResult,
    laplace: Laplace,
    chain: Chain | None,
    posterior: ChainPosterior | None,
    data: dict[str, Any],
) -> None:
    """The parameter table, one sentence per kind of interval in it, the figure of the
    intervals (with equivalence bands), and the parameters the fit held."""
    statistical = _statistical_name(fit)
    bands = _equivalence_bands(fit, laplace.labels)
    threshold = float(fit.settings.get("equivalence_de", 1.0) or 1.0)
    adjusted = chain is not None and chain.adjustment.get("method") == "affine"
    doc.heading("Parameters")
    header, rows = _parameter_table(laplace, statistical, bands, threshold, adjusted, posterior)
    doc.table(header, rows)
    meanings = _interval_meanings(fit, bands, threshold, chain if adjusted else None)
    data["intervals"] = {"statistical": statistical, "bands": bands, "meanings": meanings}
    doc.bullets(meanings)
    if bands:
        _intervals_image(doc, laplace, bands, statistical, threshold)
    if posterior is None:
        doc.para(
            f"No chain was given: the intervals are the fit's Gaussian ones ({statistical}), x̂ ± σ and x̂ ± 1.96σ, "
            "which assume the model is linear over the uncertainty and ignore the bounds. "
            "Run 'strauss-fit sample' for the posterior."
        )
    if fit.held:
        held_parameters(doc, fit.held)


def _parameter_table(
    laplace: Laplace,
    statistical: str,
    bands: dict[str, tuple[float, float]],
    threshold: float,
    adjusted: bool,
    posterior: ChainPosterior | None,
) -> tuple[list[str], list[list[str]]]:
    """The parameter table's header and rows: value and ± per parameter, its equivalence
    band when the fit has them, then the posterior's percentiles and prior, or without a
    chain the Gaussian ones of the fit's ±."""
    short = "sandwich" if statistical == "noise sandwich" else "Laplace"
    header = ["parameter", "fit", f"± ({statistical})"] + ([f"looks the same (ΔE ≤ {threshold:g})"] if bands else [])
    if posterior is not None:
        header += posterior_header("posterior, adjusted" if adjusted else "posterior")
    else:
        header += [f"16 % ({short})", f"84 % ({short})", f"2.5 % ({short})", f"97.5 % ({short})"]
    rows = []
    for k, label in enumerate(laplace.labels):
        row = [label, fmt(laplace.x_hat[k]), fmt(laplace.sd[k], 2) if laplace.sd[k] > 0 else "at bound"]
        if bands:
            row.append(range_text(*bands[label]) if label in bands else "–")
        if posterior is not None:
            row += posterior_cells(posterior.summary["parameters"][label])
            row.append(prior_text(posterior.lower[k], posterior.upper[k]))
        else:
            x, s = laplace.x_hat[k], laplace.sd[k]
            row += [fmt(x - s), fmt(x + s), fmt(x - 1.96 * s), fmt(x + 1.96 * s)]
        rows.append(row)
    return header, rows


def _interval_meanings(
    fit: FitResult, bands: dict[str, tuple[float, float]], threshold: float, adjusted: Chain | None
) -> list[str]:
    """One sentence per kind of interval in the parameter table: the fit's ±, the
    equivalence band (when there are bands) and the adjusted posterior (``adjusted``: the
    chain, when it was adjusted to the sandwich)."""
    meanings = [_statistical_meaning(fit)]
    if bands:
        meanings.append(
            f"Looks the same (perceptual equivalence): every value in the band, the other parameters re-fitted, "
            f"renders within a mean CIEDE2000 of {threshold:g} of the fit — a difference nobody sees. It says what the "
            "image of this scene can show, not how precisely the data pin the value: a band far wider than the ± "
            "means a parameter the data determine but the eye does not."
        )
    if adjusted is not None:
        meanings.append(
            "Posterior, adjusted: the emcee chain mapped to the fit's noise sandwich (θ' = θ̂ + A(θ − θ̂), A chosen "
            "so that the draws' covariance is the sandwich's), keeping its shape; "
            f"{adjusted.adjustment.get('dropped', 0)} draws that left the prior were dropped."
        )
    return meanings


def _intervals_image(
    doc: Document, laplace: Laplace, bands: dict[str, tuple[float, float]], statistical: str, threshold: float
) -> None:
    """The figure of every parameter's equivalence band against its ±1.96σ, each over its
    range ([0, 1] for a colour or a fraction, else the band and the fit)."""
    labels = laplace.labels
    lo_box = np.array(
        [
            0.0 if _unit(label) else min(bands.get(label, (np.inf,))[0], laplace.x_hat[k])
            for k, label in enumerate(labels)
        ]
    )
    hi_box = np.array(
        [
            1.0 if _unit(label) else max(bands.get(label, (0.0, -np.inf))[1], laplace.x_hat[k])
            for k, label in enumerate(labels)
        ]
    )
    doc.image(
        "intervals.png",
        intervals_figure(labels, laplace.x_hat, laplace.sd, bands, lo_box, hi_box, statistical, threshold),
        f"per parameter: the band that looks the same (light), the {statistical} ±1.96σ interval (dark), the fit",
    )


def _comparison_section(doc: Document, fit: FitResult, posterior: ChainPosterior, data: dict[str, Any]) -> None:
    """The fit's ± against the chain's posterior, per parameter (widths, shift, skew), and
    what disagrees, or that they agree."""
    statistical = _statistical_name(fit)
    short = "sandwich" if statistical == "noise sandwich" else "Laplace"
    doc.heading(f"The fit's ± ({statistical}) against the posterior")
    rows_cmp, notes = posterior.rows, posterior.notes
    data["comparison"] = {"rows": [r.as_dict() for r in rows_cmp], "notes": notes}
    doc.table(
        [
            "parameter",
            "fit",
            f"{short} ±",
            "posterior median",
            "posterior ± (half 16–84 %)",
            "width ratio",
            "shift (σ)",
            "skew",
            "disagreement",
        ],
        [
            [
                r.label,
                fmt(r.x_hat),
                fmt(r.laplace_sd, 2),
                fmt(r.median),
                fmt(r.posterior_sd, 2),
                fmt(r.width_ratio, 3),
                f"{r.shift:+.2f}",
                f"{r.skew:+.2f}",
                ", ".join(r.issues) or "none",
            ]
            for r in rows_cmp
        ],
    )
    if notes:
        doc.bullets(notes, "warn")
    else:
        doc.para(
            "They agree: widths within 20–25 %, medians within half a standard deviation of the optimum, "
            f"no skew, no bound, no curved ridge. The fit's {statistical} alone would have done.",
            "ok",
        )


def _correlation_section(doc: Document, fit: FitResult, laplace: Laplace, posterior: ChainPosterior | None) -> None:
    """The correlation matrix, of the posterior samples or else of the fit's ±, as a figure
    and a table."""
    statistical = _statistical_name(fit)
    doc.heading("Correlations")
    if posterior is not None:
        corr = np.asarray(posterior.summary["correlation"])
    else:
        corr = _laplace.correlation(laplace.covariance)
    source = "posterior samples" if posterior is not None else statistical
    doc.image(
        "correlation.png",
        correlation_figure(laplace.labels, corr, f"correlation ({source})"),
        f"correlation matrix from the {source}",
    )
    correlation_table(doc, laplace.labels, corr)


def _corner_section(doc: Document, fit: FitResult, laplace: Laplace, posterior: ChainPosterior | None) -> None:
    """The corner plot of the posterior samples, or without a chain of draws from the fit's
    Gaussian (none when its covariance cannot be drawn from)."""
    statistical = _statistical_name(fit)
    labels = laplace.labels
    doc.heading("Corner plot")
    if posterior is not None:
        png = corner_figure(posterior.samples, labels, laplace.x_hat, "posterior (orange: least-squares fit)")
        doc.image(
            "corner.png",
            png,
            "posterior samples after burn-in; dashed: 16, 50 and 84 % quantiles; orange: least-squares optimum",
        )
        return
    draws = _laplace_draws(laplace)
    if draws is not None:
        doc.image(
            "corner.png",
            corner_figure(draws, labels, laplace.x_hat, f"{statistical} (Gaussian)"),
            f"draws from the Gaussian N(x̂, Σ) of the {statistical}, not a posterior sample",
        )


def _how_to_read(doc: Document) -> None:
    """The closing sub-section: what each number of the report means."""
    doc.heading("How to read this report", 3)
    doc.bullets(
        [
            "± (noise sandwich): sqrt of the diagonal of H⁻¹ Jᵀ diag(σ²) J H⁻¹, the spread of the fitted values "
            "over fresh noise of the known level σ, around the best Strauss approximation of this image — valid "
            "whether or not the model reproduces the target, but then an interval for that approximation, not "
            "for the material.",
            "± (Laplace): the Gauss–Newton standard deviation σ̂·sqrt((JᵀJ)⁻¹) with σ̂² = RSS/(N − P), used when the "
            "noise is unknown; exact for a linear model far from the bounds, and only if the model reproduces the "
            "target (else the misfit counts as noise and the ± is too wide).",
            "median and percentiles: of the emcee posterior samples after burn-in; 16–84 % is the central 68 % "
            "interval, 2.5–97.5 % the central 95 %.",
            "τ: the integrated autocorrelation time, in steps: about how many steps a walker takes to forget where it "
            "was. Effective samples = walkers × (steps − burn-in) / τ.",
            "Acceptance fraction: the share of proposed moves accepted; emcee works well between about 0.2 and 0.5.",
            "Correlation near ±1: the two quantities trade off, and the image constrains only a combination of them.",
        ]
    )


def sampler_diagnostics(
    doc: Document, chain: Chain, diagnostics: Diagnostics, *, shown: Sequence[int] | None = None, note: str = ""
) -> None:
    """The sampler's diagnostics in a report (after its heading): the trace plots
    (``trace.png``, of the parameters ``shown``, by index, default all; ``note`` ends their
    description), the verdict in one paragraph, and τ and the effective samples of every
    parameter. The one section of the report of one image and of a capture's."""
    shown = list(range(len(chain.labels))) if shown is None else list(shown)
    doc.image(
        "trace.png",
        trace_figure(chain.chain[:, :, shown], chain.log_prob, [chain.labels[k] for k in shown], diagnostics.burn_in),
        "trace of every walker; shaded: burn-in (2 × the largest autocorrelation time), discarded" + note,
    )
    verdict = "trustworthy" if diagnostics.trustworthy else "NOT trustworthy"
    doc.para(
        f"{diagnostics.steps} steps × {diagnostics.walkers} walkers; burn-in {diagnostics.burn_in} steps; "
        f"the chain is {diagnostics.tau_multiple:.0f} autocorrelation times long "
        f"(needed: {diagnostics.min_tau_multiple:.0f}); acceptance fraction {diagnostics.acceptance_mean:.2f} "
        f"(walkers {diagnostics.acceptance_min:.2f}–{diagnostics.acceptance_max:.2f}). Verdict: {verdict}.",
        "ok" if diagnostics.trustworthy else "bad",
    )
    doc.table(
        ["parameter", "τ (steps)", "effective samples"],
        [[label, f"{t:.1f}", f"{e:.0f}"] for label, t, e in zip(diagnostics.labels, diagnostics.tau, diagnostics.ess)],
    )


def _statistical_name(fit: FitResult) -> str:
    """ "noise sandwich" or "Laplace", as the fit computed its ±."""
    return "noise sandwich" if (fit.uncertainty_method or {}).get("name") == "noise sandwich" else "Laplace"


def _statistical_meaning(fit: FitResult) -> str:
    if _statistical_name(fit) == "noise sandwich":
        source = (fit.uncertainty_method or {}).get("noise_source") or fit.residual.get("noise_source") or "known"
        text = (
            f"± (noise sandwich, the target's noise from: {source}): how far the fitted values would move if the "
            "image were taken again with fresh noise — an interval for the best Strauss approximation of this image"
        )
        loss = (fit.solver or {}).get("loss")
        if loss in ROBUST_LOSSES:  # a robust loss's pseudo-truth (docs/uncertainty.md)
            text += (
                f" (with the {loss} loss: the value its fit converges to at this noise level, the minimiser of the "
                "expected loss, not its fit of the noise-free image)"
            )
        if fit.verdict == "mismatch":
            return text + ", not for the true material, since the model cannot reproduce the target."
        return text + "; with a model that reproduces the target, as here, that is the material's value."
    return (
        "± (Laplace): σ̂·sqrt((JᵀJ)⁻¹) with σ̂² = RSS/(N − P), the noise estimated from the residual — valid only "
        "if the model reproduces the target (otherwise the misfit counts as noise); give the fit the noise level "
        "for the noise sandwich."
    )


def _verdict_text(fit: FitResult) -> str:
    residual = fit.residual
    verdict = fit.verdict
    chi2 = residual.get("chi2_per_dof")
    against = f" (χ²/dof {chi2:.4g} against the noise, from: {residual.get('noise_source', '?')})" if chi2 else ""
    at_bound = residual.get("chi2_per_dof_at_bound")
    one_sided = not chi2 and at_bound is not None
    if one_sided:
        against = f" (χ²/dof {at_bound:.4g} at the largest noise the image can hold; its own noise unknown)"
    meaning = {
        "consistent": "the Strauss model reproduces the target within its noise",
        "mismatch": "the Strauss model cannot reproduce the target: the residual is larger than the largest noise the "
        "image can hold, or spatially structured (a one-sided verdict: the noise itself is unknown)"
        if one_sided
        else "the Strauss model cannot reproduce the target: the residual is larger than the noise explains",
        "undetermined": "the target's noise is unknown and the residual is within the largest noise the image can "
        "hold, so whether the model reproduces it cannot be said",
    }.get(str(verdict), "")
    return f"Verdict: {verdict}{against}" + (f": {meaning}." if meaning else ".")


def _unit(label: str) -> bool:
    return label.startswith("color_") or label in FRACTION_NAMES


def _equivalence_bands(fit: FitResult, labels: Sequence[str]) -> dict[str, tuple[float, float]]:
    """The fit's equivalence ranges by vector label (colour per channel), or {}."""
    ranges = fit.equivalence
    out: dict[str, tuple[float, float]] = {}
    if not isinstance(ranges, dict):
        return out
    for name, value in ranges.items():
        try:
            if name == "color":
                for channel, pair in zip("rgb", value):
                    out[f"color_{channel}"] = (float(pair[0]), float(pair[1]))
            else:
                out[name] = (float(value[0]), float(value[1]))
        except (TypeError, ValueError, IndexError):
            continue
    return {label: out[label] for label in labels if label in out}


def _laplace_draws(laplace: Laplace, count: int = 4000) -> np.ndarray | None:
    cov = laplace.covariance
    if not np.all(np.isfinite(cov)) or not np.any(laplace.sd > 0):
        return None
    try:
        return np.random.default_rng(0).multivariate_normal(laplace.x_hat, cov, size=count, method="eigh")
    except (np.linalg.LinAlgError, ValueError):
        return None


# --- writing ---------------------------------------------------------------------------------


def report_paths(html_path: str | Path) -> tuple[Path, Path, Path]:
    """REPORT.html → (REPORT.html, REPORT.md, REPORT_files/)."""
    html_path = Path(html_path)
    return html_path, html_path.with_suffix(".md"), html_path.parent / f"{html_path.stem}_files"


def check_report_outputs(
    html_path: str | Path,
    force: bool,
    image_names: Sequence[str] = ("images.png", "intervals.png", "correlation.png", "corner.png", "trace.png"),
    inputs: dict[str, str | Path | None] | None = None,
) -> None:
    """Refuse (before any work) to overwrite an existing report without ``force``, and,
    even with it, a report that would overwrite one of its ``inputs`` (``{"fit": path,
    ...}``; None entries skipped): the page or its Markdown naming one, or one lying in
    its ``REPORT_files/`` folder."""
    page, markdown, folder = report_paths(html_path)
    if inputs:
        check_distinct({"the report": page, "the report's Markdown": markdown}, inputs)
        check_outside(folder, "the report", inputs)
    check_writable(page, force)
    check_writable(markdown, force)
    if folder.exists() and not folder.is_dir():
        raise ReportError(f"{folder} exists and is not a folder")
    if folder.is_dir():
        for name in image_names:
            check_writable(folder / name, force)


def write_report(
    report: Report,
    html_path: str | Path,
    *,
    force: bool = False,
    inputs: dict[str, str | Path | None] | None = None,
) -> list[Path]:
    """Write the PNGs into REPORT_files/, REPORT.md and REPORT.html, all or none: each is
    written in full to a temporary file first, and they are renamed into place together
    (a full disk or Ctrl-C leaves no part of the report, and REPORT_files/ only if it
    existed before). None of them may overwrite one of the report's ``inputs``
    (`check_report_outputs`)."""
    page, markdown, folder = report_paths(html_path)
    check_report_outputs(page, force, list(report.images), inputs)
    created = not folder.exists()
    try:
        folder.mkdir(exist_ok=True)
    except OSError as exc:
        raise ReportError(f"cannot create {folder}: {exc.strerror or exc}") from None
    try:
        with Outputs(force=force) as out:
            written = [out.add_bytes(folder / name, png) for name, png in report.images.items()]
            out.add_bytes(markdown, report.markdown.encode("utf-8"))
            out.add_bytes(page, report.html.encode("utf-8"))
            out.commit(final=True)
    except BaseException:
        if created:
            try:
                folder.rmdir()  # only if empty: nothing of anyone else's is removed
            except OSError:
                pass
        raise
    return [page, markdown] + written


# --- inputs ----------------------------------------------------------------------------------


@uses_float64
def render_fit(scene: Scene, target: Target, fit: FitResult | dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """The fitted image (H, W, 3) of a fit result — the scene rendered with the result's
    material, light intensities and exposure — and the mask of the pixels the fit used
    (`strauss_fit.fitting.problem.used_pixels`). ``scene`` must match the target's size."""
    import equinox as eqx
    import jax.numpy as jnp

    from ..fitting.parameters import lights_with
    from ..fitting.problem import used_pixels
    from ..rendering.strauss import render

    fit = FitResult.from_json(fit)
    lights = {k: jnp.asarray(float(v)) for k, v in fit.lights.items()}
    scene = eqx.tree_at(lambda s: s.lights, scene, lights_with(scene.lights, lights))
    settings = fit.settings
    image, hit = render(
        scene,
        fit.material,
        mode=settings.get("mode", "exact"),
        table_size=int(settings.get("table_size", DEFAULT_TABLE_SIZE)),
        dtype=jnp.float64,
    )
    exposure = 1.0 if fit.exposure is None else float(fit.exposure)
    # results written before edge pixels were left out (no "edge_pixels" setting) used them
    used = used_pixels(scene, target, np.asarray(hit), settings.get("edge_pixels", "include"))
    return np.asarray(image) * exposure, used


def recorded_path(path: str | None, base: Path | None) -> str | None:
    """A path recorded in a result: as written if it exists from here, else relative to
    the folder of the file that recorded it."""
    if path is None:
        return None
    if Path(path).exists() or base is None or Path(path).is_absolute():
        return path
    candidate = base / path
    return str(candidate) if candidate.exists() else path


@uses_float64
def report_from_files(
    output: str | Path,
    *,
    fit: str | Path | None = None,
    chain: str | Path | None = None,
    target: str | Path | None = None,
    scene: str | Path | None = None,
    mask: str | Path | None = None,
    encoding: str | None = None,
    title: str | None = None,
    force: bool = False,
) -> tuple[Report, list[Path]]:
    """Build the report of a fit result (``fit``, the path of its JSON), a chain
    (``chain``, of ``strauss-fit sample``) or both, and write it to ``output`` (.html;
    the Markdown and the PNG folder beside it). The target, scene, mask and encoding
    default to those the fit result or the chain recorded (a recorded relative path is
    tried from here, then from the recording file's folder). An input, given or recorded,
    that the report would overwrite or that lies in its ``REPORT_files/`` folder is
    refused, even with ``force`` (`check_report_outputs`). Returns the report and the
    files written."""
    if not fit and not chain:
        raise StraussFitError("give a fit result (--fit RESULT.json), a chain (--chain CHAIN.h5), or both")
    check_html_name(output)
    given = {"fit": fit, "chain": chain, "target": target, "scene": scene, "mask": mask}
    check_report_outputs(output, force, inputs=given)
    loaded_chain = load_chain(chain, required=True) if chain else None
    meta = loaded_chain.meta if loaded_chain is not None else {}
    chain_base = Path(chain).parent if chain else None
    if fit:
        result = read_json(fit, "fit result")
        fit_base = Path(fit).parent
        if not isinstance(result, dict) or "free" not in result:
            raise StraussFitError(f"{fit} is not a strauss-fit fit result (no 'free' list)")
    else:
        result, fit_base = meta["fit"], chain_base
    result = FitResult.from_json(result)
    recorded = result.extra
    target_path = (
        target or recorded_path(meta.get("target"), chain_base) or recorded_path(recorded.get("target"), fit_base)
    )
    scene_path = scene or recorded_path(meta.get("scene"), chain_base) or recorded_path(recorded.get("scene"), fit_base)
    if not target_path:
        raise StraussFitError("the fit result does not record its target: give --target")
    if not scene_path:
        raise StraussFitError("the fit result does not record its scene: give --scene")
    # the fit result records its mask and encoding only if 'fit' wrote them (older results do not)
    mask = mask or recorded_path(meta.get("mask"), chain_base) or recorded_path(recorded.get("mask"), fit_base)
    encoding = encoding or meta.get("encoding") or recorded.get("encoding") or "auto"
    loaded_scene = load_scene(scene_path)
    loaded_target = load_target(target_path, mask, encoding)
    loaded_scene, _ = match_scene(loaded_scene, loaded_target)
    fitted, used = render_fit(loaded_scene, loaded_target, result)
    if result.pixels_used is not None and int(used.sum()) != int(result.pixels_used):
        raise StraussFitError(
            f"the fit used {result.pixels_used} pixels but {target_path} has {int(used.sum())} "
            "usable sphere pixels: give the target (and --mask) the fit was made with"
        )
    out = Path(output)
    report = build_report(
        result,
        loaded_target.pixels,
        fitted,
        used,
        chain=loaded_chain,
        title=title,
        assets=f"{out.stem}_files",
        sources={"target": str(target_path), "scene": str(scene_path)},
    )
    # the recorded target, scene and mask too: none of them may be overwritten either
    inputs = {"fit": fit, "chain": chain, "target": target_path, "scene": scene_path, "mask": mask}
    return report, write_report(report, out, force=force, inputs=inputs)
