"""The uncertainty report: one self-contained HTML page (images embedded as base64 PNG, no
scripts, no network) and the same content as Markdown with the PNGs in a folder beside it.

Contents: warnings first (degeneracies, an untrustworthy chain, the fit's notes); the
target, fit and residual images; the parameter table (least-squares value, Laplace ±,
posterior median and 16/84 and 2.5/97.5 percentiles, prior); parameters held and why; the
Laplace-versus-posterior comparison (:func:`strauss_fit.uncertainty.compare`); the
correlation matrix; a corner plot; trace plots and sampler diagnostics. Without a chain the
intervals are the Laplace (Gaussian) ones and say so.

Plots are drawn with matplotlib's object API (``Figure`` + the Agg canvas), so building a
report never touches pyplot's global state or needs a display.
"""

from __future__ import annotations

import base64
import datetime as _dt
import html
import io
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .errors import StraussFitError
from .io import check_writable, srgb_encode, write_bytes
from .sample import Chain
from .uncertainty import (
    Laplace,
    compare,
    correlation_of,
    degeneracy_warnings,
    posterior_summary,
)

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

def _png(fig) -> bytes:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=100, bbox_inches="tight")
    return buffer.getvalue()


def _display(image: np.ndarray, exposure: float) -> np.ndarray:
    """Linear radiance to displayable sRGB in [0, 1] (exposure, clip, encode)."""
    return srgb_encode(np.asarray(image) * exposure)


def images_figure(target: np.ndarray, fitted: np.ndarray, used: np.ndarray, sigma: float | None) -> bytes:
    """Target | fit | residual (fit − target, mean over RGB, at the pixels used)."""
    from matplotlib.figure import Figure

    values = target[used]
    exposure = 1.0 / max(float(np.percentile(values, 99)) if values.size else 1.0, 1e-12)
    residual = np.where(used, (fitted - target).mean(axis=-1), np.nan)
    finite = np.abs(residual[used]) if used.any() else np.zeros(1)
    limit = max(float(np.percentile(finite, 99.5)), 1e-12)
    fig = Figure(figsize=(11, 3.8))
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
    return _png(fig)


def correlation_figure(labels: Sequence[str], corr: np.ndarray, title: str) -> bytes:
    from matplotlib.figure import Figure

    k = len(labels)
    fig = Figure(figsize=(1.0 + 0.75 * k, 0.6 + 0.7 * k))
    ax = fig.subplots()
    shown = ax.imshow(corr, cmap="RdBu_r", vmin=-1, vmax=1)
    ax.set_xticks(range(k), labels, rotation=45, ha="right")
    ax.set_yticks(range(k), labels)
    if k <= 12:
        for i in range(k):
            for j in range(k):
                ax.text(j, i, f"{corr[i, j]:+.2f}", ha="center", va="center", fontsize=8,
                        color="white" if abs(corr[i, j]) > 0.6 else "black")
    ax.set_title(title)
    fig.colorbar(shown, ax=ax, fraction=0.046, pad=0.04)
    return _png(fig)


def corner_figure(samples: np.ndarray, labels: Sequence[str], truths: np.ndarray | None, title: str) -> bytes | None:
    """corner's plot of ``samples``; columns without spread (a pinned entry) are left out."""
    import corner
    from matplotlib.figure import Figure

    spread = np.ptp(samples, axis=0) > 0
    if spread.sum() < 1:
        return None
    samples = samples[:, spread]
    labels = [label for label, keep in zip(labels, spread) if keep]
    k = len(labels)
    fig = Figure(figsize=(max(2.2 * k, 4), max(2.2 * k, 4)))
    corner.corner(samples, labels=labels, quantiles=[0.16, 0.5, 0.84], show_titles=True, title_fmt=".3g",
                  truths=None if truths is None else np.asarray(truths)[spread], truth_color="C1", fig=fig,
                  plot_datapoints=samples.shape[0] <= 5000)
    fig.suptitle(title, y=1.02)
    return _png(fig)


def trace_figure(chain: np.ndarray, log_prob: np.ndarray, labels: Sequence[str], burn: int) -> bytes:
    """Every parameter (and the log-probability) against step, one line per walker."""
    from matplotlib.figure import Figure

    steps, walkers, k = chain.shape
    shown = np.linspace(0, walkers - 1, min(walkers, MAX_TRACE_WALKERS)).astype(int)
    stride = max(1, steps // 4000)  # at most ~4000 points per line
    fig = Figure(figsize=(10, 1.5 * (k + 1)))
    axes = fig.subplots(k + 1, 1, sharex=True)
    x = np.arange(0, steps, stride)
    for row, ax in enumerate(axes):
        values = chain[::stride, shown, row] if row < k else log_prob[::stride, shown]
        ax.plot(x, values, color="k", alpha=0.25, lw=0.5)
        ax.set_ylabel(labels[row] if row < k else "log p", fontsize=9)
        if burn:
            ax.axvspan(0, burn, color="C1", alpha=0.15, lw=0)
    axes[-1].set_xlabel("step (shaded: burn-in, discarded)")
    return _png(fig)


# --- the report ------------------------------------------------------------------------------

def _fmt(value: float | None, digits: int = 4) -> str:
    if value is None or not np.isfinite(value):
        return "–"
    return f"{value:.{digits}g}"


@dataclass
class _Table:
    header: list[str]
    rows: list[list[str]]

    def html(self) -> str:
        head = "".join(f"<th>{html.escape(h)}</th>" for h in self.header)
        body = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in row) + "</tr>" for row in self.rows)
        return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"

    def markdown(self) -> str:
        def cell(text: str) -> str:
            return text.replace("|", "\\|")
        lines = ["| " + " | ".join(cell(h) for h in self.header) + " |", "|" + "---|" * len(self.header)]
        lines += ["| " + " | ".join(cell(c) for c in row) + " |" for row in self.rows]
        return "\n".join(lines)


class _Doc:
    """Builds the HTML and the Markdown side by side."""

    def __init__(self, assets: str):
        self.assets = assets
        self.html: list[str] = []
        self.md: list[str] = []
        self.images: dict[str, bytes] = {}

    def heading(self, text: str, level: int = 2) -> None:
        self.html.append(f"<h{level}>{html.escape(text)}</h{level}>")
        self.md.append("#" * level + " " + text + "\n")

    def para(self, text: str, cls: str | None = None) -> None:
        attr = f' class="{cls}"' if cls else ""
        self.html.append(f"<p{attr}>{html.escape(text)}</p>")
        self.md.append(text + "\n")

    def bullets(self, items: Sequence[str], cls: str | None = None) -> None:
        if not items:
            return
        attr = f' class="{cls}"' if cls else ""
        self.html.append(f"<ul{attr}>" + "".join(f"<li>{html.escape(i)}</li>" for i in items) + "</ul>")
        self.md.append("\n".join(f"- {i}" for i in items) + "\n")

    def table(self, table: _Table) -> None:
        self.html.append(table.html())
        self.md.append(table.markdown() + "\n")

    def image(self, name: str, png: bytes | None, alt: str) -> None:
        if png is None:
            return
        self.images[name] = png
        data = base64.b64encode(png).decode("ascii")
        self.html.append(f'<figure><img alt="{html.escape(alt)}" src="data:image/png;base64,{data}">'
                         f"<figcaption>{html.escape(alt)}</figcaption></figure>")
        self.md.append(f"![{alt}]({self.assets}/{name})\n")


_STYLE = """
body{font-family:system-ui,-apple-system,'Segoe UI',sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;color:#222}
table{border-collapse:collapse;margin:0.8em 0;font-size:0.9em}th,td{border:1px solid #ccc;padding:3px 8px;text-align:right}
th{background:#f2f2f2}td:first-child,th:first-child{text-align:left}figure{margin:1em 0}img{max-width:100%}
figcaption{color:#555;font-size:0.85em}.warn li{color:#8a3b00}.ok{color:#1a6b1a}.bad{color:#a00000;font-weight:bold}
code{background:#f4f4f4;padding:0 3px}
"""


def build_report(fit: dict[str, Any], target_pixels: np.ndarray, fitted: np.ndarray, used: np.ndarray, *,
                 chain: Chain | None = None, title: str | None = None, assets: str = "report_files",
                 sources: dict[str, str] | None = None) -> Report:
    """Assemble the report from a fit result (JSON dict), the target and fitted images
    (H, W, 3), the mask of pixels the fit used (H, W), and optionally a chain."""
    laplace = Laplace.from_fit(fit)
    labels = laplace.labels
    sources = sources or {}
    doc = _Doc(assets)
    data: dict[str, Any] = {"labels": labels}

    summary = samples = diagnostics = None
    lower = upper = None
    if chain is not None:
        if chain.labels != labels:
            raise ReportError(f"the chain {chain.path} samples {', '.join(chain.labels)} but the fit frees "
                              f"{', '.join(labels)}: they belong to different fits")
        diagnostics = chain.diagnostics()
        samples = chain.samples(diagnostics.burn_in)
        if samples.shape[0] > MAX_PLOT_SAMPLES:
            samples = samples[np.random.default_rng(0).choice(samples.shape[0], MAX_PLOT_SAMPLES, replace=False)]
        summary = posterior_summary(chain.samples(diagnostics.burn_in), labels)
        prior = chain.meta.get("prior", {})
        lower = np.array([prior.get(label, [-np.inf, np.inf])[0] for label in labels], dtype=np.float64)
        upper = np.array([prior.get(label, [-np.inf, np.inf])[1] for label in labels], dtype=np.float64)
        data.update(posterior=summary, diagnostics=diagnostics.as_dict())

    sigma = (chain.meta.get("sigma") if chain is not None else None)
    heading = title or f"strauss-fit uncertainty report: {sources.get('target', 'target')}"
    doc.heading(heading, 1)
    stamp = _dt.datetime.now().strftime("%Y-%m-%d %H:%M")
    from . import __version__

    facts = [f"target {sources.get('target', '?')}", f"scene {sources.get('scene', '?')}",
             f"{fit.get('pixels_used', '?')} pixels used", f"fitted: {', '.join(fit['free'])}"]
    if chain is not None:
        facts.append(f"chain {chain.path}")
    doc.para("; ".join(facts) + f". Generated by strauss-fit {__version__} on {stamp}.")

    # warnings first: they are what a reader must not miss
    covariance = np.cov(samples, rowvar=False) if samples is not None and len(labels) > 1 else laplace.covariance
    covariance = np.atleast_2d(covariance)
    warnings = degeneracy_warnings(labels, covariance, fit.get("held"),
                                   source="posterior" if samples is not None else "Laplace estimate",
                                   values=laplace.x_hat)
    if diagnostics is not None and not diagnostics.trustworthy:
        warnings.insert(0, "The chain is not trustworthy yet: " + "; ".join(diagnostics.reasons) + ".")
    warnings += [f"fit: {note}" for note in fit.get("notes", [])]
    data["warnings"] = warnings
    doc.heading("Warnings")
    if warnings:
        doc.bullets(warnings, "warn")
    else:
        doc.para("None: every fitted parameter is constrained on its own and the diagnostics pass.", "ok")

    doc.heading("Target, fit and residual")
    doc.image("images.png", images_figure(target_pixels, fitted, used, sigma),
              "target | least-squares fit | residual (fit − target, mean over R, G, B; grey: pixels not used)")
    res = fit.get("residual", {})
    doc.para(f"Residual RMS {_fmt(res.get('rms'), 3)} (linear), CIEDE2000 mean {_fmt(res.get('delta_e2000_mean'), 3)}, "
             f"95th percentile {_fmt(res.get('delta_e2000_p95'), 3)}."
             + (f" Noise σ = {sigma:.3g} ({chain.meta.get('sigma_source', '')})." if sigma else ""))

    doc.heading("Parameters")
    if summary is not None:
        header = ["parameter", "fit", "Laplace ±", "median", "16 %", "84 %", "2.5 %", "97.5 %", "prior"]
    else:
        header = ["parameter", "fit", "Laplace ±", "16 % (Laplace)", "84 % (Laplace)", "2.5 % (Laplace)",
                  "97.5 % (Laplace)"]
    rows = []
    for k, label in enumerate(labels):
        row = [label, _fmt(laplace.x_hat[k]), _fmt(laplace.sd[k], 2) if laplace.sd[k] > 0 else "at bound"]
        if summary is not None:
            p = summary["parameters"][label]
            row += [_fmt(p["median"]), _fmt(p["p16"]), _fmt(p["p84"]), _fmt(p["p2.5"]), _fmt(p["p97.5"]),
                    f"[{_fmt(lower[k], 3)}, {_fmt(upper[k], 3)}]"]
        else:
            x, s = laplace.x_hat[k], laplace.sd[k]
            row += [_fmt(x - s), _fmt(x + s), _fmt(x - 1.96 * s), _fmt(x + 1.96 * s)]
        rows.append(row)
    doc.table(_Table(header, rows))
    if summary is None:
        doc.para("No chain was given: the intervals are the Laplace (Gauss–Newton) ones, x̂ ± σ and x̂ ± 1.96σ, "
                 "which assume the model is linear over the uncertainty and ignore the bounds. "
                 "Run 'strauss-fit sample' for the posterior.")
    held = fit.get("held", {})
    if held:
        doc.heading("Held parameters", 3)
        doc.table(_Table(["parameter", "value", "why"],
                         [[name, _value_text(info.get("value")), info.get("reason", "")] for name, info in held.items()]))

    if summary is not None:
        doc.heading("Laplace estimate against the posterior")
        rows_cmp, notes = compare(laplace, summary, samples, lower, upper)
        data["comparison"] = {"rows": [r.as_dict() for r in rows_cmp], "notes": notes}
        doc.table(_Table(["parameter", "fit", "Laplace ±", "posterior median", "posterior ± (half 16–84 %)",
                          "width ratio", "shift (σ)", "skew", "disagreement"],
                         [[r.label, _fmt(r.x_hat), _fmt(r.laplace_sd, 2), _fmt(r.median), _fmt(r.posterior_sd, 2),
                           _fmt(r.width_ratio, 3), f"{r.shift:+.2f}", f"{r.skew:+.2f}", ", ".join(r.issues) or "none"]
                          for r in rows_cmp]))
        if notes:
            doc.bullets(notes, "warn")
        else:
            doc.para("They agree: widths within 20–25 %, medians within half a standard deviation of the optimum, "
                     "no skew, no bound, no curved ridge. The Laplace estimate alone would have done.", "ok")

    doc.heading("Correlations")
    corr = np.asarray(summary["correlation"]) if summary is not None else correlation_of(laplace.covariance)
    source = "posterior samples" if summary is not None else "Laplace estimate"
    doc.image("correlation.png", correlation_figure(labels, corr, f"correlation ({source})"),
              f"correlation matrix from the {source}")
    doc.table(_Table([""] + labels, [[label] + [f"{v:+.2f}" for v in corr[i]] for i, label in enumerate(labels)]))

    doc.heading("Corner plot")
    if samples is not None:
        png = corner_figure(samples, labels, laplace.x_hat, "posterior (orange: least-squares fit)")
        doc.image("corner.png", png, "posterior samples after burn-in; dashed: 16, 50 and 84 % quantiles; "
                  "orange: least-squares optimum")
    else:
        draws = _laplace_draws(laplace)
        if draws is not None:
            doc.image("corner.png", corner_figure(draws, labels, laplace.x_hat, "Laplace approximation (Gaussian)"),
                      "draws from the Laplace approximation N(x̂, Σ), not a posterior sample")

    if chain is not None and diagnostics is not None:
        doc.heading("Sampler diagnostics")
        doc.image("trace.png", trace_figure(chain.chain, chain.log_prob, labels, diagnostics.burn_in),
                  "trace of every walker; shaded: burn-in (2 × the largest autocorrelation time), discarded")
        verdict = "trustworthy" if diagnostics.trustworthy else "NOT trustworthy"
        doc.para(f"{diagnostics.steps} steps × {diagnostics.walkers} walkers; burn-in {diagnostics.burn_in} steps; "
                 f"the chain is {diagnostics.tau_multiple:.0f} autocorrelation times long "
                 f"(needed: {diagnostics.min_tau_multiple:.0f}); acceptance fraction {diagnostics.acceptance_mean:.2f} "
                 f"(walkers {diagnostics.acceptance_min:.2f}–{diagnostics.acceptance_max:.2f}). Verdict: {verdict}.",
                 "ok" if diagnostics.trustworthy else "bad")
        doc.table(_Table(["parameter", "τ (steps)", "effective samples"],
                         [[label, f"{t:.1f}", f"{e:.0f}"] for label, t, e in
                          zip(labels, diagnostics.tau, diagnostics.ess)]))

    doc.heading("How to read this report", 3)
    doc.bullets([
        "Laplace ±: the Gauss–Newton standard deviation σ·sqrt((JᵀJ)⁻¹) at the least-squares optimum; exact for a "
        "linear model far from the bounds.",
        "median and percentiles: of the emcee posterior samples after burn-in; 16–84 % is the central 68 % "
        "interval, 2.5–97.5 % the central 95 %.",
        "τ: the integrated autocorrelation time, in steps: about how many steps a walker takes to forget where it "
        "was. Effective samples = walkers × (steps − burn-in) / τ.",
        "Acceptance fraction: the share of proposed moves accepted; emcee works well between about 0.2 and 0.5.",
        "Correlation near ±1: the two quantities trade off, and the image constrains only a combination of them.",
    ])
    page = ("<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{html.escape(heading)}</title><style>{_STYLE}</style></head><body>"
            + "\n".join(doc.html) + "</body></html>\n")
    return Report(html=page, markdown="\n".join(doc.md), images=doc.images, assets=assets, data=data)


def _value_text(value: Any) -> str:
    if isinstance(value, (list, tuple)):
        return "(" + ", ".join(f"{float(v):.4g}" for v in value) + ")"
    return _fmt(value) if value is not None else "–"


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


def check_report_outputs(html_path: str | Path, force: bool, image_names: Sequence[str] = (
        "images.png", "correlation.png", "corner.png", "trace.png")) -> None:
    """Refuse (before any work) to overwrite an existing report without ``force``."""
    page, markdown, folder = report_paths(html_path)
    check_writable(page, force)
    check_writable(markdown, force)
    if folder.exists() and not folder.is_dir():
        raise ReportError(f"{folder} exists and is not a folder")
    if folder.is_dir():
        for name in image_names:
            check_writable(folder / name, force)


def write_report(report: Report, html_path: str | Path, *, force: bool = False) -> list[Path]:
    """Write the PNGs into REPORT_files/, then REPORT.md, then REPORT.html (each atomic)."""
    page, markdown, folder = report_paths(html_path)
    check_report_outputs(page, force, list(report.images))
    folder.mkdir(exist_ok=True)
    written = []
    for name, png in report.images.items():
        write_bytes(folder / name, png, force=force)
        written.append(folder / name)
    write_bytes(markdown, report.markdown.encode("utf-8"), force=force)
    write_bytes(page, report.html.encode("utf-8"), force=force)
    return [page, markdown] + written


# --- inputs ----------------------------------------------------------------------------------

def render_fit(scene, target, fit: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """The fitted image (H, W, 3) of a fit result — the scene rendered with the result's
    material and light intensities — and the mask of the pixels the fit used (on the
    sphere and usable in ``target``). ``scene`` must match the target's size."""
    import equinox as eqx
    import jax.numpy as jnp

    from .material import Material
    from .model import DEFAULT_TABLE_SIZE
    from .parameters import lights_with
    from .render import render

    material = Material.from_dict({k: fit[k] for k in ("color", "smoothness", "metalness", "transparency", "ior")})
    lights = {k: jnp.asarray(float(v)) for k, v in fit.get("lights", {}).items()}
    scene = eqx.tree_at(lambda s: s.lights, scene, lights_with(scene.lights, lights))
    settings = fit.get("settings", {})
    image, hit = render(scene, material, mode=settings.get("mode", "exact"),
                        table_size=int(settings.get("table_size", DEFAULT_TABLE_SIZE)), dtype=jnp.float64)
    return np.asarray(image), np.asarray(hit) & target.usable
