r"""The study on measured materials: how well do Strauss and Phong reproduce real reflectance?

Part 4 of the study (`strauss_fit.study.study.conversions`) compares the models on
images that one of them rendered itself. This module measures them on two kinds of real
data, each read from a path the user gives (the data stay where they are):

5. **MERL materials as Ngan, Durand & Matusik (2005) fitted them** (`merl_expressiveness`).
   Ngan et al. fitted a Lambertian term plus a Cook–Torrance lobe to each of 86 measured
   MERL BRDFs; the BSDF benchmark bbm publishes their parameters (``fits_parsed.json`` /
   ``ngan_cooktorrance.fit``). Each material's BRDF (`strauss_fit.study._bbm`) is
   rendered on the sphere under the study's scenes (`MERL_SCENES`; the mean over
   8 × 8 points of each fully covered pixel, as a camera integrates over its pixels), and
   both models are fitted to each image with the same objective, least squares on linear
   radiance over the same pixels: Strauss by the single-target fit
   (`strauss_fit.fit_many`, the loss held ``"linear"``), Phong by the capture fitter
   (`strauss_fit.fitting.capture.fit_capture_samples` on
   `strauss_fit.fitting.scene_samples.samples_from_scene`, the scene's lights known).
   Strauss is fitted a second time with its default loss (``"auto"``: refitted with the
   Huber loss when the least-squares fit visibly misses), which keeps a highlight it
   cannot reach from pulling the rest of the sphere (``strauss_default``; Phong has no such
   fit to compare it with). A
   material is *matched* when the mean CIEDE2000 over the sphere
   (`strauss_fit.color.delta_e_2000`, as the fitters compute it) is at most 1 (one
   just-noticeable difference) in every scene; its ΔE is the largest over the scenes.
   Strauss's fit is *out of reach* (`out_of_reach`) when it reports
   ``highlight-out-of-reach`` (the target is brighter than any Strauss material can be,
   the bound r_s ≤ 1), or when it pins the colour at 1 or the smoothness at a bound while
   the highlight holds more than `CONCENTRATION` times its share of the residual.
   Materials are classed by name (`material_class`).
6. **Real photographs** (`capture_models`): a capture the capture fitter reads
   (e.g. DiLiGenT's ``ballPNG``) fitted by every model of
   `strauss_fit.fitting.capture.MODELS` on half of its images, the other half predicted
   (held-out error), and each model's lobe parameters fitted on two disjoint halves of
   the fitted images (`strauss_fit.fitting.capture_stability.halves`: stable when each
   half's value lies within the other's perceptual equivalence range).

One material or model that fails is recorded with its error and the others go on.
"""

from __future__ import annotations

import importlib.util
import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import StraussFitError
from ..fitting.options import FitOptions
from ..io.targets import Target
from ..scene.loading import Scene, load_scene
from ._bbm import BBM_COMMIT, SUPERSAMPLE, NganMaterial, render_material

#: The entry of ``fits_parsed.json`` the MERL part reads (bbm's ``fits/ngan_cooktorrance.fit``).
NGAN_FILE = "ngan_cooktorrance"
NGAN_MODEL = "NganCookTorrance"
#: The scenes the MERL materials are rendered and fitted under (``data_synth/scenes``).
MERL_SCENES = ("two_lights.toml", "key_and_fill.toml")
#: The noise level (linear) the Strauss fit's diagnosis assumes for the noise-free renders:
#: about a quarter of an 8-bit sRGB step at mid grey. It sets the fit's verdict and where
#: the residual concentrates, not the fitted values.
MERL_NOISE = 1e-3
#: The fits of each measured material: Strauss and Phong by least squares to the radiance as
#: rendered (the comparison); Strauss with its default loss (``"auto"``: refitted with a
#: robust loss when the least-squares fit visibly misses; the capture fitter's Phong has no
#: other loss); and both by least squares to the image clipped at white, as a camera
#: exposed for the sphere records it (``*_clipped``).
FITTED = ("strauss", "phong", "strauss_default", "strauss_clipped", "phong_clipped")
#: The fits whose out-of-reach share is reported (a clipped target hides the highlight's level).
REACH = ("strauss", "strauss_default")
#: One just-noticeable difference: a material is matched when its mean CIEDE2000 is at most this.
JND = 1.0
#: The highlight (core and wings, `strauss_fit.fitting.diagnosis`) holds the residual when
#: its share of χ² exceeds this multiple of its share of the pixels (the diagnosis's own rule).
CONCENTRATION = 1.5
#: Material classes, by name keyword; the first class with a keyword in the name wins,
#: names with none are "other" (woods, stones, ceramics, …).
CLASS_KEYWORDS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("paints", ("paint",)),
    ("fabrics", ("fabric", "felt", "velvet")),
    (
        "metals",
        (
            "aluminium",
            "aluminum",
            "brass",
            "bronze",
            "chrome",
            "copper",
            "nickel",
            "steel",
            "ss440",
            "silver",
            "gold",
            "titanium",
            "tungsten",
        ),
    ),
    (
        "plastics",
        (
            "acrylic",
            "plastic",
            "pvc",
            "delrin",
            "polyethylene",
            "polyurethane",
            "teflon",
            "resin",
            "rubber",
            "neoprene",
            "latex",
            "nylon",
            "phenolic",
        ),
    ),
)
CLASSES = tuple(name for name, _ in CLASS_KEYWORDS) + ("other",)


def material_class(name: str) -> str:
    """The class of a MERL material by its name (`CLASS_KEYWORDS`): paints first (a
    "gold-metallic-paint" is a paint), then fabrics, metals and plastics; else "other"."""
    lowered = name.lower()
    for label, keywords in CLASS_KEYWORDS:
        if any(word in lowered for word in keywords):
            return label
    return "other"


def _triple(value: Any, what: str) -> tuple[float, float, float]:
    values = [float(v) for v in value] if isinstance(value, (list, tuple)) else [float(value)] * 3
    if len(values) != 3 or not all(math.isfinite(v) and v >= 0 for v in values):
        raise StraussFitError(f"{what} must be three finite numbers >= 0, got {value!r}")
    return values[0], values[1], values[2]


def read_ngan_fits(path: str | Path) -> tuple[list[NganMaterial], Path]:
    """The materials of Ngan's Cook–Torrance fits in bbm's parsed form: ``path`` is
    ``fits_parsed.json`` or the folder holding it, ``{file: {material: {lambertian_albedo,
    model, params: {albedo, eta, roughness}}}}``; the entry `NGAN_FILE` (with or
    without ``.fit``) is read. Returns the materials (in the file's order) and the file."""
    path = Path(path)
    file = path / "fits_parsed.json" if path.is_dir() else path
    if not file.is_file():
        raise StraussFitError(f"--merl-fits: {file} does not exist (give fits_parsed.json or its folder)")
    try:
        data = json.loads(file.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise StraussFitError(f"--merl-fits: cannot read {file}: {exc}") from None
    if not isinstance(data, dict):
        raise StraussFitError(f"--merl-fits: {file} is not a JSON object of fit files")
    entry = data.get(NGAN_FILE, data.get(NGAN_FILE + ".fit"))
    if not isinstance(entry, dict) or not entry:
        raise StraussFitError(f"--merl-fits: {file} has no '{NGAN_FILE}' entry (Ngan et al.'s Cook–Torrance fits)")
    materials = []
    for name, record in entry.items():
        try:
            if record.get("model") != NGAN_MODEL:
                raise StraussFitError(f"model is {record.get('model')!r}, not {NGAN_MODEL}")
            params = record["params"]
            f0, roughness = float(params["eta"]), float(params["roughness"])
            if not (0 <= f0 <= 1 and roughness > 0 and math.isfinite(roughness)):
                raise StraussFitError(f"eta (F0) {f0} must lie in [0, 1] and roughness {roughness} be > 0")
            materials.append(
                NganMaterial(
                    str(name),
                    _triple(record["lambertian_albedo"], "lambertian_albedo"),
                    _triple(params["albedo"], "albedo"),
                    f0,
                    roughness,
                )
            )
        except (KeyError, TypeError, ValueError, AttributeError, StraussFitError) as exc:
            raise StraussFitError(f"--merl-fits: {file}: material {name!r}: {exc}") from None
    return materials, file


def scene_path(name: str) -> Path:
    """A scene of ``data_synth/scenes`` (installed beside the package)."""
    spec = importlib.util.find_spec("data_synth")
    roots = list(spec.submodule_search_locations) if spec and spec.submodule_search_locations else []
    roots.append(str(Path(__file__).resolve().parent.parent.parent / "data_synth"))
    for root in roots:
        path = Path(root) / "scenes" / name
        if path.is_file():
            return path
    raise StraussFitError(f"the study scene {name} is missing from the installation")


def study_scene(name: str, size: int) -> Scene:
    """The scene ``name`` at ``size`` × ``size`` pixels (local model)."""
    scene = load_scene(scene_path(name)).resized(size, size)
    return replace(scene, depth=1) if scene.depth != 1 else scene


# --- 5. MERL ----------------------------------------------------------------------------------


def _highlight_share(regions: dict[str, Any]) -> float | None:
    """The highlight's (core and wings) share of χ² over its share of the pixels."""
    if not regions:
        return None
    pixels = sum(r["pixels"] for r in regions.values())
    parts = [regions[k] for k in ("highlight", "highlight wings") if k in regions]
    if not parts or pixels <= 0:
        return None
    pixel_share = sum(r["pixels"] for r in parts) / pixels
    chi2_share = sum(r["share_of_chi2"] for r in parts)
    return chi2_share / pixel_share if pixel_share > 0 else None


def out_of_reach(result: Any) -> tuple[bool, str | None]:
    """Whether a Strauss `FitResult` shows the target out of
    Strauss's reach, and why (module docstring): the ``highlight-out-of-reach`` warning, or
    the colour pinned at 1 or the smoothness at a bound with the residual concentrated in
    the highlight."""
    codes = {w["code"] for w in result.warnings}
    if "highlight-out-of-reach" in codes:
        return True, "highlight-out-of-reach"
    color = np.atleast_1d(np.asarray(result.material.color, dtype=float))
    pinned = []
    for label in result.at_bound:
        if label.startswith("color_") and float(color["rgb".index(label[-1])]) >= 1 - 1e-6:
            pinned.append(label)
        elif label == "smoothness":
            pinned.append(f"smoothness = {float(result.material.smoothness):.3g}")
    share = _highlight_share(result.residual.get("regions") or {})
    if pinned and share is not None and share > CONCENTRATION:
        return True, f"{', '.join(pinned)} at a bound, the highlight holding {share:.3g}× its share of the residual"
    return False, None


def _strauss_record(result: Any) -> dict[str, Any]:
    if not hasattr(result, "residual"):  # a FitFailure
        return {"status": "error", "message": str(getattr(result, "message", result))}
    reach, why = out_of_reach(result)
    material = result.material
    return {
        "status": "ok",
        "delta_e2000_mean": float(result.residual["delta_e2000_mean"]),
        "rms": float(result.residual["rms"]),
        "color": [float(v) for v in np.atleast_1d(np.asarray(material.color))],
        "smoothness": float(material.smoothness),
        "metalness": float(material.metalness),
        "free": list(result.free),
        "at_bound": list(result.at_bound),
        "warnings": sorted({w["code"] for w in result.warnings}),
        "highlight_residual_concentration": _highlight_share(result.residual.get("regions") or {}),
        "out_of_reach": reach,
        "out_of_reach_reason": why,
    }


def _phong_record(scene: Scene, target: Target, clip: float | None = None) -> dict[str, Any]:
    """Phong fitted by the capture fitter; with ``clip``, to the values at most ``clip``
    (pixels with a brighter channel left out, as saturated), its ΔE taken over every pixel."""
    from ..fitting.capture import CaptureFitOptions, delta_e_mean, fit_capture_samples, relative_rms
    from ..fitting.scene_samples import samples_from_scene

    try:
        samples = samples_from_scene(scene, target)
        everything = samples.usable
        if clip is not None:
            keep = np.all(samples.values <= clip, axis=-1, keepdims=True)
            samples = replace(samples, usable=samples.usable & keep)
        fit = fit_capture_samples(samples, CaptureFitOptions(model="phong", exposure="fixed"))
        residual = (fit.predicted - samples.values)[samples.usable]
        return {
            "status": "ok",
            "delta_e2000_mean": delta_e_mean(fit.predicted, samples.values, everything),
            "rms": float(np.sqrt(np.mean(residual**2))),
            "relative_rms": relative_rms(fit.predicted, samples.values, samples.usable),
            **fit.values(),
            "solver_status": fit.status,
        }
    except Exception as exc:  # one material that breaks the fit fails alone
        return {"status": "error", "message": f"{type(exc).__name__}: {exc}"}


def _clipped_record(result: Any, image: np.ndarray, covered: np.ndarray) -> dict[str, Any]:
    """A Strauss fit to a clipped target, its ΔE taken over every covered pixel (the fit's
    own is over the pixels it used)."""
    from ..color import delta_e_2000

    record = _strauss_record(result)
    if record["status"] == "ok":
        fitted = np.asarray(result.fitted_image)
        record["delta_e2000_mean"] = float(np.mean(delta_e_2000(fitted[covered], image[covered])))
    return record


def _worst(records: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """A material's figures over its scenes: the largest ΔE, out of reach in any scene."""
    ok = [r for r in records if r["status"] == "ok"]
    if len(ok) < len(records) or not ok:
        errors = [r.get("message") for r in records if r["status"] != "ok"]
        return {"status": "error", "message": "; ".join(str(e) for e in errors)}
    out = {"status": "ok", "delta_e2000_mean": max(r["delta_e2000_mean"] for r in ok)}
    if "out_of_reach" in ok[0]:
        out["out_of_reach"] = any(r["out_of_reach"] for r in ok)
    return out


def _summary(materials: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Share matched, median ΔE (and for Strauss the share out of reach) of some materials."""
    out: dict[str, Any] = {"materials": len(materials)}
    for model in FITTED:
        if not all(model in m for m in materials):
            continue
        ok = [m[model] for m in materials if m[model]["status"] == "ok"]
        delta = np.array([r["delta_e2000_mean"] for r in ok])
        entry: dict[str, Any] = {
            "fitted": len(ok),
            "errors": len(materials) - len(ok),
            "matched": float(np.mean(delta <= JND)) if delta.size else None,
            "median_delta_e": float(np.median(delta)) if delta.size else None,
            "p90_delta_e": float(np.percentile(delta, 90)) if delta.size else None,
        }
        if model in REACH:
            entry["out_of_reach"] = float(np.mean([r["out_of_reach"] for r in ok])) if ok else None
            reach = [r["delta_e2000_mean"] for r in ok if r["out_of_reach"]]
            entry["median_delta_e_out_of_reach"] = float(np.median(reach)) if reach else None
        out[model] = entry
    both = [m for m in materials if m["strauss"]["status"] == "ok" and m["phong"]["status"] == "ok"]
    out["strauss_better"] = (
        float(np.mean([m["strauss"]["delta_e2000_mean"] < m["phong"]["delta_e2000_mean"] for m in both]))
        if both
        else None
    )
    both = [
        m
        for m in materials
        if m.get("strauss_clipped", {}).get("status") == "ok" and m.get("phong_clipped", {}).get("status") == "ok"
    ]
    out["strauss_better_clipped"] = (
        float(
            np.mean([m["strauss_clipped"]["delta_e2000_mean"] < m["phong_clipped"]["delta_e2000_mean"] for m in both])
        )
        if both
        else None
    )
    return out


def merl_expressiveness(
    path: str | Path,
    *,
    size: int,
    scenes: Sequence[str] = MERL_SCENES,
    supersample: int = SUPERSAMPLE,
    say: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Part 5 (module docstring): every material of Ngan's Cook–Torrance fits at ``path``
    rendered under ``scenes`` at ``size`` pixels and fitted by Strauss and Phong."""
    say = say or (lambda message: None)
    started = time.perf_counter()
    materials, file = read_ngan_fits(path)
    say(f"measured materials: {len(materials)} of Ngan et al.'s Cook–Torrance fits from {file}")
    per_scene = {name: _merl_scene(materials, name, size, supersample, say) for name in scenes}
    rows = _material_rows(materials, per_scene, scenes)
    by_class = {label: _summary([r for r in rows if r["class"] == label]) for label in CLASSES}
    by_scene = {name: _summary([{key: r["scenes"][name][key] for key in FITTED} for r in rows]) for name in scenes}
    return {
        "source": str(file),
        "fits": NGAN_FILE,
        "bbm_commit": BBM_COMMIT,
        "scenes": list(scenes),
        "image_size": size,
        "supersample": supersample,
        "noise_assumed": MERL_NOISE,
        "jnd": JND,
        "class_keywords": {label: list(words) for label, words in CLASS_KEYWORDS},
        "all": _summary(rows),
        "by_class": by_class,
        "by_scene": by_scene,
        "materials": rows,
        "time_s": time.perf_counter() - started,
    }


def _merl_scene(
    materials: Sequence[NganMaterial], scene_name: str, size: int, supersample: int, say: Callable[[str], None]
) -> list[dict[str, Any]]:
    """One record per material under the scene ``scene_name``: its render's figures and
    every fit of `FITTED` (a material that could not be rendered: an error in each)."""
    scene = study_scene(scene_name, size)
    targets, clipped, levels, records = _render_targets(materials, scene, supersample)
    strauss = _fit_strauss(targets, clipped, scene, scene_name, size, say)
    say(f"measured materials, {scene_name}: fitting Phong to {len(strauss['strauss'])} images")
    t0 = time.perf_counter()
    for k, (target, record) in enumerate(zip(targets, records)):
        if target is None:
            error = {"status": "error", "message": record["render_error"]}
            record.update(dict.fromkeys(FITTED, error))
            continue
        record["strauss"] = _strauss_record(strauss["strauss"][k])
        record["strauss_default"] = _strauss_record(strauss["strauss_default"][k])
        record["phong"] = _phong_record(scene, target)
        if clipped[k] is None:  # nothing above white: the fits to the target stand
            record["strauss_clipped"], record["phong_clipped"] = record["strauss"], record["phong"]
        else:
            record["strauss_clipped"] = _clipped_record(
                strauss["strauss_clipped"][k], target.pixels, np.asarray(target.usable)
            )
            record["phong_clipped"] = _phong_record(scene, target, clip=levels[k])
        if (k + 1) % max(1, len(materials) // 8) == 0 or k + 1 == len(materials):
            say(
                f"measured materials, {scene_name}: Phong [{k + 1}/{len(materials)}] ({time.perf_counter() - t0:.0f} s)"
            )
    return records


def _render_targets(
    materials: Sequence[NganMaterial], scene: Scene, supersample: int
) -> tuple[list[Target | None], list[Target | None], list[float], list[dict[str, Any]]]:
    """Every material rendered under ``scene``: its target, the target clipped at white
    (None when nothing is above white), the white level, and its record so far (peak, white,
    pixels clipped; or the render's error, the target then None)."""
    targets: list[Target | None] = []
    clipped: list[Target | None] = []  # None: nothing above white, the fit to the target stands
    levels: list[float] = []
    records: list[dict[str, Any]] = []
    for material in materials:
        try:
            image, usable = render_material(material, scene, supersample)
            if not np.all(np.isfinite(image)):
                raise StraussFitError("the rendered image holds a NaN or infinite value")
            targets.append(Target(image, usable, material.name, "linear", 0, 0))
            # white as the ΔE metric sees it (strauss_fit.color.delta_e_2000): 1, or the 99th percentile
            level = max(1.0, float(np.percentile(image[usable], 99)))
            over = usable & np.any(image > level, axis=-1)
            levels.append(level)
            clipped.append(
                Target(image, usable & ~over, material.name, "linear", int(over.sum()), 0) if over.any() else None
            )
            records.append({"peak": float(image.max()), "white": level, "clipped_pixels": int(over.sum())})
        except Exception as exc:
            targets.append(None)
            clipped.append(None)
            levels.append(math.nan)
            records.append({"render_error": f"{type(exc).__name__}: {exc}"})
    return targets, clipped, levels, records


def _fit_strauss(
    targets: list[Target | None],
    clipped: list[Target | None],
    scene: Scene,
    scene_name: str,
    size: int,
    say: Callable[[str], None],
) -> dict[str, dict[int, Any]]:
    """Strauss's three fits of the rendered materials, in batches: by least squares, with
    its default loss, and by least squares to the targets clipped at white; each by
    material index (those without a target left out)."""
    from ..fitting.batch import fit_many

    least_squares = FitOptions(noise=MERL_NOISE, edge_pixels="exclude", loss="linear")
    jobs = {
        "strauss": (targets, least_squares, "least squares"),
        "strauss_default": (targets, FitOptions(noise=MERL_NOISE, edge_pixels="exclude"), "default loss"),  # "auto"
        "strauss_clipped": (clipped, least_squares, "least squares, clipped at white"),
    }
    strauss: dict[str, dict[int, Any]] = {}
    for key, (images, options, what) in jobs.items():
        fit_index = [i for i, t in enumerate(images) if t is not None]
        label = f"{scene_name}: Strauss ({what})"
        step = max(1, len(fit_index) // 8)

        def progress(p, label=label, every=step):
            if p.done == p.total or p.done % every == 0:
                say(f"measured materials, {label} [{p.done}/{p.total}] ({p.failed} failed, {p.elapsed_s:.0f} s)")

        say(f"measured materials, {label}: fitting {len(fit_index)} images ({size} px)")
        fitted = fit_many([images[i] for i in fit_index], scene, options, progress=progress) if fit_index else []
        strauss[key] = dict(zip(fit_index, fitted))
    return strauss


def _material_rows(
    materials: Sequence[NganMaterial], per_scene: dict[str, list[dict[str, Any]]], scenes: Sequence[str]
) -> list[dict[str, Any]]:
    """One row per material: its parameters and class, each fit's worst over the scenes
    (`_worst`), and its record in every scene."""
    rows = []
    for i, material in enumerate(materials):
        scenes_of = {name: per_scene[name][i] for name in scenes}
        rows.append(
            {
                **material.to_dict(),
                "class": material_class(material.name),
                **{key: _worst([r[key] for r in scenes_of.values()]) for key in FITTED},
                "scenes": scenes_of,
            }
        )
    return rows


# --- 6. real photographs ----------------------------------------------------------------------


def capture_models(
    path: str | Path,
    *,
    holdout: str = "2",
    models: Sequence[str] | None = None,
    say: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Part 6 (module docstring): every model of `strauss_fit.fitting.capture.MODELS`
    fitted to the capture at ``path`` without the images ``holdout`` names (every second
    by default), its error on those, and its lobe parameters on two disjoint halves of the
    fitted images."""
    from ..capture._manifest import open_capture
    from ..capture._samples import load_samples
    from ..fitting.capture import MODELS, CaptureFitOptions
    from ..fitting.capture_result import fit_capture, holdout_indices
    from ..fitting.capture_stability import compared, halves

    say = say or (lambda message: None)
    started = time.perf_counter()
    say(f"real photographs: reading the capture {path}")
    samples = load_samples(open_capture([str(path)]))
    held = holdout_indices(holdout, samples.count)
    train = samples.select([i for i in range(samples.count) if i not in set(held)])
    say(
        f"real photographs: {len(samples.rows)} sphere pixels × {samples.count} images; "
        f"fitting {train.count}, predicting {len(held)}"
    )
    out: dict[str, Any] = {}
    for model in models or MODELS:
        t0 = time.perf_counter()
        options = CaptureFitOptions(model=model)
        entry: dict[str, Any] = {"status": "ok"}
        try:
            say(f"real photographs: {model}: fitting and predicting the held-out images")
            result = fit_capture(samples, options, holdout=holdout, compare=())
            validation = result["holdout"]["models"][model]
            entry.update(
                values=result["values"],
                fit={
                    "relative_rms": result["residual"]["relative_rms"],
                    "delta_e2000_mean": result["residual"]["delta_e2000_mean"],
                    "verdict": result["residual"].get("verdict"),
                },
                held_out={
                    "relative_rms": validation["relative_rms"],
                    "delta_e2000_mean": validation["delta_e2000_mean"],
                },
                warnings=sorted({w["code"] for w in result["warnings"]}),
            )
        except Exception as exc:
            entry = {"status": "error", "message": f"{type(exc).__name__}: {exc}"}
        if entry["status"] == "ok" and not compared(model):
            entry["stability"] = None  # no lobe parameter the stability check compares
        elif entry["status"] == "ok":
            try:
                say(f"real photographs: {model}: stability over two disjoint halves")
                split = halves(train, options)
                entry["stability"] = {
                    "parameters": list(compared(model)),
                    "halves": [{"half": h["half"], "values": h["values"]} for h in split["halves"]],
                    "agree": split["agree"],
                    "stable": split["stable"],
                    "equivalence": [h["equivalence"] for h in split["halves"]],
                    "delta_e": split["delta_e"],
                }
            except Exception as exc:
                entry["stability"] = {"status": "error", "message": f"{type(exc).__name__}: {exc}"}
        entry["time_s"] = time.perf_counter() - t0
        out[model] = entry
    return {
        "source": str(path),
        "pixels": int(len(samples.rows)),
        "images": int(samples.count),
        "fitted_images": int(train.count),
        "held_out_images": len(held),
        "holdout": holdout,
        "models": out,
        "time_s": time.perf_counter() - started,
    }
