"""What a person reads about a fit: the verdict and table printed after it, the comparison
image, and one row of a batch's ``summary.csv``.

All three read a fit result's JSON (`strauss_fit.FitResult.to_json`), so that the
command line, a notebook and a batch print the same thing.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..models.material import PARAMETER_NAMES, SCALAR_NAMES

#: Columns of a batch's ``summary.csv`` (see docs/formats.md).
SUMMARY_COLUMNS = (
    "target",
    "status",
    "error",
    "verdict",
    "chi2_per_dof",
    "noise_source",
    *(f"color_{channel}" for channel in "rgb"),
    *SCALAR_NAMES,
    "exposure",
    *(f"sd_color_{channel}" for channel in "rgb"),
    *(f"sd_{name}" for name in SCALAR_NAMES),
    "sd_exposure",
    "free",
    "rms",
    "delta_e2000_mean",
    "delta_e2000_p95",
    "solver_status",
    "warnings",
    "result",
)


#: Where the noise came from, as the verdict line says it (``residual.noise_source``).
_NOISE_FROM = {"given": "noise as given", "sensor": "noise from the sensor", "image": "noise estimated from the image"}


def verdict_lines(result: dict[str, Any]) -> list[str]:
    """The verdict (does the model reproduce the target?) and the warnings, one per line."""
    residual = result.get("residual", {})
    verdict = residual.get("verdict")
    lines = []
    if verdict == "consistent":
        lines.append(
            f"verdict: the model reproduces the target within its noise (χ²/dof {residual['chi2_per_dof']:.3g}, "
            f"expected 1 ± {residual['chi2_expected_sd']:.2g}; {_noise_from(residual)})"
        )
    elif verdict == "mismatch" and residual.get("chi2_per_dof") is None and residual.get("one_sided"):
        lines.append(f"verdict: the Strauss model CANNOT reproduce this target ({_one_sided_reason(residual)})")
    elif verdict == "mismatch":
        lines.append(
            f"verdict: the Strauss model CANNOT reproduce this target (χ²/dof {residual['chi2_per_dof']:.4g}, "
            f"expected 1 ± {residual['chi2_expected_sd']:.2g}; {_noise_from(residual)})"
        )
    elif verdict == "undetermined":
        lines.append("verdict: undetermined — the target's noise is unknown (give it with --noise)")
    for warning in result.get("warnings", []):
        lines.append(f"warning [{warning['code']}]: {warning['message']}")
    return lines


def _one_sided_reason(residual: dict[str, Any]) -> str:
    """Why a target of unknown noise is a mismatch, in one parenthesis: the verdict is
    one-sided, against the largest noise the image can hold (``residual.one_sided``)."""
    test = residual["one_sided"]
    why = " and ".join(
        text
        for text, fired in (("too large", test.get("too_large")), ("too structured", test.get("too_structured")))
        if fired
    )
    bound = ", ".join(f"{v:.2g}" for v in residual.get("noise_bound") or [])
    return (
        f"one-sided, the noise being unknown: the residual is {why or 'too large'} for any noise up to the "
        f"largest the image can hold, {bound}; χ²/dof {residual['chi2_per_dof_at_bound']:.4g} at that noise"
    )


def _noise_from(residual: dict[str, Any]) -> str:
    source = residual.get("noise_source")
    return _NOISE_FROM.get(source, f"noise from the {source}")


def _uncertainty_header(result: dict[str, Any]) -> str:
    method = result.get("uncertainty_method", {})
    if method.get("name") == "noise sandwich":
        return "± (noise)"
    return "± (if the model is right)"


def format_fit_table(result: dict[str, Any]) -> str:
    """The verdict, then one row per parameter (value, deviation, equivalence range when
    computed, status), then the residual and the solver."""
    header = ["parameter", "value", _uncertainty_header(result), "status"]
    equivalence = result.get("equivalence") or {}
    if equivalence:
        header.insert(3, "looks the same from-to")
    rows = [tuple(header)]
    uncertainty = result.get("uncertainty", {})
    lights = result.get("lights", {})
    names = (*PARAMETER_NAMES, "exposure", *lights)
    for name in names:
        value = result.get(name, lights.get(name))
        if value is None or (name not in result["free"] and name not in result["held"]):
            continue
        sd = uncertainty.get(name) if name in result["free"] else None
        if name in result["free"]:
            status = "fitted"
        else:
            status = "held: " + result["held"][name]["reason"]
        if isinstance(value, list):
            text = ", ".join(f"{v:.4f}" for v in value)
            sd_text = ", ".join(f"{v:.2g}" for v in sd) if sd is not None else "-"
        else:
            text = f"{value:.4f}"
            sd_text = f"{sd:.2g}" if sd is not None else "-"
        row = [name, text, sd_text, status]
        if equivalence:
            span = equivalence.get(name)
            if span is None:
                row.insert(3, "-")
            elif isinstance(span[0], list):
                row.insert(3, ", ".join(f"{lo:.3g}–{hi:.3g}" for lo, hi in span))
            else:
                row.insert(3, f"{span[0]:.3g}–{span[1]:.3g}")
        rows.append(tuple(row))
    columns = len(rows[0]) - 1
    widths = [max(len(r[i]) for r in rows) for i in range(columns)]
    lines = ["  ".join(f"{r[i]:<{widths[i]}}" for i in range(columns)) + f"  {r[-1]}" for r in rows]
    lines.insert(1, "-" * min(100, sum(widths) + 2 * columns + 6))
    method = result.get("uncertainty_method", {})
    if method.get("meaning"):
        lines.append(f"±: {method['meaning']}")
    res = result["residual"]
    lines.append("")
    lines.append(
        f"residual: RMS {res['rms']:.3g} (linear), CIEDE2000 mean {res['delta_e2000_mean']:.3g}, "
        f"95th percentile {res['delta_e2000_p95']:.3g}; {result['pixels_used']} pixels"
    )
    solver = result["solver"]
    loss = f", {solver['loss']} loss" if solver.get("loss") and solver["loss"] != "linear" else ""
    lines.append(
        f"solver: {solver['name']}{loss}, {solver['steps']} steps, {solver['status']}, "
        f"{len(result['starts'])} start(s); wall time {result['wall_time_s']:.2f} s"
    )
    for note in result.get("notes", []):
        lines.append(f"note: {note}")
    return "\n".join(verdict_lines(result) + [""] + lines)


def comparison_image(
    target: np.ndarray, fitted: np.ndarray, mask: np.ndarray, standardized: np.ndarray | None = None
) -> np.ndarray:
    """target | fit | |residual| (amplified to fill the range) side by side, linear; with
    ``standardized`` ((H, W): the residual in noise units, NaN where not fitted) a fourth
    panel shows it on a logarithmic scale, black at one noise deviation or less and white
    at the 99th percentile (at least 5): where, and by how much, the model misses."""
    mask = np.asarray(mask, dtype=bool)
    residual = np.abs(fitted - target) * mask[..., None]
    peak = float(residual.max())
    scale = float(np.percentile(target[mask], 99)) if mask.any() else 1.0
    scale = max(scale, 1e-12)
    residual_view = residual / peak * scale if peak > 0 else residual
    gap = np.ones((target.shape[0], 2, 3)) * scale
    panels = [target, gap, fitted, gap, residual_view]
    if standardized is not None:
        z = np.nan_to_num(np.asarray(standardized, dtype=float), nan=0.0)
        top = max(float(np.percentile(z[mask], 99)) if mask.any() else 5.0, 5.0)
        level = np.clip(np.log10(np.maximum(z, 1.0)) / np.log10(top), 0.0, 1.0)[..., None] * np.ones(3)
        panels += [gap, level * scale]
    return np.concatenate(panels, axis=1) / scale


def standardized_map(result: Any, shape: tuple[int, int]) -> np.ndarray | None:
    """A result's residual in noise units as an (H, W) map (NaN off the pixels used)."""
    if result.standardized_residual is None or result.used_index is None:
        return None
    out = np.full(shape[0] * shape[1], np.nan)
    out[np.asarray(result.used_index)] = np.asarray(result.standardized_residual)
    return out.reshape(shape)


def _number(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, float) and not math.isfinite(value):
        return ""
    return repr(float(value)) if isinstance(value, (int, float)) else str(value)


def summary_row(target: str, result: dict[str, Any] | None, *, error: str | None = None, path: str = "") -> dict:
    """One row of ``summary.csv`` for a fitted target (its result JSON) or a failed one."""
    row = dict.fromkeys(SUMMARY_COLUMNS, "")
    row["target"] = target
    if result is None:
        row.update(status="failed", error=error or "")
        return row
    residual = result.get("residual", {})
    uncertainty = result.get("uncertainty", {})
    row.update(
        status="ok",
        verdict=residual.get("verdict") or "",
        chi2_per_dof=_number(residual.get("chi2_per_dof")),
        noise_source=residual.get("noise_source") or "",
        exposure=_number(result.get("exposure", 1.0)),
        free=" ".join(result.get("free", [])),
        rms=_number(residual.get("rms")),
        delta_e2000_mean=_number(residual.get("delta_e2000_mean")),
        delta_e2000_p95=_number(residual.get("delta_e2000_p95")),
        solver_status=result.get("solver", {}).get("status", ""),
        warnings=" ".join(w["code"] for w in result.get("warnings", [])),
        result=path,
    )
    for channel, value in zip("rgb", result.get("color", [])):
        row[f"color_{channel}"] = _number(value)
    for name in SCALAR_NAMES:
        row[name] = _number(result.get(name))
    for name in (*SCALAR_NAMES, "exposure"):
        if name in uncertainty and name in result.get("free", []):
            row[f"sd_{name}"] = _number(uncertainty[name])
    if "color" in uncertainty and "color" in result.get("free", []):
        for channel, value in zip("rgb", uncertainty["color"]):
            row[f"sd_color_{channel}"] = _number(value)
    return row
