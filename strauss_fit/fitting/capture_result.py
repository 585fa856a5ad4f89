r"""A capture's fit as users get it: the result (JSON), its verdict and warnings, held-out
validation against other models, and the printed table.

The verdict needs the noise, which a photograph does not state. A capture bounds it from
both sides:

- from below, by the noise of the background away from the sphere (differences between
  images of the same dark pixels: read noise, no shot noise) and the quantisation of the
  stored values;
- from above, by the images' five-point Laplacian on the sphere, binned by level: noise of
  level σ gives it a spread of √20 σ, and the picture's own curvature only adds to it
  (`strauss_fit.stats.noise.binned_laplacian_bound`).

``consistent`` when the residual is within even the lower bound; ``mismatch`` when its RMS
exceeds `strauss_fit.fitting.capture.BOUND_FACTOR` times the upper bound (whatever the
noise, the model does not reproduce the photographs); ``undetermined`` in between.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import jax.numpy as jnp
import numpy as np

from ..capture._manifest import Capture, open_capture
from ..capture._samples import CaptureSamples, load_samples
from ..color import delta_e_2000
from ..errors import CaptureError
from ..models.material import PARAMETER_NAMES
from ..precision import float64
from ..stats.noise import binned_laplacian_bound
from . import capture_stability
from .capture import (
    BOUND_FACTOR,
    HELD,
    MIN_IMAGE_CLUSTERS,
    MODELS,
    TILE_PX,
    CaptureFit,
    CaptureFitOptions,
    _by_name,
    _labels,
    _offsets,
    _Param,
    _parameters,
    _predict,
    _terms,
    delta_e_mean,
    fit_capture_samples,
    relative_rms,
)
from .capture_equivalence import DEFAULT_DELTA_E, capture_equivalence

#: The models a held-out validation compares with the one fitted.
COMPARED = ("lambert", "phong", "blinn-phong")


def holdout_indices(spec: str | int | Sequence[int], count: int) -> list[int]:
    """0-based indices of the held-out images: every k-th (``"2"``: images 2, 4, 6, … in
    1-based numbering) or a list of 1-based numbers (``"1,5,9"``)."""
    if isinstance(spec, int):
        items = [spec]
        every = True
    elif isinstance(spec, str):
        text = spec.strip()
        every = "," not in text
        try:
            items = [int(part) for part in text.split(",") if part.strip()]
        except ValueError:
            raise CaptureError(
                f"--holdout takes a number k (every k-th image) or a list like 2,5,9, not {spec!r}"
            ) from None
    else:
        items, every = [int(v) for v in spec], False
    if not items:
        raise CaptureError("--holdout is empty")
    if every:
        k = items[0]
        if not 2 <= k <= count:
            raise CaptureError(f"--holdout {k}: k must be between 2 and the number of images ({count})")
        held = [i for i in range(count) if (i + 1) % k == 0]
    else:
        bad = [v for v in items if not 1 <= v <= count]
        if bad:
            raise CaptureError(
                f"--holdout: image {bad[0]} does not exist (the capture has {count} images, numbered from 1)"
            )
        held = sorted(set(v - 1 for v in items))
    if len(held) >= count:
        raise CaptureError("--holdout leaves no image to fit")
    return held


def noise_bound(samples: CaptureSamples, residual_levels: np.ndarray) -> tuple[np.ndarray, list[dict[str, Any]]]:
    """Per value (L, P, 3): an upper bound on the noise σ at the observed level, from the
    images' five-point Laplacians (`strauss_fit.stats.noise.binned_laplacian_bound`);
    and its level bins (for the result)."""
    return binned_laplacian_bound(samples.laplacian, samples.values, samples.usable, residual_levels)


def _verdict(samples: CaptureSamples, fit: CaptureFit) -> tuple[dict[str, Any], list[dict[str, str]]]:
    usable = samples.usable
    residual = (fit.predicted - samples.values)[usable]
    count = residual.size
    dof = max(count - len(fit.physical), 1)
    bound, bins = noise_bound(samples, samples.values)
    bound_used = bound[usable]
    # one target fitted with --model is an image of one scene, not a capture's photographs
    subject, images = ("this capture", "the photographs allow") if samples.count > 1 else ("this image", "it allows")
    finite = np.isfinite(bound_used) & (bound_used > 0)
    floor = np.sqrt(
        (samples.background_noise if samples.background_noise is not None else np.zeros(3)) ** 2
        + samples.quantisation**2
    )
    floor_per_value = np.broadcast_to(floor, samples.values.shape)[usable]
    out: dict[str, Any] = {
        "noise_floor": [float(v) for v in floor],
        "noise_floor_source": "background differences and quantisation"
        if samples.background_noise is not None
        else "quantisation",
        "noise_bound_bins": bins,
    }
    warnings: list[dict[str, str]] = []
    chi2_up = float(np.mean(residual[finite] ** 2 / bound_used[finite] ** 2)) if finite.any() else None
    chi2_low = float(np.sum(residual**2 / floor_per_value**2) / dof) if np.all(floor_per_value > 0) else None
    out["chi2_per_dof_at_bound"] = chi2_up
    out["chi2_per_dof_at_floor"] = chi2_low
    expected_sd = math.sqrt(2.0 / dof)
    if chi2_up is not None and chi2_up > BOUND_FACTOR**2:
        verdict = "mismatch"
        ratio = math.sqrt(chi2_up)
        warnings.append(
            {
                "code": "model-mismatch",
                "message": f"the residual's RMS is {ratio:.1f} times the largest noise {images} "
                f"(a bound from the pixel-to-pixel differences; a mismatch above {BOUND_FACTOR:g} times): "
                f"the {fit.model} model does not reproduce {subject}, whatever its noise",
            }
        )
    elif chi2_low is not None and chi2_low <= 1 + 3 * expected_sd:
        verdict = "consistent"
    else:
        verdict = "undetermined"
        warnings.append(
            {
                "code": "noise-unknown",
                "message": "the residual lies between the noise floor (background, quantisation) and the largest "
                f"noise {images}: no verdict",
            }
        )
    out["verdict"] = verdict
    return out, warnings


def _regions(samples: CaptureSamples, fit: CaptureFit, terms: dict[str, Any]) -> dict[str, Any]:
    """Where the residual sits: the highlight (within about 25° of a light's mirror
    direction), the lit body, and the side no stated light reaches."""
    cos_beta = np.asarray(terms["cos_beta"]).max(axis=1)  # (L, P)
    lit = np.asarray(terms["cos_alpha"]).max(axis=1) > 0
    regions = {"highlight": lit & (cos_beta > 0.9), "body": lit & (cos_beta <= 0.9), "unlit": ~lit}
    out = {}
    for name, where in regions.items():
        use = samples.usable & where[..., None]
        if not use.any():
            continue
        observed, predicted = samples.values[use], fit.predicted[use]
        scale = float(np.sqrt(np.mean(observed**2))) or 1.0
        out[name] = {
            "values": int(use.sum()),
            "relative_rms": float(np.sqrt(np.mean((predicted - observed) ** 2)) / scale),
            "mean_residual": float(np.mean(observed - predicted)),
            "observed_median": float(np.median(observed)),
            "predicted_median": float(np.median(predicted)),
        }
    return out


def _room_light_warning(
    regions: dict[str, Any], floor: np.ndarray, options: CaptureFitOptions
) -> dict[str, str] | None:
    unlit, body = regions.get("unlit"), regions.get("body")
    if options.ambient or unlit is None or body is None:
        return None
    excess = unlit["observed_median"] - unlit["predicted_median"]
    if excess > max(3 * float(np.max(floor)), 0.01 * body["observed_median"]):
        share = 100 * unlit["observed_median"] / max(body["observed_median"], 1e-300)
        return {
            "code": "unstated-light",
            "message": f"where no stated light reaches ({unlit['values']} values on the shadowed side), "
            f"the photographs show a median of {unlit['observed_median']:.3g} "
            f"({share:.1f} % of the lit side's median) and the fit "
            f"{unlit['predicted_median']:.3g}: light the capture does not state (the room, stray light). "
            "Fit it with --ambient",
        }
    return None


def _per_image(samples: CaptureSamples, predicted: np.ndarray, held: Sequence[bool]) -> list[dict[str, Any]]:
    rows = []
    for i in range(samples.count):
        use = samples.usable[i]
        keep = use.all(axis=-1)
        rows.append(
            {
                "file": samples.files[i],
                "held_out": bool(held[i]),
                "values_used": int(use.sum()),
                "saturated_pixels": int(samples.saturated[i]),
                "relative_rms": relative_rms(
                    predicted[i : i + 1], samples.values[i : i + 1], samples.usable[i : i + 1]
                ),
                "delta_e2000_mean": float(
                    np.mean(delta_e_2000(np.maximum(predicted[i][keep], 0), np.maximum(samples.values[i][keep], 0)))
                )
                if keep.any()
                else None,
            }
        )
    return rows


def predict(samples: CaptureSamples, fit: CaptureFit) -> tuple[np.ndarray, list[float]]:
    """The fitted material's prediction of ``samples``' images (other images than it was
    fitted to, e.g. held out). Where the fit had a free exposure per image, each image's
    exposure is fitted alone (one scale); returns the prediction and those scales."""
    params = tuple(p for p in fit.params if p.name != "image_exposure")
    names = {p.name for p in fit.params}
    physical = np.concatenate(
        [
            fit.physical[start : start + p.size]
            for p, start in zip(fit.params, _offsets(fit.params))
            if p.name != "image_exposure"
        ]
    )
    with float64():
        # a writable copy: each image is scaled in place below
        predicted = np.array(_predict(fit.model, params, jnp.asarray(physical), _terms(samples, fit.model)))
    scales = [1.0] * samples.count
    if "image_exposure" in names:
        for i in range(samples.count):
            use = samples.usable[i]
            den = float(np.sum((predicted[i] * use) ** 2))
            scales[i] = float(np.sum(predicted[i] * samples.values[i] * use) / den) if den > 0 else 1.0
            predicted[i] = predicted[i] * scales[i]
    return predicted, scales


def _material(fit: CaptureFit) -> dict[str, Any]:
    values = fit.values()
    if fit.model == "strauss":
        # every Strauss parameter, as a scene file's material: the fitted ones and those held
        return {name: HELD[name] if name in HELD else values[name] for name in PARAMETER_NAMES}
    return {k: v for k, v in values.items() if k in ("albedo", "diffuse", "specular", "exponent")}


def _held(model: str) -> dict[str, Any]:
    if model != "strauss":
        return {}
    return {
        "transparency": {
            "value": HELD["transparency"],
            "reason": "a capture of an opaque sample against a dark background: t only dims the surface "
            "and trades off with C",
        },
        "ior": {
            "value": HELD["ior"],
            "reason": "nothing is seen through the sphere: refraction has no effect on the photographs",
        },
    }


def _uncertainty_method(fit: CaptureFit) -> dict[str, Any]:
    circle = "; the uncertainty of where the sphere is (its circle) is added, as it is to the Laplace ±"
    if fit.cluster_kind == "image":
        return {
            "name": "image-cluster sandwich",
            "conditional_on_model": False,
            "meaning": "how far the fitted values would move with other photographs of this kind: the residuals of one "
            "image are summed before the spread is taken, since a misfit is correlated over the sphere" + circle,
        }
    return {
        "name": "tile-cluster sandwich",
        "conditional_on_model": False,
        "meaning": f"how far the fitted values would move with other images of this kind: the residuals of each "
        f"{TILE_PX}×{TILE_PX}-pixel tile are summed before the spread is taken, since a misfit is correlated over "
        f"neighbouring pixels (too few images, under {MIN_IMAGE_CLUSTERS}, to sum per image)" + circle,
    }


def _correlation(cov: np.ndarray, labels: list[str]) -> dict[str, Any]:
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(sd, sd)
    corr = np.where(np.outer(sd, sd) > 0, corr, 0.0)
    np.fill_diagonal(corr, 1.0)
    return {"labels": labels, "matrix": [[round(float(v), 6) for v in row] for row in corr]}


def _fit_summary(samples: CaptureSamples, fit: CaptureFit) -> dict[str, Any]:
    return {
        "model": fit.model,
        "values": fit.values(),
        "relative_rms": relative_rms(fit.predicted, samples.values, samples.usable),
        "delta_e2000_mean": delta_e_mean(fit.predicted, samples.values, samples.usable),
    }


def _validation(test: CaptureSamples, fit: CaptureFit) -> dict[str, Any]:
    predicted, scales = predict(test, fit)
    per_image = _per_image(test, predicted, [True] * test.count)
    out = {
        "model": fit.model,
        "relative_rms": relative_rms(predicted, test.values, test.usable),
        "delta_e2000_mean": delta_e_mean(predicted, test.values, test.usable),
        "per_image": [
            {"file": r["file"], "relative_rms": r["relative_rms"], "delta_e2000_mean": r["delta_e2000_mean"]}
            for r in per_image
        ],
    }
    if any(p.name == "image_exposure" for p in fit.params):
        out["exposures_fitted_per_held_out_image"] = scales
    return out


def fit_capture(
    capture: Capture | CaptureSamples,
    options: CaptureFitOptions | None = None,
    *,
    holdout: str | int | Sequence[int] | None = None,
    compare: Sequence[str] | None = None,
    progress: Callable[[str], Any] | None = None,
    inputs: dict[str, Any] | None = None,
    equivalence: bool = False,
    equivalence_de: float | None = None,
    stability: bool = False,
) -> dict[str, Any]:
    """Fit one material to a whole capture and describe the fit (the result of
    ``strauss-fit fit --capture``, see docs/formats.md).

    ``inputs`` (`strauss_fit.capture.capture_inputs`) are recorded in the result, so
    that `reload_capture_fit` (``sample``, ``report``) can read the capture again.

    ``equivalence`` adds each material parameter's perceptual equivalence range (within
    ``equivalence_de``, default one JND of mean CIEDE2000;
    `strauss_fit.fitting.capture_equivalence`); ``stability`` fits two disjoint halves of
    the images and each image alone and says where and why they disagree
    (`strauss_fit.fitting.capture_stability`).

    With ``holdout``, the images it names are left out of the fit and predicted by it; the
    models in ``compare`` (default: Lambert, Phong and Blinn–Phong) are fitted to the same
    images and predict the same held-out ones."""
    options = options or CaptureFitOptions()
    log = progress or (lambda message: None)
    t0 = time.perf_counter()
    if isinstance(capture, Capture):
        log(f"reading {len(capture.images)} images")
        samples = load_samples(capture)
    else:
        samples = capture
    t_read = time.perf_counter() - t0
    log(f"sphere: {samples.circle.describe()}; {len(samples.rows)} pixels × {samples.count} images")
    held = holdout_indices(holdout, samples.count) if holdout is not None else []
    train_idx = [i for i in range(samples.count) if i not in set(held)]
    train = samples.select(train_idx) if held else samples
    log(f"fitting {options.model} to {train.count} images")
    fit = fit_capture_samples(train, options)
    with float64():
        terms = _terms(train)
    verdict, warnings = _verdict(train, fit)
    regions = _regions(train, fit, terms)
    warnings += _fit_warnings(samples, fit, regions, np.asarray(verdict["noise_floor"]), options)
    result = _capture_record(samples, train, fit, verdict, regions, warnings, options, holdout)
    delta_e = DEFAULT_DELTA_E if equivalence_de is None else float(equivalence_de)
    if equivalence or equivalence_de is not None:
        log("equivalence ranges")
        result["equivalence"] = capture_equivalence(train, fit, delta_e=delta_e)
        result["equivalence_delta_e"] = delta_e
    if stability:
        result["stability"] = _stability(train, fit, options, delta_e, log)
        if not result["stability"]["stable"]:
            result["warnings"].append(_unstable_warning(result["stability"]))
    if held:
        result["holdout"] = _validation_by_model(samples, train, held, fit, options, compare, log)
    if inputs:
        result.update(inputs)
    result["timing"] = {"read_s": t_read, **fit.timing}
    result["wall_time_s"] = time.perf_counter() - t0
    return result


def _fit_warnings(
    samples: CaptureSamples,
    fit: CaptureFit,
    regions: dict[str, Any],
    floor: np.ndarray,
    options: CaptureFitOptions,
) -> list[dict[str, str]]:
    """The warnings about the capture besides the verdict's: light the capture does not
    state (on the shadowed side, or in the frame away from the sphere) and fitted values
    that trade off. ``floor``: the noise floor per channel."""
    warnings = []
    room = _room_light_warning(regions, floor, options)
    if room is not None:
        warnings.append(room)
    stray = _stray_light_warning(samples, floor)
    if stray is not None:
        warnings.append(stray)
    correlated = _correlation_warning(fit)
    if correlated is not None:
        warnings.append(correlated)
    return warnings


def _stray_light_warning(samples: CaptureSamples, floor: np.ndarray) -> dict[str, str] | None:
    """A warning when the frame away from the sphere is bright beside the sphere: stray
    light or a black level not subtracted; None otherwise."""
    background = samples.background
    sphere_median = float(np.median(samples.values[samples.usable])) if samples.usable.any() else 0.0
    stray = float(np.median(background))
    if sphere_median > 0 and stray > max(3 * float(np.max(floor)), 0.02 * sphere_median):
        return {
            "code": "stray-light",
            "message": f"the frame away from the sphere reads {stray:.3g} "
            f"({100 * stray / sphere_median:.1f} % of the "
            "sphere's median): stray light or a black level not subtracted (set black_level in the manifest)",
        }
    return None


def _correlation_warning(fit: CaptureFit) -> dict[str, str] | None:
    """A warning naming the fitted values that trade off (correlation beyond ±0.95 in the
    image-cluster covariance); None when none do."""
    pairs = []
    cov = fit.clustered
    for i, a in enumerate(fit.labels):
        for j in range(i + 1, len(fit.labels)):
            denom = math.sqrt(max(cov[i, i] * cov[j, j], 0.0))
            if denom > 0 and abs(cov[i, j] / denom) > 0.95:
                pairs.append(f"{a} and {fit.labels[j]} ({cov[i, j] / denom:+.2f})")
    if not pairs:
        return None
    more = f" and {len(pairs) - 3} more pairs" if len(pairs) > 3 else ""
    return {"code": "strong-correlation", "message": "values that trade off: " + ", ".join(pairs[:3]) + more}


def _capture_record(
    samples: CaptureSamples,
    train: CaptureSamples,
    fit: CaptureFit,
    verdict: dict[str, Any],
    regions: dict[str, Any],
    warnings: list[dict[str, str]],
    options: CaptureFitOptions,
    holdout: str | int | Sequence[int] | None,
) -> dict[str, Any]:
    """The capture's result (JSON) but for its optional parts: the fitted values and their
    deviations, the residual and verdict, per image, the sphere and what was fitted."""
    residual = (fit.predicted - train.values)[train.usable]
    result: dict[str, Any] = {
        "model": fit.model,
        **_material(fit),
        "free": [p.name for p in fit.params],
        "values": fit.values(),
        "held": _held(fit.model),
        "uncertainty": fit.deviations("clustered"),
        "uncertainty_method": _uncertainty_method(fit),
        "uncertainty_laplace": fit.deviations("laplace"),
        "uncertainty_circle": _by_name(fit.params, fit.circle_sd) if fit.circle_sd is not None else None,
        "correlation": _correlation(fit.clustered, fit.labels),
        "residual": {
            "rms": float(np.sqrt(np.mean(residual**2))),
            "relative_rms": relative_rms(fit.predicted, train.values, train.usable),
            "max_abs": float(np.max(np.abs(residual))),
            "delta_e2000_mean": delta_e_mean(fit.predicted, train.values, train.usable),
            "sum_of_squares": float(residual @ residual),
            **verdict,
            "regions": regions,
        },
        "per_image": _per_image(train, fit.predicted, [False] * train.count),
        "circle": {**samples.circle.to_dict(), "description": samples.circle.describe()},
        "camera": samples.camera.to_dict(),
        "images": samples.count,
        "images_fitted": train.count,
        "pixels": int(len(samples.rows)),
        "values_used": int(train.usable.sum()),
        "saturated_values": int((~train.usable).sum()),
        "background": [[float(v) for v in row] for row in samples.background],
        "solver": {"name": "lm", "steps": fit.steps, "status": fit.status},
        "starts": fit.starts,
        "warnings": warnings,
        "notes": [],
        "settings": {
            "model": options.model,
            "exposure": options.exposure,
            "white_balance": options.white_balance,
            "ambient": options.ambient,
            "max_steps": options.max_steps,
            "holdout": None if holdout is None else str(holdout),
        },
    }
    if fit.model == "strauss" and "exposure" in fit.values():
        result["exposure"] = fit.values()["exposure"]
    if samples.saturated.any():
        result["notes"].append(
            f"{int(samples.saturated.sum())} saturated pixels in {int((samples.saturated > 0).sum())} images "
            "were left out"
        )
    return result


def _stability(
    train: CaptureSamples, fit: CaptureFit, options: CaptureFitOptions, delta_e: float, log: Callable[[str], Any]
) -> dict[str, Any]:
    """The result's ``stability``: two disjoint halves of the images fitted and compared
    within ``delta_e``, and each image fitted alone (`strauss_fit.fitting.capture_stability`)."""
    return {
        **capture_stability.halves(train, options, delta_e=delta_e, progress=log),
        "single_images": capture_stability.single_images(
            train, fit, options, verdict=lambda one, f: _verdict(one, f)[0]["verdict"], progress=log
        ),
    }


def _unstable_warning(stability: dict[str, Any]) -> dict[str, str]:
    """The warning of a capture whose two halves give materials that look different."""
    differ = [name for name, ok in stability["agree"].items() if not ok]
    return {
        "code": "unstable",
        "message": "two disjoint halves of the images give materials that do not look the same "
        f"({', '.join(differ)} outside each other's equivalence ranges)",
    }


def _validation_by_model(
    samples: CaptureSamples,
    train: CaptureSamples,
    held: list[int],
    fit: CaptureFit,
    options: CaptureFitOptions,
    compare: Sequence[str] | None,
    log: Callable[[str], Any],
) -> dict[str, Any]:
    """The result's ``holdout``: the held-out images (indices ``held`` of ``samples``)
    predicted by ``fit`` and by each model of ``compare`` (default `COMPARED`) fitted
    to the same images ``train``."""
    test = samples.select(held)
    log(f"predicting {test.count} held-out images")
    models = [fit.model] + [m for m in (COMPARED if compare is None else compare) if m != fit.model]
    validation = {"held_out": [samples.files[i] for i in held], "models": {fit.model: _validation(test, fit)}}
    for other in models[1:]:
        if other not in MODELS:
            raise CaptureError(f"unknown model {other!r} to compare with; expected one of {', '.join(MODELS)}")
        log(f"fitting {other} to the same images")
        other_options = replace(
            options, model=other, exposure="per-image" if options.exposure == "per-image" else "global"
        )
        other_fit = fit_capture_samples(train, other_options)
        entry = _validation(test, other_fit)
        entry["fit"] = _fit_summary(train, other_fit)
        validation["models"][other] = entry
    return validation


def _recorded(path: str, base: Path | None) -> str:
    """A recorded path as written, else relative to the result's folder ``base``."""
    if Path(path).exists() or base is None or Path(path).is_absolute():
        return path
    beside = base / path
    return str(beside) if beside.exists() else path


def is_capture_result(data: Any) -> bool:
    """Whether ``data`` (a parsed result JSON) is a capture's fit result."""
    return isinstance(data, dict) and "images_fitted" in data and "circle" in data and "settings" in data


#: The JSON types of a capture's result's fields that ``sample`` and ``report`` read (each
#: may be absent or null: the readers say what they miss).
_FIELD_TYPES: dict[str, tuple[type, ...]] = {
    **dict.fromkeys(
        (
            "values",
            "held",
            "uncertainty",
            "uncertainty_laplace",
            "uncertainty_method",
            "uncertainty_circle",
            "correlation",
            "residual",
            "circle",
            "camera",
            "settings",
            "solver",
            "holdout",
            "equivalence",
            "stability",
        ),
        (dict,),
    ),
    **dict.fromkeys(("free", "warnings", "notes", "per_image"), (list,)),
    **dict.fromkeys(("model", "lights", "mask", "target", "scene", "encoding"), (str,)),
    **dict.fromkeys(("images", "images_fitted", "pixels"), (int,)),
    "equivalence_delta_e": (float, int),
    "capture": (str, list),
}


#: How `check_capture_result` names the JSON types.
_JSON_NAMES = {
    dict: "an object",
    list: "a list",
    str: "text",
    int: "a whole number",
    float: "a number",
    bool: "true/false",
}


def check_capture_result(result: dict[str, Any], source: str = "the capture's result") -> None:
    """A one-line `CaptureError` when a field of a capture's
    result (``source`` names it) has the wrong JSON type: a damaged or hand-edited file."""
    for name, types in _FIELD_TYPES.items():
        value = result.get(name)
        if value is None:
            continue
        if not isinstance(value, types) or isinstance(value, bool):
            expected = " or ".join(dict.fromkeys(_JSON_NAMES[t] for t in types))
            found = _JSON_NAMES.get(type(value), type(value).__name__)
            raise CaptureError(f"{source} is damaged: its {name!r} is {found}, not {expected}")
        items = value if name in ("free", "notes", "capture") and isinstance(value, list) else []
        if any(not isinstance(item, str) for item in items):
            raise CaptureError(f"{source} is damaged: its {name!r} holds something other than text")


def capture_options(result: dict[str, Any]) -> CaptureFitOptions:
    """The options a capture's result was fitted with (its ``settings``)."""
    settings = result.get("settings") or {}
    fields = ("model", "exposure", "white_balance", "ambient", "max_steps")
    return CaptureFitOptions(**{k: settings[k] for k in fields if k in settings})


def reload_capture_fit(
    result: dict[str, Any], *, base: str | Path | None = None, capture: Capture | None = None
) -> tuple[CaptureSamples, CaptureFit]:
    """A capture's fit again from its result: the images it was fitted to (the held-out ones
    left out again) and a `strauss_fit.fitting.capture.CaptureFit` with its values, its
    prediction of them and the covariances the result states (the image-cluster sandwich
    from the ± and correlations, the Laplace one diagonal).

    The capture is read from the inputs the result records (paths as written, else relative
    to ``base``, the result's folder), unless ``capture`` is given."""
    if not is_capture_result(result):
        raise CaptureError("not a capture's fit result (no images_fitted, circle and settings)")
    check_capture_result(result)
    options = capture_options(result)
    samples = _fitted_samples(result, None if base is None else Path(base), capture)
    params = _parameters(options, samples.count)
    values = result.get("values") or {name: result[name] for name in result.get("free") or [] if name in result}
    physical = _by_parameter(values, params, "values", "value")
    sd_clustered = _by_parameter(result.get("uncertainty") or {}, params, "uncertainties", "uncertainty")
    sd_laplace = _by_parameter(
        result.get("uncertainty_laplace") or {}, params, "Laplace uncertainties", "Laplace uncertainty"
    )
    corr = _finite_numbers((result.get("correlation") or {}).get("matrix", np.eye(physical.size)), "correlations")
    if corr.shape != (physical.size, physical.size):
        corr = np.eye(physical.size)
    with float64():
        predicted = np.asarray(_predict(options.model, params, jnp.asarray(physical), _terms(samples, options.model)))
    fit = CaptureFit(
        model=options.model,
        params=params,
        physical=physical,
        labels=_labels(params),
        laplace=np.diag(sd_laplace**2),
        clustered=corr * np.outer(sd_clustered, sd_clustered),
        predicted=predicted,
        steps=int((result.get("solver") or {}).get("steps", 0)),
        status=str((result.get("solver") or {}).get("status", "")),
    )
    return samples, fit


def _fitted_samples(result: dict[str, Any], folder: Path | None, capture: Capture | None) -> CaptureSamples:
    """The images a capture's result was fitted to, read again: ``capture`` if given, else
    the capture or the target and scene the result records (relative to ``folder``), with
    the images it held out left out."""
    if capture is None and result.get("scene") and result.get("target") and not result.get("capture"):
        # one target and its scene (``fit --model``): the scene states the sphere and lights
        from ..io.targets import load_target
        from ..scene.loading import load_scene
        from .scene_samples import samples_from_scene

        mask = result.get("mask")
        samples = samples_from_scene(
            load_scene(_recorded(result["scene"], folder)),
            load_target(
                _recorded(result["target"], folder),
                None if mask is None else _recorded(mask, folder),
                result.get("encoding") or "auto",
            ),
        )
    else:
        if capture is None:
            paths = result.get("capture")
            if not paths:
                raise CaptureError("the capture's result records no capture paths: give the capture")
            paths = [paths] if isinstance(paths, str) else paths
            lights, mask = result.get("lights"), result.get("mask")
            capture = open_capture(
                [_recorded(p, folder) for p in paths],
                None if lights is None else _recorded(lights, folder),
                None if mask is None else _recorded(mask, folder),
                result.get("encoding"),
            )
        samples = load_samples(capture)
    if samples.count != result.get("images"):
        raise CaptureError(
            f"the capture now has {samples.count} images, the result was fitted to a capture of {result.get('images')}"
        )
    holdout = (result.get("settings") or {}).get("holdout")
    if holdout is not None:
        held = set(holdout_indices(holdout, samples.count))
        samples = samples.select([i for i in range(samples.count) if i not in held])
    return samples


def _finite_numbers(value: Any, what: str) -> np.ndarray:
    """``value`` (a number or nested lists of them) as a float64 array; a one-line
    `CaptureError` naming ``what`` when it holds anything but
    finite numbers (a damaged result)."""
    try:
        out = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise CaptureError(f"the capture's result is damaged: its {what} are not numbers") from None
    if not np.all(np.isfinite(out)):
        raise CaptureError(f"the capture's result is damaged: its {what} are not all finite")
    return out


def _by_parameter(field: dict[str, Any], params: Sequence[_Param], what: str, one: str) -> np.ndarray:
    """A result's ``field`` (values or deviations by parameter name) as one vector in the
    order of ``params``; a one-line error when one is missing (``one`` names it) or the
    sizes do not match the settings."""
    try:
        parts = [np.atleast_1d(_finite_numbers(field[p.name], what)) for p in params]
    except KeyError as missing:
        raise CaptureError(f"the capture's result has no {one} for {missing.args[0]}") from None
    out = np.concatenate(parts)
    if out.size != _offsets(params)[-1]:
        raise CaptureError("the capture's result does not match its settings (parameter sizes differ)")
    return out


def format_capture_table(result: dict[str, Any]) -> str:
    """The printed summary of a capture's fit."""
    if result.get("scene") and not result.get("capture"):
        lines = [f"target {result.get('target')}: {result['pixels']} sphere pixels, model {result['model']}"]
    else:
        lines = [
            f"capture: {result['images_fitted']} of {result['images']} images, {result['pixels']} sphere pixels, "
            f"model {result['model']}"
        ]
    lines.append(f"sphere: {result['circle'].get('description', '')}".rstrip())
    unc, lap = result["uncertainty"], result["uncertainty_laplace"]
    ranges = result.get("equivalence") or {}
    header = f"{'parameter':<16}{'value':>10}{'± cluster':>12}{'± Laplace':>12}"
    if ranges:
        header += f"  looks the same (ΔE ≤ {result.get('equivalence_delta_e', 1):g})"
    lines.append(header)
    values_of = result.get("values", {})
    for name in result["free"]:
        value = values_of.get(name, result.get(name))
        if value is None:
            continue
        values = value if isinstance(value, list) else [value]
        sds = unc[name] if isinstance(unc[name], list) else [unc[name]]
        lsd = lap[name] if isinstance(lap[name], list) else [lap[name]]
        band = ranges.get(name)
        bands = (band if len(values) > 1 else [band]) if band is not None else [None] * len(values)
        for k, (v, sd, ls, b) in enumerate(zip(values, sds, lsd, bands)):
            label = f"{name}[{'rgb'[k]}]" if len(values) == 3 else (f"{name}[{k + 2}]" if len(values) > 1 else name)
            line = f"{label:<16}{v:>10.4f}{sd:>12.4f}{ls:>12.4f}"
            if b is not None:
                line += f"  [{b[0]:.3f}, {b[1]:.3f}]"
            lines.append(line)
    res = result["residual"]
    lines.append(
        f"residual: relative RMS {100 * res['relative_rms']:.1f} %, mean CIEDE2000 {res['delta_e2000_mean']:.2f}, "
        f"verdict: {res['verdict']}"
    )
    if "holdout" in result:
        lines.append(f"held-out images: {len(result['holdout']['held_out'])}")
        lines.append(f"{'model':<14}{'held-out rel. RMS':>18}{'mean CIEDE2000':>16}")
        for name, entry in result["holdout"]["models"].items():
            lines.append(f"{name:<14}{100 * entry['relative_rms']:>17.1f}%{entry['delta_e2000_mean']:>16.2f}")
    stability = result.get("stability")
    if stability:
        verdicts = ", ".join(f"{name} {'agrees' if ok else 'differs'}" for name, ok in stability["agree"].items())
        lines.append(f"stability, two halves of the images: {verdicts or 'nothing compared'}")
        for half in stability["halves"]:
            shown = ", ".join(
                f"{name} {value:.3f}" for name, value in half["values"].items() if not isinstance(value, list)
            )
            lines.append(f"  {half['half']} half ({len(half['images'])} images): {shown}")
        single = stability["single_images"]
        lines.append(
            f"single images disagreeing with the joint fit: {single['disagreeing']} of {len(single['fits'])}"
            + (": " + "; ".join(f"{k} ({n})" for k, n in single["reasons"].items()) if single["reasons"] else "")
        )
    for warning in result["warnings"]:
        lines.append(f"warning [{warning['code']}]: {warning['message']}")
    for note in result["notes"]:
        lines.append(f"note: {note}")
    lines.append(f"wall time {result['wall_time_s']:.2f} s")
    return "\n".join(lines)


def reload_held_out(
    result: dict[str, Any], fit: CaptureFit, capture: Capture
) -> tuple[CaptureSamples, np.ndarray] | None:
    """The images a capture's result held out (``settings.holdout``) read again from
    ``capture``, and the fit's prediction of them (`predict`, as the result's
    ``holdout`` was computed); None when the result holds none out. ``fit`` is the fit
    `reload_capture_fit` gives back."""
    holdout = (result.get("settings") or {}).get("holdout")
    if holdout is None:
        return None
    samples = load_samples(capture)
    if samples.count != result.get("images"):
        raise CaptureError(
            f"the capture now has {samples.count} images, the result was fitted to a capture of {result.get('images')}"
        )
    held = samples.select(holdout_indices(holdout, samples.count))
    predicted, _ = predict(held, fit)
    return held, predicted
