r"""Several reflectance models fitted to the same data, and whether Strauss is distinguishable
from the best of them (``strauss-fit compare``, docs/commands/compare.md).

Every model of `strauss_fit.fitting.capture.MODELS` (read when called: the registry may
grow) is fitted by the one capture fitter, `strauss_fit.fitting.capture.fit_capture_samples`,
to the same usable values — one target and its scene
(`strauss_fit.fitting.scene_samples.samples_from_scene`) or a capture — and compared by:

- the residual: its sum of squares (RSS), relative RMS and mean CIEDE2000
  (`relative_rms`, `delta_e_mean`);
- `\chi^2/\mathrm{dof}` with `\chi^2 = \sum (r/\sigma)^2` and dof = n − k, when
  the noise σ is known (one value, one per channel, or one per value);
- AIC and BIC from the Gaussian likelihood: with σ known, `-2\ln L = \chi^2` (+ a
  constant shared by every model), so AIC = χ² + 2k and BIC = χ² + k ln n; with σ unknown
  it is profiled out (one σ for every value, its maximum-likelihood `\hat\sigma^2 =
  \mathrm{RSS}/n`), so AIC = n ln(RSS/n) + 2k and BIC = n ln(RSS/n) + k ln n. n is the
  number of usable values (pixels × channels × images fitted), k the number of fitted
  parameters (a value that ended on its bound still counts);
- with a ``holdout``, each model fitted to the other images predicts the held-out ones
  (`strauss_fit.fitting.capture_result.predict`): their relative RMS and mean CIEDE2000.

The best model has the lowest BIC, or with a holdout the lowest held-out relative RMS. The
verdict says whether Strauss's fit is distinguishable from the best's: ΔBIC = BIC(Strauss) −
BIC(best) above `DELTA_BIC_STRONG` (10, "very strong" on Kass and Raftery's scale) and,
with a holdout, a higher held-out error; and, separately, whether the difference is visible:
the mean CIEDE2000 between the two fits' predictions against `JND` (1). BIC assumes
independent noise: a misfit correlated over the sphere is counted as many independent pieces
of evidence, and ΔBIC is then overconfident (the result says so).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..capture._samples import CaptureSamples
from ..errors import CaptureError
from . import capture as _capture
from .capture import CaptureFit, CaptureFitOptions, delta_e_mean, fit_capture_samples, relative_rms
from .capture_result import holdout_indices, predict

#: ΔBIC above which the worse model is "very strongly" disfavoured (Kass & Raftery 1995).
DELTA_BIC_STRONG = 10.0
#: One just-noticeable difference, in mean CIEDE2000.
JND = 1.0

CAVEAT = (
    "AIC, BIC and χ² assume independent Gaussian noise in every value. A misfit that is correlated over the sphere "
    "(a highlight of the wrong shape spans many neighbouring pixels) is counted as many independent pieces of "
    "evidence, so ΔBIC is overconfident: read a large ΔBIC as 'the residuals differ', and the held-out error and "
    "the ΔE between the two fits as how much that matters."
)
PROFILED_CAVEAT = (
    "The noise σ is not known, so it is profiled out: each model's own residual stands for the noise, as one σ "
    "shared by every value (a misfit is then treated as noise)."
)


def known_models() -> tuple[str, ...]:
    """The reflectance models the capture fitter knows now (`strauss_fit.fitting.capture.MODELS`)."""
    return tuple(_capture.MODELS)


def check_models(models: Sequence[str] | str | None) -> list[str]:
    """The models to compare: ``None`` for all, else names (a list or ``"a,b,c"``), each
    known and given once; a one-line `CaptureError` otherwise."""
    known = known_models()
    if models is None:
        return list(known)
    names = [m.strip() for m in models.split(",")] if isinstance(models, str) else [str(m).strip() for m in models]
    names = [m for m in names if m]
    if not names:
        raise CaptureError(f"no model to compare; the known models are {', '.join(known)}")
    for name in names:
        if name not in known:
            raise CaptureError(f"unknown model {name!r}; the known models are {', '.join(known)}")
    repeated = sorted({m for m in names if names.count(m) > 1})
    if repeated:
        raise CaptureError(f"model {repeated[0]!r} is named twice")
    return names


def _finite(value: float | None) -> float | None:
    """A number for JSON: None for NaN and infinities."""
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def noise_per_value(noise: Any, samples: CaptureSamples) -> np.ndarray | None:
    """σ per value (L, P, 3) from ``noise``: None, one σ, three (R, G, B) or an array that
    broadcasts to the values; every σ at a usable value must be finite and > 0."""
    if noise is None:
        return None
    try:
        sigma = np.broadcast_to(np.asarray(noise, dtype=np.float64), samples.values.shape)
    except ValueError:
        raise CaptureError(
            f"the noise σ must be one value, three (R, G, B) or one per value {samples.values.shape}, "
            f"got shape {np.shape(noise)}"
        ) from None
    used = sigma[samples.usable]
    if not np.all(np.isfinite(used)) or np.any(used <= 0):
        raise CaptureError("the noise σ must be finite and > 0 at every value fitted")
    return sigma


def information_criteria(rss: float, n: int, k: int, chi2: float | None = None) -> dict[str, Any]:
    """AIC and BIC of a least-squares fit of ``k`` parameters to ``n`` values (module
    docstring): from χ² when the noise is known, else with σ profiled out of ``rss``."""
    if chi2 is not None:
        deviance, likelihood = float(chi2), "gaussian, σ known"
    else:
        deviance = n * math.log(max(rss, 1e-300) / n)
        likelihood = "gaussian, σ profiled out"
    return {"aic": deviance + 2 * k, "bic": deviance + k * math.log(n), "likelihood": likelihood}


@dataclass
class ModelComparison:
    """What `fit_models` gives back: ``result`` (JSON-able, see `compare_models`),
    and per model that fitted its prediction of every image of the samples (L, P, 3): the
    fitted images from the fit, the held-out ones predicted."""

    result: dict[str, Any]
    predictions: dict[str, np.ndarray] = field(default_factory=dict)


def compare_models(
    samples: CaptureSamples,
    models: Sequence[str] | str | None = None,
    *,
    exposure: str = "global",
    holdout: str | int | Sequence[int] | None = None,
    noise: Any = None,
    progress: Callable[[str], Any] | None = None,
) -> dict[str, Any]:
    """Fit each of ``models`` (default: every known one) to ``samples`` and compare them
    (module docstring); a JSON-able result. ``noise``: the noise σ when known (one value,
    R, G, B, or one per value); ``holdout``: images held out and predicted (as
    `strauss_fit.fitting.capture_result.holdout_indices` reads it). A model whose fit
    raises is recorded with its error; the others go on."""
    return fit_models(samples, models, exposure=exposure, holdout=holdout, noise=noise, progress=progress).result


def fit_models(
    samples: CaptureSamples,
    models: Sequence[str] | str | None = None,
    *,
    exposure: str = "global",
    holdout: str | int | Sequence[int] | None = None,
    noise: Any = None,
    progress: Callable[[str], Any] | None = None,
) -> ModelComparison:
    """`compare_models`, with each model's prediction of every image kept (for figures)."""
    log = progress or (lambda message: None)
    t0 = time.perf_counter()
    names = check_models(models)
    CaptureFitOptions(exposure=exposure)  # a one-line error for an unknown exposure, before any fit
    sigma_all = noise_per_value(noise, samples)
    held = holdout_indices(holdout, samples.count) if holdout is not None else []
    train_idx = [i for i in range(samples.count) if i not in set(held)]
    train = samples.select(train_idx) if held else samples
    test = samples.select(held) if held else None
    sigma = None if sigma_all is None else sigma_all[train_idx]
    n = int(np.asarray(train.usable).sum())
    if n == 0:
        raise CaptureError("no usable values: every sphere pixel is saturated or under-exposed in every image")

    entries: dict[str, dict[str, Any]] = {}
    predictions: dict[str, np.ndarray] = {}
    fitted: dict[str, np.ndarray] = {}
    held_predictions: dict[str, np.ndarray] = {}
    for number, name in enumerate(names, 1):
        log(f"fitting {name} ({number} of {len(names)}) to {train.count} image{'s' * (train.count != 1)}")
        entries[name], fit, held_pred = _fit_model(name, train, test, exposure, sigma, log)
        if fit is None:
            continue
        fitted[name] = fit.predicted
        full = np.zeros(samples.values.shape)
        full[train_idx] = fit.predicted
        if held_pred is not None:
            held_predictions[name] = held_pred
            full[held] = held_pred
        predictions[name] = full

    ok = _rank_criteria(entries, names)
    result: dict[str, Any] = {
        "format": "strauss-fit model comparison",
        "models": entries,
        "order": names,
        "failed": [m for m in names if m not in ok],
        "images": samples.count,
        "images_fitted": train.count,
        "held_out": [samples.files[i] for i in held] if held else None,
        "pixels": int(len(samples.rows)),
        "values_used": n,
        "exposure": exposure,
        "noise": _noise_summary(sigma, np.asarray(train.usable)),
        "criteria": _criteria_record(sigma is not None, n),
        "verdict": _verdict(entries, ok, train, test, fitted, held_predictions, sigma is not None),
        "settings": {
            "models": names,
            "exposure": exposure,
            "holdout": None if holdout is None else str(holdout),
        },
        "wall_time_s": time.perf_counter() - t0,
    }
    return ModelComparison(result, predictions)


def _fit_model(
    name: str,
    train: CaptureSamples,
    test: CaptureSamples | None,
    exposure: str,
    sigma: np.ndarray | None,
    log: Callable[[str], Any],
) -> tuple[dict[str, Any], CaptureFit | None, np.ndarray | None]:
    """One model fitted to ``train`` and predicting ``test``: its entry of the comparison,
    its fit and its prediction of ``test``; a model whose fit raises gives an entry with its
    error, and no fit (the other models go on)."""
    t_model = time.perf_counter()
    try:
        fit = fit_capture_samples(train, CaptureFitOptions(model=name, exposure=exposure))
        held_pred, held_out = None, None
        if test is not None:
            held_pred, scales = predict(test, fit)
            held_out = {
                "relative_rms": _finite(relative_rms(held_pred, test.values, test.usable)),
                "delta_e2000_mean": _finite(delta_e_mean(held_pred, test.values, test.usable)),
                "exposure_scales": scales if "image_exposure" in {p.name for p in fit.params} else None,
            }
    except Exception as exc:  # one model failing does not stop the others
        entry = {
            "model": name,
            "status": "failed",
            "error": f"{type(exc).__name__}: {' '.join(str(exc).split())}",
            "wall_time_s": time.perf_counter() - t_model,
        }
        log(f"{name} failed: {exc}")
        return entry, None, None
    return _model_entry(name, fit, train, sigma, held_out, t_model), fit, held_pred


def _model_entry(
    name: str,
    fit: CaptureFit,
    train: CaptureSamples,
    sigma: np.ndarray | None,
    held_out: dict[str, Any] | None,
    t_model: float,
) -> dict[str, Any]:
    """The comparison's entry of a model that fitted: its values, residual, χ², AIC and BIC
    (`information_criteria`) and ``held_out`` prediction errors."""
    usable = np.asarray(train.usable)
    n = int(usable.sum())
    residual = (fit.predicted - train.values)[usable]
    rss = float(residual @ residual)
    k = int(len(fit.physical))
    chi2 = None if sigma is None else float(np.sum((residual / sigma[usable]) ** 2))
    dof = n - k
    criteria = information_criteria(rss, n, k, chi2)
    return {
        "model": name,
        "status": "ok",
        "values": fit.values(),
        "labels": list(fit.labels),
        "k": k,
        "n": n,
        "dof": dof,
        "rss": rss,
        "relative_rms": _finite(relative_rms(fit.predicted, train.values, train.usable)),
        "delta_e2000_mean": _finite(delta_e_mean(fit.predicted, train.values, train.usable)),
        "chi2": _finite(chi2),
        "chi2_per_dof": _finite(chi2 / dof) if chi2 is not None and dof > 0 else None,
        "aic": criteria["aic"],
        "bic": criteria["bic"],
        "held_out": held_out,
        "solver": {"steps": fit.steps, "status": fit.status},
        "wall_time_s": time.perf_counter() - t_model,
    }


def _rank_criteria(entries: dict[str, dict[str, Any]], names: list[str]) -> list[str]:
    """The models that fitted (in ``names``' order), each entry given its ΔAIC and ΔBIC
    from the best; a one-line error when every model failed."""
    ok = [name for name in names if entries[name]["status"] == "ok"]
    if not ok:
        raise CaptureError("every model failed: " + "; ".join(f"{name}: {entries[name]['error']}" for name in names))
    best_aic = min(entries[m]["aic"] for m in ok)
    best_bic = min(entries[m]["bic"] for m in ok)
    for m in ok:
        entries[m]["delta_aic"] = entries[m]["aic"] - best_aic
        entries[m]["delta_bic"] = entries[m]["bic"] - best_bic
    return ok


def _criteria_record(known_sigma: bool, n: int) -> dict[str, Any]:
    """The comparison's ``criteria``: how AIC and BIC were computed (module docstring)."""
    return {
        "likelihood": "gaussian, σ known" if known_sigma else "gaussian, σ profiled out",
        "aic": "χ² + 2k" if known_sigma else "n ln(RSS/n) + 2k",
        "bic": "χ² + k ln n" if known_sigma else "n ln(RSS/n) + k ln n",
        "n": n,
        "meaning": "n: usable values fitted (pixels × channels × images); k: fitted parameters; lower is "
        "better; only differences between models mean anything",
    }


def _noise_summary(sigma: np.ndarray | None, usable: np.ndarray) -> dict[str, Any]:
    if sigma is None:
        return {"known": False}
    per_channel = [float(np.sqrt(np.mean(sigma[..., c][usable[..., c]] ** 2))) for c in range(3)]
    constant = all(np.all(sigma[..., c][usable[..., c]] == sigma[..., c][usable[..., c]][0]) for c in range(3))
    return {"known": True, "sigma_rms_per_channel": per_channel, "per_value": not constant}


def _verdict(
    entries: dict[str, dict[str, Any]],
    ok: list[str],
    train: CaptureSamples,
    test: CaptureSamples | None,
    fitted: dict[str, np.ndarray],
    held_predictions: dict[str, np.ndarray],
    known_sigma: bool,
) -> dict[str, Any]:
    """The comparison's ``verdict``: the best model, and whether Strauss's fit is
    distinguishable from the best other's and whether the difference is visible (module
    docstring)."""
    caveats = [CAVEAT] + ([] if known_sigma else [PROFILED_CAVEAT])
    ranked, best_by = _ranked(entries, ok, test)
    best = ranked[0]
    out: dict[str, Any] = {
        "best": best,
        "best_by": best_by,
        "delta_bic_threshold": DELTA_BIC_STRONG,
        "jnd_delta_e2000": JND,
        "caveats": caveats,
    }
    if "strauss" not in entries:
        return out | {"outcome": "not-compared", "statement": "Strauss was not among the models compared"}
    if "strauss" not in ok:
        return out | {
            "outcome": "strauss-failed",
            "statement": f"the Strauss fit failed ({entries['strauss']['error']}); the best model is {best}",
        }
    if len(ok) == 1:
        return out | {"outcome": "nothing-to-compare", "statement": "only Strauss fitted: nothing to compare with"}
    other = ranked[1] if best == "strauss" else best
    gap = _gap(entries, other, train, test, fitted, held_predictions)
    out |= {
        "compared_with": other,
        "delta_bic": gap.delta_bic,
        "delta_aic": entries["strauss"]["aic"] - entries[other]["aic"],
        "delta_held_out_relative_rms": gap.delta_held,
        "prediction_delta_e2000_mean": gap.delta_e,
        "held_out_prediction_delta_e2000_mean": gap.delta_e_held,
        "visible": gap.visible,
    }
    if best == "strauss":
        return out | _strauss_best(other, best_by, gap)
    return out | _strauss_not_best(other, gap)


def _ranked(entries: dict[str, dict[str, Any]], ok: list[str], test: CaptureSamples | None) -> tuple[list[str], str]:
    """The models that fitted, best first, and by what: the held-out relative RMS when every
    one has it, else BIC (Strauss first among equals)."""
    by_held_out = test is not None and all((entries[m]["held_out"] or {}).get("relative_rms") is not None for m in ok)
    if by_held_out:
        return sorted(
            ok, key=lambda m: (entries[m]["held_out"]["relative_rms"], m != "strauss")
        ), "held-out relative RMS"
    return sorted(ok, key=lambda m: (entries[m]["bic"], m != "strauss")), "BIC"


@dataclass
class _Gap:
    """How Strauss's fit differs from another model's (``other``'s): in BIC, in held-out
    error, and in how the two fits' predictions look."""

    #: BIC(Strauss) − BIC(other)
    delta_bic: float
    #: the difference of their held-out relative RMS; None without a holdout
    delta_held: float | None
    #: mean CIEDE2000 between the two fits on the fitted images (None when it cannot be computed)
    delta_e: float | None
    #: the same on the held-out images; None without a holdout
    delta_e_held: float | None
    #: whether the difference shown (held-out if there are, else fitted) is at least one JND
    visible: bool
    #: the sentence on how the predictions compare
    look: str
    #: the held-out difference as a clause of a sentence ("" without a holdout)
    held_text: str


def _gap(
    entries: dict[str, dict[str, Any]],
    other: str,
    train: CaptureSamples,
    test: CaptureSamples | None,
    fitted: dict[str, np.ndarray],
    held_predictions: dict[str, np.ndarray],
) -> _Gap:
    """The `_Gap` between Strauss's fit and ``other``'s."""

    def held_error(m: str) -> float | None:
        return (entries[m]["held_out"] or {}).get("relative_rms")

    delta_bic = entries["strauss"]["bic"] - entries[other]["bic"]
    delta_held = None
    if held_error("strauss") is not None and held_error(other) is not None:
        delta_held = held_error("strauss") - held_error(other)
    usable = np.asarray(train.usable)
    delta_e = _finite(delta_e_mean(fitted["strauss"], fitted[other], usable))
    delta_e_held = None
    if test is not None and "strauss" in held_predictions and other in held_predictions:
        delta_e_held = _finite(delta_e_mean(held_predictions["strauss"], held_predictions[other], test.usable))
    shown_de = delta_e_held if delta_e_held is not None else delta_e
    visible = shown_de is not None and shown_de >= JND
    where = "held-out images" if delta_e_held is not None else "fitted images"
    look = (
        f"mean CIEDE2000 between the two fits' predictions on the {where}: {shown_de:.2f}"
        if shown_de is not None
        else "their predictions' CIEDE2000 could not be computed"
    )
    held_text = "" if delta_held is None else f", held-out relative RMS {100 * delta_held:+.3f} points"
    return _Gap(delta_bic, delta_held, delta_e, delta_e_held, visible, look, held_text)


def _strauss_best(other: str, best_by: str, gap: _Gap) -> dict[str, Any]:
    """The verdict's outcome and statement when Strauss is the best model (``other`` the
    runner-up)."""
    behind = f"ΔBIC = {-gap.delta_bic:.1f}"
    if gap.delta_held is not None:
        behind += f" and {100 * -gap.delta_held:.3f} points of held-out relative RMS"
    seen = "they look different" if gap.visible else "below 1 JND: they look the same"
    return {
        "outcome": "strauss-best",
        "distinguishable": None,
        "statement": f"Strauss is the best model (lowest {best_by}); the runner-up, {other}, is {behind} "
        f"behind; {gap.look} ({seen})",
    }


def _strauss_not_best(other: str, gap: _Gap) -> dict[str, Any]:
    """The verdict's outcome and statement when ``other`` is the best model: Strauss is
    distinguishable from it when ΔBIC exceeds `DELTA_BIC_STRONG` and, with a holdout,
    its held-out error is higher too."""
    strong = gap.delta_bic > DELTA_BIC_STRONG
    distinguishable = strong and (gap.delta_held is None or gap.delta_held > 0)
    out: dict[str, Any] = {
        "distinguishable": distinguishable,
        "outcome": "distinguishable" if distinguishable else "indistinguishable",
    }
    evidence = f"ΔBIC = {gap.delta_bic:.1f} ({'>' if strong else '≤'} {DELTA_BIC_STRONG:g}"
    evidence += f"; BIC prefers Strauss){gap.held_text}" if gap.delta_bic < 0 else f"){gap.held_text}"
    if distinguishable:
        seen = (
            "and the two fits look different"
            if gap.visible
            else "but the two fits look the same (below 1 JND): the difference is real, not visible"
        )
        out["statement"] = f"Strauss is distinguishable from the best model, {other}: {evidence}; {gap.look}, {seen}"
    else:
        seen = "they look different" if gap.visible else "below 1 JND: they look the same"
        out["statement"] = (
            f"Strauss is not distinguishable from the best model, {other}: {evidence}; {gap.look} ({seen})"
        )
    return out


def format_comparison_table(result: dict[str, Any]) -> str:
    """The printed table of a comparison: one row per model, then the verdict."""
    held = result.get("held_out")
    lines = [
        f"{result['images_fitted']} of {result['images']} image{'s' * (result['images'] != 1)} fitted, "
        f"{result['pixels']} sphere pixels, {result['values_used']} values; "
        f"likelihood: {result['criteria']['likelihood']}"
        + (f"; held out: {len(held)} image{'s' * (len(held) != 1)}" if held else "")
    ]
    header = ["model", "k", "rel. RMS", "mean ΔE", "χ²/dof", "AIC", "BIC", "ΔBIC", "held-out rel. RMS"]
    rows = [header]

    def number(value: Any, spec: str) -> str:
        return "–" if value is None else format(value, spec)

    for name in result["order"]:
        entry = result["models"][name]
        if entry["status"] != "ok":
            rows.append([name, "failed"] + [""] * (len(header) - 2))
            continue
        held_rms = (entry.get("held_out") or {}).get("relative_rms")
        rows.append(
            [
                name,
                str(entry["k"]),
                "–" if entry["relative_rms"] is None else f"{100 * entry['relative_rms']:.2f} %",
                number(entry["delta_e2000_mean"], ".2f"),
                number(entry["chi2_per_dof"], ".3f"),
                f"{entry['aic']:.1f}",
                f"{entry['bic']:.1f}",
                f"{entry['delta_bic']:.1f}",
                "–" if held_rms is None else f"{100 * held_rms:.2f} %",
            ]
        )
    widths = [max(len(row[j]) for row in rows) for j in range(len(header))]
    for row in rows:
        cells = [row[0].ljust(widths[0])] + [cell.rjust(width) for cell, width in zip(row[1:], widths[1:])]
        lines.append("  ".join(cells).rstrip())
    for name in result["failed"]:
        lines.append(f"{name} failed: {result['models'][name]['error']}")
    verdict = result["verdict"]
    lines.append(f"best: {verdict['best']} (lowest {verdict['best_by']})")
    lines.append(f"verdict: {verdict['statement']}")
    lines.append(f"note: {verdict['caveats'][0]}")
    return "\n".join(lines)
