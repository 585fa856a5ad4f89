"""The report of a capture's fit (``strauss-fit report --fit`` of a result of ``fit --capture``):
one self-contained HTML page and the same content as Markdown with the PNGs beside it, like
the report of one image (`strauss_fit.reporting.fit_report`, whose document, figures and
atomic writing it shares).

Contents, in order: the verdict and the warnings (codes and messages, then the fit's notes);
the capture (images fitted and held out, sphere pixels, the circle, the camera); the parameter
table (value, ± image-cluster sandwich, ± Laplace, and the perceptual equivalence range when
the result has one) with one sentence per kind of interval; the residual (relative RMS, mean
CIEDE2000, against the noise floor and the noise bound, by region); the per-light grid, one row
of target, fit and residual per image (`light_panels`, `grid_figure`), the
held-out images last with the fit's prediction of them; the per-image table; the held-out
comparison with other models; the correlation matrix; with a chain of ``strauss-fit sample``
(`strauss_fit.inference.capture_posterior`), the posterior: its percentiles against the
fit, the corner plot and the sampler's diagnostics (an untrustworthy chain is the first warning).

`capture_report_from_files` is the whole workflow: it reads the capture the result
records again (`strauss_fit.fitting.capture_result.reload_capture_fit` and
`strauss_fit.fitting.capture_result.reload_held_out`; a chain's from the fit its metadata
holds, `strauss_fit.inference.capture_posterior.reload_chain_capture`), builds the
report and writes it.
"""

from __future__ import annotations

import math
import warnings as _warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..capture import Capture, CaptureSamples, Circle, open_capture
from ..errors import StraussFitError
from ..fitting.capture import BOUND_FACTOR, CaptureFit, delta_e_mean, relative_rms
from ..fitting.capture_result import (
    check_capture_result,
    holdout_indices,
    is_capture_result,
    reload_capture_fit,
    reload_held_out,
)
from ..inference.capture_posterior import (
    _circle_warning,
    _fit_laplace,
    capture_chain_summary,
    check_capture_chain,
    data_digest,
    is_capture_chain,
    reload_chain_capture,
)
from ..inference.sampler import Chain, Diagnostics, load_chain
from ..io.files import read_json
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
from .fit_report import (
    _STYLE,
    MAX_PLOT_SAMPLES,
    Report,
    ReportError,
    _display,
    check_report_outputs,
    corner_figure,
    correlation_figure,
    intervals_figure,
    recorded_path,
    sampler_diagnostics,
    write_report,
)

#: At most this many images per figure of the per-light grid.
GRID_IMAGES = 16
#: Images side by side in one row of a grid figure (each: target, fit, residual).
GRID_COLUMNS = 2
#: The longest side of a thumbnail, in pixels (larger crops are averaged down in blocks).
THUMBNAIL_PX = 96
#: Pixels of margin around the sphere's bounding box in the thumbnails.
CROP_MARGIN_PX = 3
#: The correlation figure leaves out the per-image exposures beyond this many labels.
MAX_CORRELATION_LABELS = 16
#: At most this many disagreeing single images are listed (the rest are in the JSON).
MAX_DISAGREEING_ROWS = 24
#: The residuals read again may differ from the recorded ones by this much (relative) before
#: the report warns that the capture changed.
RELOAD_TOLERANCE = 1e-6
#: A chain belongs to a fit result when the values of the fit it was sampled from are the
#: result's within this (relative) tolerance.
CHAIN_TOLERANCE = 1e-6

_VERDICTS = {
    "consistent": "the {model} model reproduces the {photographs} within their noise",
    "mismatch": "the {model} model does not reproduce {subject}, whatever its noise: the residual's RMS is "
    "more than {factor:g} times the largest noise the {photographs} allow",
    "undetermined": "the residual lies between the noise floor (background, quantisation) and the largest noise "
    "the {photographs} allow, so whether the {model} model reproduces them cannot be said",
}


# --- the per-light grid ----------------------------------------------------------------------


@dataclass
class LightPanels:
    """The thumbnails of the per-light grid, N images, each cropped to the sphere's bounding
    box (``crop``: first row, end row, first column, end column of the frame) and averaged
    down in blocks of ``factor`` × ``factor`` pixels.

    ``target`` and ``fitted`` (N, h, w, 3) are linear, 0 off the sphere; ``residual`` (N, h, w)
    is fit − target, the mean over R, G and B, at the pixels whose three channels are usable
    (NaN at the others and off the sphere); ``sphere`` (h, w) marks the thumbnail pixels on
    the sphere. ``exposure`` is the one display exposure of every row, ``limit`` the one
    symmetric limit of the residual's colour scale."""

    files: list[str]
    numbers: list[int]
    held_out: list[bool]
    target: np.ndarray
    fitted: np.ndarray
    residual: np.ndarray
    sphere: np.ndarray
    relative_rms: list[float]
    delta_e2000_mean: list[float]
    saturated: list[int]
    exposure: float
    limit: float
    crop: tuple[int, int, int, int]
    factor: int

    @property
    def count(self) -> int:
        return len(self.files)


def _blocks(values: np.ndarray, factor: int, *, nan: bool = False) -> np.ndarray:
    """Mean over blocks of ``factor`` × ``factor`` pixels of (h, w, ...) (h, w multiples of it)."""
    if factor == 1:
        return values
    h, w = values.shape[:2]
    shaped = values.reshape((h // factor, factor, w // factor, factor) + values.shape[2:])
    if not nan:
        return shaped.mean(axis=(1, 3))
    with _warnings.catch_warnings():
        _warnings.simplefilter("ignore", RuntimeWarning)  # a block without a usable pixel: NaN
        return np.nanmean(shaped, axis=(1, 3))


def light_panels(
    parts: Sequence[tuple[CaptureSamples, np.ndarray, Sequence[int], bool]],
    *,
    thumbnail: int = THUMBNAIL_PX,
    margin: int = CROP_MARGIN_PX,
) -> LightPanels:
    """The grid's thumbnails of ``parts``: per part the images (`CaptureSamples`),
    their prediction (L, P, 3), their 1-based numbers in the capture and whether they were
    held out. The rows come in the order of the parts and their images."""
    parts = [part for part in parts if part[0].count]
    if not parts:
        raise ReportError("the capture's result has no image to show")
    height, width = parts[0][0].shape
    rows = np.concatenate([samples.rows for samples, *_ in parts])
    cols = np.concatenate([samples.cols for samples, *_ in parts])
    r0, c0 = max(int(rows.min()) - margin, 0), max(int(cols.min()) - margin, 0)
    r1, c1 = min(int(rows.max()) + margin + 1, height), min(int(cols.max()) + margin + 1, width)
    factor = max(1, math.ceil(max(r1 - r0, c1 - c0) / max(int(thumbnail), 1)))
    # padded to whole blocks (below and right of the frame, if need be)
    ph, pw = math.ceil((r1 - r0) / factor) * factor, math.ceil((c1 - c0) / factor) * factor
    observed_all = np.concatenate([samples.values[samples.usable] for samples, *_ in parts])
    top = float(np.percentile(observed_all, 99)) if observed_all.size else 1.0
    exposure = 1.0 / max(top, 1e-12)

    files: list[str] = []
    numbers: list[int] = []
    held_out: list[bool] = []
    targets, fits, residuals, rms, de, saturated = [], [], [], [], [], []
    sphere = np.zeros((ph, pw), dtype=bool)
    for samples, predicted, part_numbers, held in parts:
        rr, cc = samples.rows - r0, samples.cols - c0
        sphere[rr, cc] = True
        for i in range(samples.count):
            observed, fitted = np.zeros((ph, pw, 3)), np.zeros((ph, pw, 3))
            observed[rr, cc] = samples.values[i]
            fitted[rr, cc] = predicted[i]
            keep = samples.usable[i].all(axis=-1)
            residual = np.full((ph, pw), np.nan)
            residual[rr[keep], cc[keep]] = (predicted[i] - samples.values[i])[keep].mean(axis=-1)
            targets.append(_blocks(observed, factor))
            fits.append(_blocks(fitted, factor))
            residuals.append(_blocks(residual, factor, nan=True))
            one = slice(i, i + 1)
            rms.append(relative_rms(predicted[one], samples.values[one], samples.usable[one]))
            de.append(delta_e_mean(predicted[one], samples.values[one], samples.usable[one]))
            saturated.append(int(samples.saturated[i]))
            files.append(samples.files[i])
            numbers.append(int(part_numbers[i]))
            held_out.append(bool(held))
    residual_stack = np.stack(residuals)
    finite = np.abs(residual_stack[np.isfinite(residual_stack)])
    limit = max(float(np.percentile(finite, 99.5)) if finite.size else 0.0, 1e-12)
    return LightPanels(
        files=files,
        numbers=numbers,
        held_out=held_out,
        target=np.stack(targets),
        fitted=np.stack(fits),
        residual=residual_stack,
        sphere=_blocks(sphere.astype(np.float64), factor) > 0,
        relative_rms=rms,
        delta_e2000_mean=de,
        saturated=saturated,
        exposure=exposure,
        limit=limit,
        crop=(r0, r0 + ph, c0, c0 + pw),
        factor=factor,
    )


def _short(name: str, length: int = 22) -> str:
    name = Path(name).name
    return name if len(name) <= length else name[: length - 1] + "…"


def grid_figure(panels: LightPanels, indices: Sequence[int]) -> bytes:
    """One figure of the per-light grid: for each image of ``indices`` (rows of ``panels``)
    its target, fit and residual (fit − target, mean over RGB; white: off the sphere; grey:
    values not used), labelled with its number, file name and relative RMS, two images side
    by side; one colour scale and one display exposure for all."""
    import matplotlib
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    indices = list(indices)
    columns = min(GRID_COLUMNS, len(indices))
    lines = math.ceil(len(indices) / columns)
    h, w = panels.sphere.shape
    # the layout in inches: panels of about 100 pixels at the figures' 100 dpi
    panel, tall, gap, between, label, side = 1.0, 1.0 * h / w, 0.04, 0.3, 0.2, 0.1
    top, bottom = 0.35, 0.75
    width = 2 * side + columns * (3 * panel + 2 * gap) + (columns - 1) * between
    height = top + lines * (label + tall + 0.06) + bottom
    fig = new_figure(figsize=(width, height))
    cmap = matplotlib.colormaps["RdBu_r"]
    norm = Normalize(-panels.limit, panels.limit)
    for slot, index in enumerate(indices):
        line, column = divmod(slot, columns)
        left = side + column * (3 * panel + 2 * gap + between)
        lower = height - top - (line + 1) * (label + tall + 0.06) + 0.06
        target_ax, fit_ax, residual_ax = (
            fig.add_axes(((left + k * (panel + gap)) / width, lower / height, panel / width, tall / height))
            for k in range(3)
        )
        target_ax.imshow(_display(panels.target[index], panels.exposure), interpolation="nearest")
        fit_ax.imshow(_display(panels.fitted[index], panels.exposure), interpolation="nearest")
        rgba = cmap(norm(np.nan_to_num(panels.residual[index])))
        rgba[~panels.sphere] = (1.0, 1.0, 1.0, 1.0)
        rgba[panels.sphere & ~np.isfinite(panels.residual[index])] = (0.72, 0.72, 0.72, 1.0)
        residual_ax.imshow(rgba, interpolation="nearest")
        held = panels.held_out[index]
        text = (
            f"{panels.numbers[index]}. {_short(panels.files[index])}  rel. RMS {100 * panels.relative_rms[index]:.2f} %"
        )
        target_ax.text(
            0.0,
            1.05,
            text + ("  held out" if held else ""),
            transform=target_ax.transAxes,
            ha="left",
            va="bottom",
            fontsize=7,
            color="#a00000" if held else "black",
            fontweight="bold" if held else "normal",
        )
        for ax in (target_ax, fit_ax, residual_ax):
            ax.set_xticks([])
            ax.set_yticks([])
            if held:
                for spine in ax.spines.values():
                    spine.set_color("#a00000")
                    spine.set_linewidth(1.5)
    fig.text(
        0.5,
        1 - 0.12 / height,
        "each image: target | fit | fit − target (mean over R, G, B)",
        ha="center",
        va="top",
        fontsize=9,
    )
    cax = fig.add_axes((0.25, 0.42 / height, 0.5, 0.1 / height))
    bar = fig.colorbar(ScalarMappable(norm=norm, cmap=cmap), cax=cax, orientation="horizontal")
    bar.ax.tick_params(labelsize=7)
    bar.set_label("fit − target (linear; grey: saturated or under-exposed, not used)", fontsize=7)
    return png_bytes(fig)


# --- the report ------------------------------------------------------------------------------


def _kinds(fit: CaptureFit) -> list[str]:
    return [p.kind for p in fit.params for _ in range(p.size)]


def equivalence_bands(ranges: Any, labels: Sequence[str]) -> dict[str, tuple[float, float]]:
    """A capture's equivalence ranges (``{name: [low, high]}``, a colour or another RGB
    parameter: three pairs) by parameter label (``color_r``), or {} without any."""
    out: dict[str, tuple[float, float]] = {}
    if not isinstance(ranges, dict):
        return out
    for name, value in ranges.items():
        try:
            pairs = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            continue
        if pairs.shape == (2,):
            out[str(name)] = (float(pairs[0]), float(pairs[1]))
        elif pairs.shape == (3, 2):
            for channel, pair in zip("rgb", pairs):
                out[f"{name}_{channel}"] = (float(pair[0]), float(pair[1]))
    return {label: out[label] for label in labels if label in out and all(map(math.isfinite, out[label]))}


def _camera_text(camera: Any) -> str:
    if not isinstance(camera, dict):
        return "?"
    text = str(camera.get("type", "?"))
    if camera.get("focal_px") is not None:
        text += f", focal length {float(camera['focal_px']):.4g} px"
    if camera.get("principal_point") is not None:
        x, y = camera["principal_point"]
        text += f", principal point ({float(x):.1f}, {float(y):.1f})"
    return text


def _circle_text(recorded: Any, samples: CaptureSamples) -> str:
    try:
        circle = Circle.from_dict(recorded)
    except (StraussFitError, TypeError, ValueError, KeyError):
        circle = samples.circle
    return f"{circle.describe()} (from the {circle.source})"


def _sd_text(value: float) -> str:
    return fmt(value, 2) if value > 0 else "0 (on its bound)"


def _numbers(result: dict[str, Any]) -> tuple[list[int], list[int]]:
    """1-based numbers of the fitted and the held-out images."""
    count = int(result.get("images") or 0)
    holdout = (result.get("settings") or {}).get("holdout")
    held = holdout_indices(holdout, count) if holdout is not None else []
    fitted = [i + 1 for i in range(count) if i not in set(held)]
    return fitted, [i + 1 for i in held]


def build_capture_report(
    result: dict[str, Any],
    samples: CaptureSamples,
    fit: CaptureFit,
    *,
    held: tuple[CaptureSamples, np.ndarray] | None = None,
    title: str | None = None,
    equivalence: dict[str, Any] | None = None,
    assets: str = "report_files",
    chain: Chain | None = None,
) -> Report:
    """Assemble the report of a capture's fit from its result (the JSON of ``fit
    --capture``), the images it was fitted to and the fit read back
    (`strauss_fit.fitting.capture_result.reload_capture_fit`), and optionally the held-out
    images with the fit's prediction of them (`strauss_fit.fitting.capture_result.reload_held_out`).
    ``equivalence`` replaces the result's equivalence ranges. ``chain``: a capture's chain
    sampled from this fit (`check_chain_fit`), whose posterior gets a section of its own
    (`_posterior_section`)."""
    if not is_capture_result(result):
        raise ReportError("not a capture's fit result (no images_fitted, circle and settings)")
    posterior = _chain_part(chain, result, fit, samples) if chain is not None else None
    doc = Document(assets)
    model = str(result.get("model", fit.model))
    data: dict[str, Any] = {"labels": list(fit.labels), "model": model}
    capture_paths = _capture_paths(result)
    heading = title or f"strauss-fit capture report: {', '.join(capture_paths) or 'capture'}"
    doc.heading(heading, 1)
    doc.para(f"One {model} material fitted to every photograph of the capture at once. " + generated_by())
    # the grid's numbers first: the warnings say when they differ from the recorded ones
    panels, held_numbers = _grid_panels(result, samples, fit, held)
    _verdict_section(doc, result, samples, fit, model, posterior, data)
    _capture_section(doc, result, samples, held, held_numbers, panels, model, chain)
    _parameters_section(doc, result, fit, equivalence, chain is not None, data)
    _residual_section(doc, result.get("residual") or {})
    grid_rows = _grid_section(doc, panels, held is not None, data)
    _per_image_section(doc, grid_rows)
    _holdout_section(doc, result, samples.count, model, data)
    stability = result.get("stability")
    if isinstance(stability, dict) and isinstance(stability.get("halves"), list):
        _stability_section(doc, stability, data)
    _correlation_section(doc, result, list(fit.labels))
    if chain is not None and posterior is not None:
        _posterior_section(doc, posterior, chain, fit, data)
    return Report(html=doc.html(heading, _STYLE), markdown=doc.markdown(), images=doc.images, assets=assets, data=data)


def _capture_paths(result: dict[str, Any]) -> list[str]:
    """The capture's paths as the result records them (one or several)."""
    paths = result.get("capture") or []
    return [paths] if isinstance(paths, str) else [str(p) for p in paths]


def _grid_panels(
    result: dict[str, Any],
    samples: CaptureSamples,
    fit: CaptureFit,
    held: tuple[CaptureSamples, np.ndarray] | None,
) -> tuple[LightPanels, list[int]]:
    """The per-light grid's thumbnails (the fitted images, then the held-out ones with the
    fit's prediction) and the held-out images' numbers; numbers the result records for
    another count of images than those read are replaced by the images' order."""
    fitted_numbers, held_numbers = _numbers(result)
    if len(fitted_numbers) != samples.count:
        fitted_numbers = list(range(1, samples.count + 1))
    parts: list[tuple[CaptureSamples, np.ndarray, Sequence[int], bool]] = [
        (samples, fit.predicted, fitted_numbers, False)
    ]
    if held is not None:
        held_samples, held_predicted = held
        if len(held_numbers) != held_samples.count:
            held_numbers = list(range(samples.count + 1, samples.count + held_samples.count + 1))
        parts.append((held_samples, held_predicted, held_numbers, True))
    return light_panels(parts), held_numbers


def _verdict_section(
    doc: Document,
    result: dict[str, Any],
    samples: CaptureSamples,
    fit: CaptureFit,
    model: str,
    posterior: _ChainPart | None,
    data: dict[str, Any],
) -> None:
    """The verdict and the warnings: the chain's first when it is not trustworthy, the
    fit's codes and messages, a capture that changed since the fit, the chain's others and
    the fit's notes."""
    residual = result.get("residual") or {}
    fit_warnings = [w for w in result.get("warnings") or [] if isinstance(w, dict)]
    warnings = [f"[{w.get('code', '?')}] {w.get('message', '')}" for w in fit_warnings]
    recorded_rms = residual.get("relative_rms")
    now_rms = relative_rms(fit.predicted, samples.values, samples.usable)
    if isinstance(recorded_rms, (int, float)) and not math.isclose(
        now_rms, recorded_rms, rel_tol=RELOAD_TOLERANCE, abs_tol=1e-12
    ):
        warnings.append(
            f"[capture-changed] the images read now give a relative RMS of {100 * now_rms:.4g} %, the result "
            f"records {100 * recorded_rms:.4g} %: the capture changed since the fit, and the grid shows it as it "
            "is now"
        )
    if posterior is not None:
        warnings = posterior.first + warnings + posterior.later  # an untrustworthy chain first
    warnings += [f"fit: {note}" for note in result.get("notes") or []]
    verdict = residual.get("verdict")
    data.update(verdict=verdict, warnings=warnings, fit_warnings=fit_warnings)
    verdict_and_warnings(
        doc,
        "Verdict and warnings",
        verdict,
        _verdict_text(str(verdict), model, residual, _image_count(result)) if verdict else "",
        warnings,
        "No warnings.",
    )


def _capture_section(
    doc: Document,
    result: dict[str, Any],
    samples: CaptureSamples,
    held: tuple[CaptureSamples, np.ndarray] | None,
    held_numbers: list[int],
    panels: LightPanels,
    model: str,
    chain: Chain | None,
) -> None:
    """The capture in a list: its paths, the images fitted and held out, the sphere's pixels
    and circle, the camera, the model and what was fitted, the exposure, the chain."""
    settings = result.get("settings") or {}
    capture_paths = _capture_paths(result)
    doc.heading("The capture")
    images = int(result.get("images", samples.count + (0 if held is None else held[0].count)))
    facts = [
        ["capture", ", ".join(capture_paths) or "?"],
        ["images", f"{images} ({samples.count} fitted" + (f", {len(held_numbers)} held out)" if held_numbers else ")")],
        [
            "sphere pixels",
            f"{result.get('pixels', len(samples.rows))} ({fmt(result.get('values_used'), 8)} values "
            f"used, {fmt(result.get('saturated_values'), 8)} saturated or under-exposed values left out)",
        ],
        ["sphere", _circle_text(result.get("circle"), samples)],
        ["camera", _camera_text(result.get("camera"))],
        ["model", f"{model}; fitted: {', '.join(result.get('free') or [])}"],
        [
            "exposure",
            str(settings.get("exposure", "?"))
            + ("; white balance fitted" if settings.get("white_balance") else "")
            + ("; ambient light fitted" if settings.get("ambient") else ""),
        ],
    ]
    if held_numbers:
        facts.append(
            [
                "held out",
                ", ".join(f"{n} ({_short(f)})" for n, f in zip(held_numbers, panels.files[samples.count :]))
                or ", ".join(str(n) for n in held_numbers),
            ]
        )
    if chain is not None:
        facts.append(
            ["chain", f"{chain.path} ({chain.chain.shape[0]} steps × {chain.chain.shape[1]} walkers; see Posterior)"]
        )
    doc.bullets([f"{name}: {text}" for name, text in facts])


def _parameters_section(
    doc: Document,
    result: dict[str, Any],
    fit: CaptureFit,
    equivalence: dict[str, Any] | None,
    with_chain: bool,
    data: dict[str, Any],
) -> None:
    """The parameter table (value, both ±, the equivalence range when there is one), one
    sentence per kind of interval, the figure of the ranges and the parameters held."""
    labels = list(fit.labels)
    settings = result.get("settings") or {}
    values = np.asarray(fit.physical, dtype=np.float64)
    sd_cluster = np.sqrt(np.maximum(np.diag(fit.clustered), 0.0))
    sd_laplace = np.sqrt(np.maximum(np.diag(fit.laplace), 0.0))
    bands = equivalence_bands(result.get("equivalence") if equivalence is None else equivalence, labels)
    threshold = float(result.get("equivalence_delta_e") or settings.get("equivalence_delta_e") or 1.0)
    doc.heading("Parameters")
    header = ["parameter", "value", "± (image-cluster sandwich)", "± (Laplace)"]
    if bands:
        header.append(f"looks the same (ΔE ≤ {threshold:g})")
    rows = []
    for k, label in enumerate(labels):
        row = [label, fmt(values[k]), _sd_text(sd_cluster[k]), _sd_text(sd_laplace[k])]
        if bands:
            row.append(range_text(*bands[label]) if label in bands else "–")
        rows.append(row)
    doc.table(header, rows)
    meanings = _interval_meanings(result, bool(bands), threshold)
    data["intervals"] = {"bands": bands, "threshold": threshold, "meanings": meanings}
    doc.bullets(meanings)
    if with_chain:
        doc.para("The chain's posterior of these values, against the fit and its ±, is in the section Posterior below.")
    if bands:
        _intervals_image(doc, fit, values, sd_cluster, bands, threshold)
    held_parameters_recorded = result.get("held") or {}
    if isinstance(held_parameters_recorded, dict) and held_parameters_recorded:
        held_parameters(doc, held_parameters_recorded)


def _interval_meanings(result: dict[str, Any], bands: bool, threshold: float) -> list[str]:
    """One sentence per kind of interval of the parameter table: the image-cluster sandwich
    (in the words the result records), the Laplace ±, the equivalence range (with
    ``bands``), and what 0 means."""
    method = result.get("uncertainty_method") or {}
    meaning = str(method.get("meaning") or "how far the fitted values would move with other photographs of this kind")
    meanings = [
        f"± (image-cluster sandwich): {meaning} — valid whether or not the model reproduces the photographs, but "
        "then an interval for the model's best approximation of this capture, not for the material.",
        "± (Laplace): σ̂·sqrt((JᵀJ)⁻¹) with σ̂² = RSS/(N − P), every value's residual taken as independent noise — "
        "valid only if the model reproduces the photographs; a misfit correlated over the sphere makes it too "
        "narrow.",
    ]
    if bands:
        meanings.append(
            "Looks the same (perceptual equivalence): every value in the range, the other values (exposures, white "
            f"balance and ambient light included) re-fitted, predicts the capture within a mean CIEDE2000 of "
            f"{threshold:g} of the fit — a difference nobody sees. It says what the photographs can show, not how "
            "precisely they pin the value."
        )
    meanings.append("A value on its bound has 0 in both ± columns.")
    return meanings


def _intervals_image(
    doc: Document,
    fit: CaptureFit,
    values: np.ndarray,
    sd_cluster: np.ndarray,
    bands: dict[str, tuple[float, float]],
    threshold: float,
) -> None:
    """The figure of the parameters with an equivalence range: the range against the
    sandwich's ±1.96σ, each over [0, 1] for a unit parameter, else over both with a margin."""
    labels = list(fit.labels)
    shown = [k for k, label in enumerate(labels) if label in bands]
    kinds = _kinds(fit)
    lower, upper = [], []
    for k in shown:
        low, high = bands[labels[k]]
        if kinds[k] == "unit":
            lower.append(0.0)
            upper.append(1.0)
        else:
            lo = min(low, values[k] - 1.96 * sd_cluster[k])
            hi = max(high, values[k] + 1.96 * sd_cluster[k])
            pad = 0.05 * max(hi - lo, 1e-6 * max(abs(values[k]), 1.0))
            lower.append(lo - pad)
            upper.append(hi + pad)
    doc.image(
        "intervals.png",
        intervals_figure(
            [labels[k] for k in shown],
            values[shown],
            sd_cluster[shown],
            {labels[k]: bands[labels[k]] for k in shown},
            np.array(lower),
            np.array(upper),
            "image-cluster sandwich",
            threshold,
        ),
        "per parameter: the range that looks the same (light), the image-cluster sandwich ±1.96σ (dark), the fit",
    )


def _residual_section(doc: Document, residual: dict[str, Any]) -> None:
    """The residual in numbers against the noise, and by region when the result has them."""
    doc.heading("Residual")
    doc.table(["quantity", "value"], _residual_rows(residual))
    regions = residual.get("regions") or {}
    if not (isinstance(regions, dict) and regions):
        return
    doc.table(
        ["region", "values", "relative RMS", "mean (photograph − fit)", "median photograph", "median fit"],
        [
            [
                str(name),
                str(entry.get("values", "–")),
                _percent(entry.get("relative_rms")),
                fmt(entry.get("mean_residual"), 3),
                fmt(entry.get("observed_median"), 3),
                fmt(entry.get("predicted_median"), 3),
            ]
            for name, entry in regions.items()
            if isinstance(entry, dict)
        ],
    )
    doc.para(
        "Regions: highlight, within about 25° of a light's mirror direction; body, the rest of the lit side; "
        "unlit, where no stated light reaches."
    )


def _grid_section(doc: Document, panels: LightPanels, with_held: bool, data: dict[str, Any]) -> list[dict[str, Any]]:
    """The per-light grid, `GRID_IMAGES` images a figure, and what its rows show;
    returns one row of numbers per image (also in ``data``)."""
    doc.heading("Target, fit and residual per light")
    figures = []
    for page, start in enumerate(range(0, panels.count, GRID_IMAGES)):
        indices = list(range(start, min(start + GRID_IMAGES, panels.count)))
        name = f"lights-{page + 1}.png"
        figures.append(name)
        first, last = indices[0] + 1, indices[-1] + 1
        doc.image(
            name,
            grid_figure(panels, indices),
            f"rows {first}–{last} of {panels.count}: target | fit | fit − target (mean over R, G, B; one colour "
            f"scale ±{panels.limit:.3g} and one display exposure for every row; grey: values not used)"
            + (
                "; framed in red and marked held out: images the fit did not see, predicted"
                if any(panels.held_out[i] for i in indices)
                else ""
            ),
        )
    doc.para(
        f"Each row is one photograph, cropped to the sphere ({panels.crop[1] - panels.crop[0]} × "
        f"{panels.crop[3] - panels.crop[2]} px"
        + (f", averaged over blocks of {panels.factor} × {panels.factor} px" if panels.factor > 1 else "")
        + "), labelled with its number in the capture, its file and its relative RMS √(Σ(Î − I)²/ΣI²)."
        + (" The held-out images come last: the fit never saw them, and its prediction is shown." if with_held else "")
    )
    grid_rows = [
        {
            "number": panels.numbers[i],
            "file": panels.files[i],
            "held_out": panels.held_out[i],
            "relative_rms": panels.relative_rms[i],
            "delta_e2000_mean": panels.delta_e2000_mean[i],
            "saturated_pixels": panels.saturated[i],
        }
        for i in range(panels.count)
    ]
    data["grid"] = {
        "rows": grid_rows,
        "figures": figures,
        "exposure": panels.exposure,
        "limit": panels.limit,
        "crop": panels.crop,
        "factor": panels.factor,
        "residual": panels.residual,
    }
    return grid_rows


def _per_image_section(doc: Document, grid_rows: list[dict[str, Any]]) -> None:
    """The per-image table: each image's relative RMS, mean CIEDE2000, saturated pixels and
    whether it was held out."""
    doc.heading("Per image")
    doc.table(
        ["#", "file", "relative RMS", "mean CIEDE2000", "saturated pixels", "held out"],
        [
            [
                str(row["number"]),
                Path(row["file"]).name,
                _percent(row["relative_rms"]),
                fmt(row["delta_e2000_mean"], 3),
                str(row["saturated_pixels"]),
                "held out" if row["held_out"] else "",
            ]
            for row in grid_rows
        ],
    )


def _holdout_section(
    doc: Document, result: dict[str, Any], fitted_images: int, model: str, data: dict[str, Any]
) -> None:
    """When the result compared models on held-out images: each model's error on the images
    fitted and on those held out (nothing without such a comparison)."""
    holdout = result.get("holdout")
    if not (isinstance(holdout, dict) and isinstance(holdout.get("models"), dict)):
        return
    residual = result.get("residual") or {}
    doc.heading("Held-out images: the models compared")
    comparison = []
    for name, entry in holdout["models"].items():
        if not isinstance(entry, dict):
            continue
        on_fitted = residual.get("relative_rms") if name == model else (entry.get("fit") or {}).get("relative_rms")
        comparison.append(
            [
                str(name),
                _percent(on_fitted),
                _percent(entry.get("relative_rms")),
                fmt(entry.get("delta_e2000_mean"), 3),
            ]
        )
    doc.table(
        ["model", "relative RMS, fitted images", "relative RMS, held out", "mean CIEDE2000, held out"], comparison
    )
    doc.para(
        f"Each model is fitted to the same {fitted_images} images and predicts the "
        f"{len(holdout.get('held_out') or [])} held out: a model that predicts unseen lights better describes "
        "the material better, whatever its fit to the images it saw."
    )
    data["holdout"] = {"rows": comparison}


def _correlation_section(doc: Document, result: dict[str, Any], labels: list[str]) -> None:
    """The correlation matrix of the image-cluster sandwich (the per-image exposures left
    out beyond `MAX_CORRELATION_LABELS` labels), and as a table when it is small."""
    doc.heading("Correlations")
    corr = np.asarray((result.get("correlation") or {}).get("matrix", np.eye(len(labels))), dtype=np.float64)
    if corr.shape != (len(labels), len(labels)):
        corr = np.eye(len(labels))
    keep = _shown(labels)
    shown_labels = [labels[k] for k in keep]
    small = corr[np.ix_(keep, keep)]
    left_out = len(labels) - len(keep)
    doc.image(
        "correlation.png",
        correlation_figure(shown_labels, small, "correlation (image-cluster sandwich)"),
        "correlation matrix of the image-cluster sandwich"
        + (f" (the {left_out} per-image exposures left out)" if left_out else ""),
    )
    if len(shown_labels) <= 12:
        correlation_table(doc, shown_labels, small)
    doc.para("Correlation near ±1: the two values trade off, and the photographs constrain only a combination of them.")


def _shown(labels: Sequence[str]) -> list[int]:
    """The parameters a figure shows: all, or without the per-image exposures beyond
    `MAX_CORRELATION_LABELS` labels."""
    if len(labels) <= MAX_CORRELATION_LABELS:
        return list(range(len(labels)))
    return [k for k, label in enumerate(labels) if not label.startswith("image_exposure_")]


# --- the posterior -----------------------------------------------------------------------------


def _result_values(result: dict[str, Any]) -> dict[str, np.ndarray] | None:
    """A capture's result's values by name (each a vector), or None if they are not numbers."""
    values = result.get("values") or {name: result[name] for name in result.get("free") or [] if name in result}
    try:
        return {str(name): np.atleast_1d(np.asarray(v, dtype=np.float64)) for name, v in dict(values).items()}
    except (TypeError, ValueError):
        return None


def check_chain_fit(
    chain: Chain, result: dict[str, Any], fit: CaptureFit | None = None, *, source: str = "the fit result"
) -> None:
    """Refuse, in one line, a chain that was not sampled from the capture's fit ``result``
    (called ``source`` in the message): it must be a capture's chain whose recorded fit has
    the result's model, free parameters (and, with ``fit``, its labels) and values within
    `CHAIN_TOLERANCE`."""
    if not is_capture_chain(chain.meta):
        raise ReportError(
            f"{chain.path} is the chain of a single image's fit, not of a capture's: give a capture's chain "
            "('strauss-fit sample --fit' of a capture's result)"
        )
    own = chain.meta.get("fit") if isinstance(chain.meta.get("fit"), dict) else {}
    advice = "give the fit result it was sampled from, or the chain alone (it holds its fit)"
    if own.get("model") != result.get("model"):
        raise ReportError(
            f"the chain {chain.path} was sampled from a fit of the {own.get('model')} model, {source} is of the "
            f"{result.get('model')} model: {advice}"
        )
    free, own_free = list(result.get("free") or []), list(own.get("free") or [])
    labels = list(fit.labels) if fit is not None else None
    if own_free != free or (labels is not None and chain.labels != labels):
        raise ReportError(
            f"the chain {chain.path} samples {', '.join(chain.labels)} but {source} frees "
            f"{', '.join(labels or free)}: they belong to different fits ({advice})"
        )
    values, own_values = _result_values(result), _result_values(own)
    if values is None or own_values is None:
        raise ReportError(f"the chain {chain.path} or {source} records values that are not numbers")
    for name in sorted(set(values) | set(own_values)):
        a, b = own_values.get(name), values.get(name)
        if a is None or b is None or a.shape != b.shape or not np.allclose(a, b, rtol=CHAIN_TOLERANCE, atol=1e-12):

            def text(v: np.ndarray | None) -> str:
                return "absent" if v is None else ", ".join(f"{x:.6g}" for x in v)

            raise ReportError(
                f"the chain {chain.path} was sampled from another fit than {source}: its fit's {name} is "
                f"{text(a)}, not {text(b)} ({advice})"
            )


@dataclass
class _ChainPart:
    """What the report says about a chain: its diagnostics, `capture_chain_summary`,
    the draws after burn-in (as adjusted, at most `MAX_PLOT_SAMPLES`) and how many the
    adjustment dropped, and the warnings that go first and those after the fit's."""

    diagnostics: Diagnostics
    summary: dict[str, Any]
    draws: np.ndarray
    dropped: int
    first: list[str]
    later: list[str]


def _chain_part(chain: Chain, result: dict[str, Any], fit: CaptureFit, samples: CaptureSamples) -> _ChainPart:
    check_chain_fit(chain, result, fit)
    diagnostics = chain.diagnostics()
    summary = capture_chain_summary(chain)
    draws, dropped = chain.adjusted(diagnostics.burn_in)
    if draws.shape[0] > MAX_PLOT_SAMPLES:
        draws = draws[np.random.default_rng(0).choice(draws.shape[0], MAX_PLOT_SAMPLES, replace=False)]
    first = []
    if not diagnostics.trustworthy:
        first.append(untrustworthy_chain(diagnostics.reasons))
    later = []
    digest = chain.meta.get("data_sha256")
    if isinstance(digest, str) and digest != data_digest(samples):
        later.append(
            "The chain was sampled from other photographs than those read now (their usable values differ): its "
            "posterior is of the capture as it was then."
        )
    circle = _circle_warning(chain.meta, _fit_laplace(chain.meta, chain.labels))
    if circle:
        later.append(circle[0].upper() + circle[1:] + ".")
    return _ChainPart(diagnostics, summary, draws, int(dropped), first, later)


def _adjustment_text(chain: Chain, dropped: int) -> str:
    info = chain.adjustment
    method = info.get("method", "none")
    reason = str(info.get("reason") or "").rstrip(".")
    why = f" Why: {reason}." if reason else ""
    if method == "affine":
        return (
            "The draws are adjusted (affine): mapped to the fit's image-cluster sandwich, θ' = θ̂ + A(θ − θ̂) with A "
            "chosen so that their covariance is the sandwich's, keeping the posterior's shape; "
            f"{dropped} draws that left the prior were dropped.{why}"
        )
    if method == "temperature":
        factor = info.get("temperature")
        t = f", T = {factor:.3g}" if isinstance(factor, (int, float)) else ""
        return (
            f"The draws are tempered: sampled with the noise σ widened by √T{t}, so that the posterior is about as "
            f"wide as the fit's image-cluster sandwich.{why}"
        )
    return (
        "The draws are not adjusted: they are the Gaussian likelihood's posterior, every usable value's noise "
        "independent and the sphere's circle taken as detected, set against the fit's Laplace ± without the "
        "circle's share. When the model does not reproduce the photographs the misfit is correlated over each "
        f"image, and this posterior is narrower than the image-cluster sandwich, the ± to quote then.{why}"
    )


def _posterior_section(doc: Document, part: _ChainPart, chain: Chain, fit: CaptureFit, data: dict[str, Any]) -> None:
    """The posterior of a capture's chain: per parameter the fit, its image-cluster ±, the
    posterior's median and 16/84 % and 2.5/97.5 % percentiles and the prior; what the draws
    are (adjusted or not, σ and the likelihood); the corner plot; the sampler's diagnostics."""
    labels = list(fit.labels)
    summary = part.summary
    method = summary.get("adjustment", "none")
    name = {"affine": "posterior, adjusted", "temperature": "posterior, tempered"}.get(method, "posterior")
    values = np.asarray(fit.physical, dtype=np.float64)
    doc.heading("Posterior")
    rows = _posterior_table(doc, part, chain, fit, name)
    meanings = _posterior_meanings(part, chain)
    doc.bullets(meanings)
    keep = _shown(labels)
    left_out = len(labels) - len(keep)
    note = f" (the {left_out} per-image exposures left out)" if left_out else ""
    doc.image(
        "corner.png",
        corner_figure(
            part.draws[:, keep], [labels[k] for k in keep], values[keep], f"{name} (orange: least-squares fit)"
        ),
        f"{name}: the draws after burn-in; dashed: 16, 50 and 84 % quantiles; orange: the least-squares fit" + note,
    )
    doc.heading("Sampler diagnostics", 3)
    sampler_diagnostics(
        doc,
        chain,
        part.diagnostics,
        shown=keep,
        note=note + ("; the draws as sampled, before the adjustment" if method == "affine" else ""),
    )
    data["posterior"] = rows
    data["diagnostics"] = part.diagnostics.as_dict()
    data["chain"] = {
        "path": chain.path,
        "adjustment": method,
        "dropped": part.dropped,
        "sigma": summary.get("sigma"),
        "sigma_source": chain.meta.get("sigma_source"),
        "likelihood": summary.get("likelihood"),
        "count": summary["count"],
        "burn_in": summary["burn_in"],
        "trustworthy": part.diagnostics.trustworthy,
        "meanings": meanings,
    }


def _posterior_table(doc: Document, part: _ChainPart, chain: Chain, fit: CaptureFit, name: str) -> list[dict[str, Any]]:
    """The table of the fit against the posterior ``name``: value, image-cluster ±, the
    posterior's median and percentiles and the prior's box per parameter; returns the same
    numbers as one row per parameter for the report's data."""
    values = np.asarray(fit.physical, dtype=np.float64)
    sd_cluster = np.sqrt(np.maximum(np.diag(fit.clustered), 0.0))
    prior = chain.meta.get("prior") or {}
    rows, cells = [], []
    for k, label in enumerate(fit.labels):
        p = part.summary["parameters"][label]
        box = prior.get(label)
        rows.append(
            {
                "label": label,
                "value": float(values[k]),
                "sd_cluster": float(sd_cluster[k]),
                **{key: float(p[key]) for key in ("median", "p16", "p84", "p2.5", "p97.5", "mean", "sd")},
                "prior": [float(v) for v in box] if isinstance(box, list) else None,
            }
        )
        cells.append(
            [label, fmt(values[k]), _sd_text(sd_cluster[k])]
            + posterior_cells(p)
            + [prior_text(box[0], box[1]) if isinstance(box, list) else "–"]
        )
    doc.table(["parameter", "fit", "± (image-cluster sandwich)"] + posterior_header(name), cells)
    return rows


def _posterior_meanings(part: _ChainPart, chain: Chain) -> list[str]:
    """What the posterior's numbers are: the draws they come from and whether the chain is
    trustworthy, the likelihood and prior, and how the draws were adjusted."""
    summary, diagnostics = part.summary, part.diagnostics
    sigma = summary.get("sigma")
    sigma_text = f"σ = {sigma:.3g}" if isinstance(sigma, (int, float)) else "σ = ?"
    source = chain.meta.get("sigma_source")
    kept = diagnostics.steps - diagnostics.burn_in
    verdict = "trustworthy" if diagnostics.trustworthy else "NOT trustworthy (see the warnings)"
    return [
        f"Median and percentiles: of the {summary['count']} draws of the emcee chain after its burn-in "
        f"({diagnostics.walkers} walkers × {kept} steps, the first {diagnostics.burn_in} discarded); 16–84 % is the "
        f"central 68 % interval, 2.5–97.5 % the central 95 %. The chain is {verdict}.",
        f"Likelihood: Gaussian noise of {sigma_text} on every usable value"
        + (f" ({source})" if source else "")
        + f"; evaluated over {summary.get('likelihood') or '?'}. Prior: uniform over the box of the last column.",
        _adjustment_text(chain, part.dropped),
    ]


def _stability_section(doc: Document, stability: dict[str, Any], data: dict[str, Any]) -> None:
    """Two halves of the images against each other's equivalence ranges, and the single
    images that disagree with the joint fit, with the reasons the fit gave."""
    doc.heading("Stability")
    agree = stability.get("agree") or {}
    rows = []
    for half in stability["halves"]:
        if not isinstance(half, dict):
            continue
        values, ranges = half.get("values") or {}, half.get("equivalence") or {}
        for name in agree:
            band = ranges.get(name)
            rows.append(
                [
                    f"{half.get('half', '?')} ({len(half.get('images') or [])} images)",
                    str(name),
                    fmt(values.get(name)),
                    range_text(band[0], band[1]) if isinstance(band, list) and len(band) == 2 else "–",
                ]
            )
    doc.table(["half", "parameter", "value", "looks the same"], rows)
    verdicts = ", ".join(f"{name} {'agrees' if ok else 'differs'}" for name, ok in agree.items())
    doc.para(
        f"Two disjoint halves of the images (odd and even), each fitted alone: {verdicts or 'nothing compared'}. "
        "A parameter agrees when each half's value lies within the other half's range of values that look the same "
        f"(mean CIEDE2000 ≤ {fmt(stability.get('delta_e'), 3)}).",
        css="ok" if stability.get("stable") else "bad",
    )
    single = stability.get("single_images")
    if isinstance(single, dict) and isinstance(single.get("fits"), list):
        fits = single["fits"]
        disagreeing = [row for row in fits if isinstance(row, dict) and row.get("disagrees")]
        doc.para(
            f"Each image fitted alone: {len(disagreeing)} of {len(fits)} disagree with the joint fit "
            f"({single.get('rule', '')})."
        )
        if disagreeing:
            doc.table(
                ["image", "disagrees on", "why"],
                [
                    [
                        Path(str(row.get("file", "?"))).name,
                        ", ".join(str(v) for v in row.get("disagrees") or []),
                        "; ".join(str(v) for v in row.get("reasons") or []),
                    ]
                    for row in disagreeing[:MAX_DISAGREEING_ROWS]
                ],
            )
            if len(disagreeing) > MAX_DISAGREEING_ROWS:
                doc.para(f"… and {len(disagreeing) - MAX_DISAGREEING_ROWS} more (all in the result's JSON).")
    data["stability"] = {"rows": rows, "stable": bool(stability.get("stable"))}


def _percent(value: Any) -> str:
    if not isinstance(value, (int, float)) or not math.isfinite(value):
        return "–"
    return f"{100 * value:.3g} %"


def _image_count(result: dict[str, Any]) -> int:
    """How many images the fit used (a result without the count: a capture's several)."""
    images = result.get("images")
    return images if isinstance(images, int) and not isinstance(images, bool) else 2


def _verdict_text(verdict: str, model: str, residual: dict[str, Any], images: int = 2) -> str:
    # one target fitted with --model is one image of a scene, not a capture's photographs
    words = (
        {"subject": "this capture", "photographs": "photographs"}
        if images > 1
        else {"subject": "this image", "photographs": "image's values"}
    )
    meaning = _VERDICTS.get(verdict, "").format(model=model, factor=BOUND_FACTOR, **words)
    against = []
    up, low = residual.get("chi2_per_dof_at_bound"), residual.get("chi2_per_dof_at_floor")
    if isinstance(up, (int, float)):
        against.append(f"the residual's RMS is {math.sqrt(max(up, 0.0)):.3g} times the noise bound")
    if isinstance(low, (int, float)):
        against.append(f"{math.sqrt(max(low, 0.0)):.3g} times the noise floor")
    return (
        f"Verdict: {verdict}" + (f" ({', '.join(against)})" if against else "") + (f": {meaning}." if meaning else ".")
    )


def _residual_rows(residual: dict[str, Any]) -> list[list[str]]:
    rows = [
        ["relative RMS √(Σ(Î − I)²/ΣI²)", _percent(residual.get("relative_rms"))],
        ["RMS (linear)", fmt(residual.get("rms"), 3)],
        ["largest |residual|", fmt(residual.get("max_abs"), 3)],
        ["mean CIEDE2000", fmt(residual.get("delta_e2000_mean"), 3)],
    ]
    floor = residual.get("noise_floor")
    if isinstance(floor, list) and floor:
        rows.append(
            [
                "noise floor (R, G, B)",
                ", ".join(fmt(v, 3) for v in floor) + f" (from {residual.get('noise_floor_source', '?')})",
            ]
        )
    up, low = residual.get("chi2_per_dof_at_bound"), residual.get("chi2_per_dof_at_floor")
    if isinstance(up, (int, float)):
        rows.append(
            [
                "RMS / noise bound",
                f"{math.sqrt(max(up, 0.0)):.3g} (the bound: the largest noise the photographs allow; a mismatch above "
                f"{BOUND_FACTOR:g})",
            ]
        )
    if isinstance(low, (int, float)):
        rows.append(["RMS / noise floor", f"{math.sqrt(max(low, 0.0)):.3g}"])
    rows.append(["verdict", str(residual.get("verdict", "–"))])
    return rows


# --- from files -------------------------------------------------------------------------------


def _existing(path: str | None, bases: Sequence[Path], recorder: str, tried: str, what: str, option: str) -> str | None:
    """A recorded ``path`` as written if it exists, else relative to the first of ``bases``
    where it does; a path found nowhere is a one-line error naming it and ``option``."""
    if path is None:
        return None
    for base in bases:
        found = recorded_path(path, base)
        if found is not None and Path(found).exists():
            return found
    raise ReportError(
        f"{recorder} records the {what} {path}, which no longer exists (tried from here and from {tried}): "
        f"give {option} explicitly"
    )


def open_recorded_capture(
    result: dict[str, Any],
    fit_path: str | Path,
    *,
    capture: Sequence[str | Path] | None = None,
    lights: str | Path | None = None,
    mask: str | Path | None = None,
    chain: str | Path | None = None,
) -> Capture:
    """The capture a capture's result records (its paths as written, else relative to the
    folder of ``fit_path``, the result's JSON), each of ``capture`` (paths), ``lights`` and
    ``mask`` replacing the recorded one when given; the result's recorded encoding, if any,
    replaces the capture's (as `strauss_fit.fitting.capture_result.reload_capture_fit`
    reads it). With ``chain`` (the path of a capture's chain, whose metadata holds
    ``result``), ``fit_path`` is the folder the recorded paths are relative to (the chain's
    ``fit_base``), then the chain's own folder. A recorded path found nowhere is a one-line
    error naming it and the option to give instead."""
    if chain is None:
        bases = [Path(fit_path).parent]
        recorder, tried = f"the fit result {fit_path}", "the result's folder"
    else:
        bases = [Path(fit_path), Path(chain).parent]
        recorder = f"the fit result the chain {chain} was sampled from"
        tried = f"that result's folder {fit_path} and the chain's folder"
    if capture:
        paths = [str(p) for p in capture]
    else:
        recorded = result.get("capture")
        if not recorded:
            raise ReportError(f"{recorder} records no capture: give --capture")
        recorded = [recorded] if isinstance(recorded, str) else list(recorded)
        paths = [str(_existing(str(p), bases, recorder, tried, "capture", "--capture")) for p in recorded]
    lights_path = (
        str(lights) if lights else _existing(result.get("lights"), bases, recorder, tried, "lights file", "--lights")
    )
    mask_path = str(mask) if mask else _existing(result.get("mask"), bases, recorder, tried, "mask", "--mask")
    return open_capture(paths, lights_path, mask_path, result.get("encoding"))


def capture_report_from_files(
    fit_json_path: str | Path | None,
    output_html: str | Path,
    *,
    chain: str | Path | None = None,
    capture: Capture | Sequence[str | Path] | None = None,
    lights: str | Path | None = None,
    mask: str | Path | None = None,
    title: str | None = None,
    force: bool = False,
) -> tuple[Report, list[Path]]:
    """Build the report of a capture's fit result (the path of its JSON), of a capture's
    chain (``chain``, of ``strauss-fit sample --fit``; without a fit result, the fit its
    metadata holds) or of both, and write it to ``output_html`` (.html; the Markdown and the
    PNG folder beside it, all or none). The capture is read again from the paths the result
    records (`open_recorded_capture`; a chain's relative to the folder of the result
    it was sampled from) unless ``capture`` (a `strauss_fit.capture.Capture` or
    paths) is given. A chain sampled from another fit than ``fit_json_path`` is a one-line
    error (`check_chain_fit`). Returns the report and the files written."""
    out = Path(output_html)
    if fit_json_path is None and chain is None:
        raise ReportError("give a capture's fit result (--fit RESULT.json), its chain (--chain CHAIN.h5), or both")
    check_html_name(output_html)
    loaded = load_chain(chain, required=True) if chain is not None else None
    if loaded is not None and not is_capture_chain(loaded.meta):
        raise ReportError(
            f"{chain} is the chain of a single image's fit, not of a capture's: give a capture's chain "
            "('strauss-fit sample --fit' of a capture's result)"
        )
    if loaded is not None:
        check_capture_chain(loaded.meta, chain)
    if fit_json_path is not None:
        result = read_json(fit_json_path, "fit result")
        if not is_capture_result(result):
            raise ReportError(f"{fit_json_path} is not a capture's fit result (no images_fitted, circle and settings)")
        check_capture_result(result, f"the fit result {fit_json_path}")
        if loaded is not None:
            check_chain_fit(loaded, result, source=f"the fit result {fit_json_path}")
    else:  # the chain alone (given: see above)
        result = loaded.meta["fit"]
        if not is_capture_result(result):
            raise ReportError(f"the chain {chain} holds no capture's fit result (its metadata's 'fit' is damaged)")
        check_capture_result(result, f"the fit result in the chain {chain}")
    pages = max(1, math.ceil(int(result.get("images") or 0) / GRID_IMAGES))
    names = [f"lights-{k + 1}.png" for k in range(pages)] + ["intervals.png", "correlation.png"]
    inputs = {"fit": fit_json_path, "chain": chain, "lights": lights, "mask": mask}
    if capture is not None and not isinstance(capture, Capture):
        paths = [capture] if isinstance(capture, (str, Path)) else list(capture)
        inputs.update({f"capture {path}": path for path in paths})
    check_report_outputs(out, force, names + (["corner.png", "trace.png"] if loaded is not None else []), inputs)
    scene_based = bool(result.get("scene") and result.get("target") and not result.get("capture") and not capture)
    if scene_based:  # one target and its scene (fit --model): read back from them
        base = Path(fit_json_path).parent if fit_json_path is not None else loaded.meta.get("fit_base")
        samples, fit = reload_capture_fit(result, base=base)
    elif fit_json_path is not None:
        if not isinstance(capture, Capture):
            capture = open_recorded_capture(result, fit_json_path, capture=capture, lights=lights, mask=mask)
        samples, fit = reload_capture_fit(result, capture=capture)
    else:
        if not isinstance(capture, Capture):
            base = loaded.meta.get("fit_base") or Path(chain).parent
            capture = open_recorded_capture(result, base, capture=capture, lights=lights, mask=mask, chain=chain)
        samples, fit = reload_chain_capture(loaded.meta, capture)
    held = None if scene_based else reload_held_out(result, fit, capture)
    report = build_capture_report(
        result, samples, fit, held=held, title=title, assets=f"{out.stem}_files", chain=loaded
    )
    return report, write_report(report, out, force=force, inputs=inputs)
