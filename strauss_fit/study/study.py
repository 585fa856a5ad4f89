r"""The intuitive-parameter study: does Strauss's parameterisation beat Phong's, in numbers?

Strauss (1990) claims that his parameters are more intuitive and more consistent than
Phong's: a user cannot set values that create energy, each parameter does one thing, and
the parameters are closer to physics. `run_study` measures four aspects, for both
models, and `strauss_fit.reporting.study_report` writes them up with conclusions drawn from
the numbers.

1. **Consistency** (`consistency`): parameter sets drawn as a novice would — Phong
   ka, kd, ks uniform in [0, 1], n uniform in [1, 1000], colours uniform in [0, 1]³;
   Strauss C, s, m, t each uniform in its range (n is irrelevant to reflectance) — and
   the fraction whose directional-hemispherical reflectance (`strauss_fit.models.albedo`)
   exceeds 1 at some angle of incidence up to 60°, 80° and 89°. A set counts only if it
   exceeds 1 by more than the quadrature's stated accuracy. Because the fraction for
   Phong depends mostly on how n is drawn, a log-uniform n is reported too.
2. **Independence** (`independence`): on the same sphere images (the conversion
   scene, `strauss_fit.convert.converter`; Phong-rendered and Strauss-rendered materials),
   the Fisher information `\mathcal I = J^\top J/\sigma^2` of each model at its
   parameters for that image (the truth for its own renders, the fitted conversion for
   the other model's), J from ``jax.jacfwd`` of the rendered pixels, σ = 1 % of the
   image's 98th percentile. Reported: the posterior correlations
   (`\mathcal I^{-1}` normalised), the condition number of `\mathcal I` with
   every parameter on a unit range (Strauss: C, s, m; Phong: D = kd·Cd, S = ks·Cs, and
   u = log n / log 10000), and the scale-free condition number of the correlation form
   `D^{-1/2}\mathcal I D^{-1/2}` (invariant to any per-parameter rescaling or
   reparameterisation, so it measures dependence alone). The parameterisations users
   actually set are checked too: Phong's kd, Cd, ks, Cs, n (where only products reach
   the image) and Strauss's C, s, m, t (t in a local image only dims).
3. **Uniformity** (`uniformity`): for base materials drawn as in 1 (Phong's n
   log-uniform here, so that the bases' highlights are wider than a pixel), each parameter
   is swept across its range in equal steps and the CIEDE2000 difference (mean over the
   sphere) between successive images is recorded; a perfectly even parameter changes the
   image by the same amount per step. Reported per parameter: the coefficient of
   variation of the steps, the largest step over the mean step, and where the largest
   step lies. Phong's exponent is swept linearly (as drawn in 1) and geometrically.
4. **Expressiveness** (`conversions`): Phong materials (drawn as in 1) converted to
   Strauss and Strauss materials (opaque, drawn as in 1) converted to Phong, with the
   distribution of the residual CIEDE2000.

Part 4's images are rendered by one of the two models; `strauss_fit.study.real` adds,
when given the data, 5. the same question on measured materials (the MERL BRDFs as Ngan et
al. fitted them) and 6. on real photographs (held-out error and stability of every capture
model).
"""

from __future__ import annotations

import dataclasses
import math
import platform
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..color import delta_e_2000
from ..convert.converter import Converter, Entry, Settings, conversion_scene
from ..convert.phong_fit import LOG_MAX_EXPONENT, vector_from_material
from ..errors import StraussFitError
from ..fitting.identifiability import reference_noise_level
from ..fitting.options import FitOptions
from ..fitting.problem import Problem, build_problem
from ..io.targets import Target
from ..models.albedo import DEFAULT_NODES, phong_reflectance, quadrature_error, strauss_reflectance
from ..models.material import FRACTION_NAMES, REFLECTION_NAMES, Material
from ..models.phong import PhongMaterial
from ..precision import uses_float64
from ..rendering.strauss import plan_render
from ..stats import laplace

#: Novice ranges of the draws.
PHONG_EXPONENT_RANGE = (1.0, 1000.0)
STRAUSS_IOR_RANGE = (1.0, 3.0)
#: Angle caps (degrees) for the consistency fractions.
CAPS = (60.0, 80.0, 89.0)
#: The cap the conclusions quote.
HEADLINE_CAP = 80.0


@dataclass(frozen=True)
class StudyConfig:
    """How big the study is. ``tiny`` is for tests, ``small`` (default) takes a few
    minutes on two cores, ``full`` is the thorough run."""

    name: str
    consistency_count: int
    angles: tuple[float, ...]
    nodes: int
    image_size: int
    conversion_count: int
    starts: int
    uniformity_bases: int
    uniformity_steps: int
    uniformity_size: int
    seed: int = 1990
    #: Image size of the measured-material part (5), when it runs.
    merl_image_size: int = 48

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def _grid(step: float) -> tuple[float, ...]:
    return tuple(float(a) for a in np.arange(0.0, 89.0, step)) + (89.0,)


SIZES = {
    "tiny": StudyConfig("tiny", 60, (0.0, 30.0, 60.0, 80.0, 89.0), 24, 24, 3, 4, 1, 6, 24, merl_image_size=24),
    "small": StudyConfig("small", 1000, _grid(5.0), DEFAULT_NODES, 32, 16, 4, 4, 21, 48, merl_image_size=48),
    "full": StudyConfig("full", 4000, _grid(2.0), DEFAULT_NODES, 64, 96, 4, 12, 41, 96, merl_image_size=64),
}


def study_config(size: str, seed: int | None = None) -> StudyConfig:
    if size not in SIZES:
        raise StraussFitError(f"unknown study size {size!r}; expected one of {', '.join(SIZES)}")
    config = SIZES[size]
    return dataclasses.replace(config, seed=seed) if seed is not None else config


# --- draws ------------------------------------------------------------------------------------


def draw_phong(rng: np.random.Generator, count: int, *, log_exponent: bool = False) -> dict[str, np.ndarray]:
    """Novice Phong sets: ka, kd, ks ~ U[0, 1]; n ~ U[1, 1000] (or log-uniform); Cd, Cs ~ U[0, 1]³."""
    low, high = PHONG_EXPONENT_RANGE
    exponent = (
        np.exp(rng.uniform(math.log(low), math.log(high), count)) if log_exponent else rng.uniform(low, high, count)
    )
    return {
        "ka": rng.uniform(0, 1, count),
        "kd": rng.uniform(0, 1, count),
        "ks": rng.uniform(0, 1, count),
        "exponent": exponent,
        "diffuse_color": rng.uniform(0, 1, (count, 3)),
        "specular_color": rng.uniform(0, 1, (count, 3)),
    }


def draw_strauss(rng: np.random.Generator, count: int, *, opaque: bool = False) -> dict[str, np.ndarray]:
    """Strauss sets, every parameter uniform in its range (t = 0 with ``opaque``; n in [1, 3])."""
    return {
        "color": rng.uniform(0, 1, (count, 3)),
        "smoothness": rng.uniform(0, 1, count),
        "metalness": rng.uniform(0, 1, count),
        "transparency": np.zeros(count) if opaque else rng.uniform(0, 1, count),
        "ior": rng.uniform(*STRAUSS_IOR_RANGE, count),
    }


def _phong_material(draw: dict[str, np.ndarray], i: int) -> PhongMaterial:
    return PhongMaterial(
        ka=float(draw["ka"][i]),
        kd=float(draw["kd"][i]),
        ks=float(draw["ks"][i]),
        exponent=float(draw["exponent"][i]),
        diffuse_color=draw["diffuse_color"][i].tolist(),
        specular_color=draw["specular_color"][i].tolist(),
    )


def _strauss_material(draw: dict[str, np.ndarray], i: int) -> Material:
    return Material(
        color=draw["color"][i].tolist(),
        smoothness=float(draw["smoothness"][i]),
        metalness=float(draw["metalness"][i]),
        transparency=float(draw["transparency"][i]),
        ior=float(draw["ior"][i]),
    )


# --- 1. consistency ---------------------------------------------------------------------------


def _phong_rho(draw, angles, nodes):
    return phong_reflectance(
        draw["kd"], draw["ks"], draw["exponent"], draw["diffuse_color"], draw["specular_color"], angles, nodes=nodes
    )


def _strauss_rho(draw, angles, nodes):
    return strauss_reflectance(
        draw["color"], draw["smoothness"], draw["metalness"], draw["transparency"], angles, nodes=nodes
    )


def _energy_summary(rho: np.ndarray, angles: np.ndarray, tolerance: float) -> dict[str, Any]:
    """Fractions of sets with max-channel ρ > 1 + tolerance at some angle ≤ each cap."""
    peak = rho.max(axis=2)  # (M, A)
    out: dict[str, Any] = {"count": int(rho.shape[0]), "caps": {}}
    for cap in CAPS:
        within = angles <= cap + 1e-9
        worst = peak[:, within].max(axis=1)
        over = worst > 1 + tolerance
        excess = worst[over] - 1
        out["caps"][f"{cap:g}"] = {
            "fraction": float(over.mean()),
            "borderline": float((np.abs(worst - 1) <= tolerance).mean()),
            "excess_median": float(np.median(excess)) if excess.size else 0.0,
            "excess_p95": float(np.percentile(excess, 95)) if excess.size else 0.0,
            "excess_max": float(excess.max()) if excess.size else 0.0,
        }
    out["by_angle"] = [float((peak[:, : k + 1].max(axis=1) > 1 + tolerance).mean()) for k in range(angles.size)]
    out["worst_at_angle_median"] = [float(v) for v in np.median(peak, axis=0)]
    return out


def consistency(config: StudyConfig, rng: np.random.Generator, say: Callable[[str], None]) -> dict[str, Any]:
    angles = np.asarray(config.angles)
    n = config.consistency_count
    say(f"consistency: albedo of {n} Phong and {n} Strauss sets at {angles.size} angles of incidence")
    phong = draw_phong(rng, n)
    phong_log = draw_phong(rng, n, log_exponent=True)
    strauss = draw_strauss(rng, n)
    rho_p = _phong_rho(phong, angles, config.nodes)
    rho_pl = _phong_rho(phong_log, angles, config.nodes)
    rho_s = _strauss_rho(strauss, angles, config.nodes)
    # accuracy: node doubling on a subset of each draw, and the closed forms
    sub = min(n, 48)
    take = lambda d: {k: v[:sub] for k, v in d.items()}
    errors = [
        quadrature_error(
            lambda a, nodes, d=take(phong): _phong_rho(d, a, nodes), angles_deg=angles, nodes=config.nodes
        ),
        quadrature_error(
            lambda a, nodes, d=take(phong_log): _phong_rho(d, a, nodes), angles_deg=angles, nodes=config.nodes
        ),
        quadrature_error(
            lambda a, nodes, d=take(strauss): _strauss_rho(d, a, nodes), angles_deg=angles, nodes=config.nodes
        ),
    ]
    lambert = phong_reflectance([0.8], [0.0], [1.0], [[1.0, 1.0, 1.0]], [[1.0, 1.0, 1.0]], angles, nodes=config.nodes)
    lambert_error = float(np.max(np.abs(lambert - 0.8)))
    exponents = np.array([1.0, 10.0, 100.0, 1000.0])
    normal = phong_reflectance(
        np.zeros(4), np.ones(4), exponents, np.ones((4, 3)), np.ones((4, 3)), [0.0], nodes=config.nodes
    )[:, 0, 0]
    lobe_error = float(np.max(np.abs(normal - 2 / (exponents + 2))))
    accuracy = max(errors + [lambert_error, lobe_error])
    tolerance = max(accuracy, 1e-9)
    result = {
        "angles_deg": angles.tolist(),
        "nodes": config.nodes,
        "accuracy": {
            "stated": accuracy,
            "doubling_phong": errors[0],
            "doubling_phong_log": errors[1],
            "doubling_strauss": errors[2],
            "lambertian_closed_form": lambert_error,
            "phong_normal_incidence_closed_form": lobe_error,
        },
        "phong": _energy_summary(rho_p, angles, tolerance),
        "phong_log_exponent": _energy_summary(rho_pl, angles, tolerance),
        "strauss": _energy_summary(rho_s, angles, tolerance),
    }
    # who creates energy (at the headline cap)
    within = angles <= HEADLINE_CAP + 1e-9
    over_s = rho_s[:, within].max(axis=(1, 2)) > 1 + tolerance
    over_p = rho_p[:, within].max(axis=(1, 2)) > 1 + tolerance
    over_pl = rho_pl[:, within].max(axis=(1, 2)) > 1 + tolerance
    result["strauss"]["offenders"] = _describe(
        strauss, over_s, FRACTION_NAMES, {"max_color": strauss["color"].max(axis=1)}
    )
    result["phong"]["offenders"] = _describe(
        phong,
        over_p,
        ("kd", "ks", "exponent"),
        {"max_kd_cd": (phong["kd"][:, None] * phong["diffuse_color"]).max(axis=1)},
    )
    result["phong_log_exponent"]["offenders"] = _describe(
        phong_log,
        over_pl,
        ("kd", "ks", "exponent"),
        {"max_kd_cd": (phong_log["kd"][:, None] * phong_log["diffuse_color"]).max(axis=1)},
    )
    # white matte Strauss (s = m = t = 0, C = 1): excess from the off-specular term k_j j alone
    white = strauss_reflectance([[1.0, 1.0, 1.0]], [0.0], [0.0], [0.0], angles, nodes=config.nodes)[0, :, 0]
    result["strauss_white_matte_albedo"] = white.tolist()
    return result


def _describe(draw: dict, mask: np.ndarray, keys: tuple[str, ...], extra: dict[str, np.ndarray]) -> dict[str, Any]:
    """Medians of some parameters among the sets that create energy and among all."""
    columns = {k: draw[k] for k in keys}
    columns.update(extra)
    out = {}
    for key, values in columns.items():
        out[key] = {
            "median_offenders": float(np.median(values[mask])) if mask.any() else None,
            "median_all": float(np.median(values)),
        }
    return out


# --- 4. expressiveness (the conversions) ---------------------------------------------------


def _distribution(values: list[float]) -> dict[str, Any]:
    v = np.asarray(values, dtype=float)
    if v.size == 0:
        return {"count": 0}
    return {
        "count": int(v.size),
        "median": float(np.median(v)),
        "p90": float(np.percentile(v, 90)),
        "max": float(v.max()),
        "mean": float(v.mean()),
        "below_1": float((v < 1).mean()),
        "below_2": float((v < 2).mean()),
        "below_5": float((v < 5).mean()),
    }


def conversions(config: StudyConfig, rng: np.random.Generator, say: Callable[[str], None]) -> dict[str, Any]:
    """Convert novice Phong sets to Strauss and opaque uniform Strauss sets to Phong."""
    count = config.conversion_count
    scene = conversion_scene(size=config.image_size)
    converter = Converter(scene, Settings(starts=config.starts))
    phong = draw_phong(rng, count)
    strauss = draw_strauss(rng, count, opaque=True)
    phong_entries = [Entry(f"phong-{i:03d}", "study draw", _phong_material(phong, i)) for i in range(count)]
    strauss_entries = [Entry(f"strauss-{i:03d}", "study draw", _strauss_material(strauss, i)) for i in range(count)]

    def progress(label):
        return lambda done, total, message: say(f"{label}: [{done}/{total}] {message}")

    say(f"expressiveness: converting {count} Phong materials to Strauss ({config.image_size} px images)")
    p2s = converter.phong_to_strauss(phong_entries, progress("phong2strauss"))
    say(f"expressiveness: converting {count} Strauss materials to Phong")
    s2p = converter.strauss_to_phong(strauss_entries, progress("strauss2phong"))
    rho = _phong_rho(phong, np.asarray([a for a in config.angles if a <= HEADLINE_CAP]), config.nodes)
    conserving = rho.max(axis=(1, 2)) <= 1
    ok_p = [r for r in p2s if r["status"] == "ok"]
    ok_s = [r for r in s2p if r["status"] == "ok"]
    expressiveness = {
        "scene": converter.describe(),
        "phong_to_strauss": {
            "delta_e2000_mean": _distribution([r["residual"]["delta_e2000_mean"] for r in ok_p]),
            "rms": _distribution([r["residual"]["rms"] for r in ok_p]),
            "errors": len(p2s) - len(ok_p),
            "energy_conserving_sources": _distribution(
                [r["residual"]["delta_e2000_mean"] for r, c in zip(p2s, conserving) if r["status"] == "ok" and c]
            ),
            "energy_creating_sources": _distribution(
                [r["residual"]["delta_e2000_mean"] for r, c in zip(p2s, conserving) if r["status"] == "ok" and not c]
            ),
        },
        "strauss_to_phong": {
            "delta_e2000_mean": _distribution([r["residual"]["delta_e2000_mean"] for r in ok_s]),
            "rms": _distribution([r["residual"]["rms"] for r in ok_s]),
            "errors": len(s2p) - len(ok_s),
        },
        "worst_matched": {
            "phong_to_strauss": _worst(
                p2s,
                {
                    "exponent": phong["exponent"],
                    "ks": phong["ks"],
                    "max_kd_cd": (phong["kd"][:, None] * phong["diffuse_color"]).max(axis=1),
                },
            ),
            "strauss_to_phong": _worst(
                s2p,
                {
                    "smoothness": strauss["smoothness"],
                    "metalness": strauss["metalness"],
                    "max_color": strauss["color"].max(axis=1),
                },
            ),
        },
        "materials": {
            "phong_to_strauss": [_brief(r) for r in p2s],
            "strauss_to_phong": [_brief(r) for r in s2p],
        },
    }
    return {
        "converter": converter,
        "phong_entries": phong_entries,
        "strauss_entries": strauss_entries,
        "p2s": p2s,
        "s2p": s2p,
        "summary": expressiveness,
    }


def _worst(results: list[dict[str, Any]], sources: dict[str, np.ndarray]) -> dict[str, Any]:
    """Medians of source parameters among the worst-matched quarter (by mean ΔE) and among all."""
    ok = np.array([r["status"] == "ok" for r in results])
    if not ok.any():
        return {}
    delta = np.array([r["residual"]["delta_e2000_mean"] if r["status"] == "ok" else np.nan for r in results])
    order = np.argsort(np.where(ok, -delta, np.inf))
    worst = order[: max(1, int(ok.sum()) // 4)]
    return {
        key: {"median_worst": float(np.median(values[worst])), "median_all": float(np.median(values[ok]))}
        for key, values in sources.items()
    } | {"worst_count": int(worst.size)}


def _brief(result: dict[str, Any]) -> dict[str, Any]:
    out = {"name": result["name"], "status": result["status"]}
    if result["status"] != "ok":
        out["message"] = result.get("message")
        return out
    out["input"] = result["input"].get("phong") or result["input"].get("strauss")
    out["output"] = result.get("strauss") or result.get("phong")
    out["residual"] = result["residual"]
    return out


# --- 2. independence --------------------------------------------------------------------------

STRAUSS_LABELS = ["C_r", "C_g", "C_b", "s", "m"]
STRAUSS_T_LABELS = STRAUSS_LABELS + ["t"]
PHONG_LABELS = ["D_r", "D_g", "D_b", "S_r", "S_g", "S_b", "log n"]
PHONG_USER_LABELS = ["kd", "Cd_r", "Cd_g", "Cd_b", "ks", "Cs_r", "Cs_g", "Cs_b", "n"]


def _fisher_metrics(j: np.ndarray, sigma: float, labels: list[str]) -> dict[str, Any]:
    fisher = laplace.information(j) / sigma**2
    diag = np.diag(fisher)
    dead = diag <= 0
    scale = np.sqrt(np.where(dead, 1.0, diag))
    corr_form = fisher / np.outer(scale, scale)
    eig = np.linalg.eigvalsh(corr_form)
    eig_raw = np.linalg.eigvalsh(fisher)
    p = len(labels)
    rank = (
        int(np.sum(eig > eig.max() * 1e-10))
        if not dead.any()
        else int(np.sum(eig > eig.max() * 1e-10)) - int(dead.sum())
    )
    cond_free = float(eig.max() / eig.min()) if eig.min() > eig.max() * 1e-14 and not dead.any() else math.inf
    cond_raw = float(eig_raw.max() / eig_raw.min()) if eig_raw.min() > eig_raw.max() * 1e-16 else math.inf
    covariance = laplace.covariance(fisher, rcond=1e-12)
    sd = laplace.deviations(covariance)
    corr = laplace.correlation(covariance)
    off = np.abs(corr - np.eye(p))
    i, k = np.unravel_index(int(np.argmax(off)), off.shape)
    return {
        "rank": min(rank, p),
        "parameters": p,
        "condition_scale_free": cond_free,
        "condition_unit_range": cond_raw,
        "max_abs_correlation": float(off.max()),
        "max_pair": [labels[i], labels[k]],
        "mean_abs_correlation": float(off[np.triu_indices(p, 1)].mean()),
        "sd": sd.tolist(),
        "abs_correlation": np.abs(corr).tolist(),
    }


def _phong_user_transform(x: np.ndarray, material: dict[str, Any]) -> np.ndarray:
    """d(D, S, u)/d(kd, Cd, ks, Cs, n) at a Phong material (scalar kd, ks)."""
    kd, ks = float(material["kd"]), float(material["ks"])
    cd, cs = np.asarray(material["diffuse_color"]), np.asarray(material["specular_color"])
    n = float(material["exponent"])
    t = np.zeros((7, 9))
    t[0:3, 0] = cd
    t[0:3, 1:4] = kd * np.eye(3)
    t[3:6, 4] = cs
    t[3:6, 5:8] = ks * np.eye(3)
    t[6, 8] = 1.0 / (max(n, 1e-12) * LOG_MAX_EXPONENT)
    return t


#: The four parameterisations whose Fisher information part 2 reports, with their labels.
PARAMETERISATIONS = (
    ("strauss", STRAUSS_LABELS),
    ("strauss_with_t", STRAUSS_T_LABELS),
    ("phong", PHONG_LABELS),
    ("phong_user", PHONG_USER_LABELS),
)
#: The figures of each image's Fisher information the study keeps per image.
PER_IMAGE_KEYS = ("condition_scale_free", "condition_unit_range", "max_abs_correlation", "max_pair", "rank")


def independence(run: dict[str, Any], say: Callable[[str], None]) -> dict[str, Any]:
    """Part 2 (module docstring): the Fisher information of both models, in every
    parameterisation, on the images of the conversions that succeeded (``run``: what
    `conversions` returns), summarised over the images and kept per image."""
    converter: Converter = run["converter"]
    say("independence: Fisher information of both models on the same images")
    with_t = _problem_with_transparency(converter)
    records = [
        _image_fisher(converter, with_t, origin, target, strauss_values, phong_values)
        for origin, target, strauss_values, phong_values in _independence_images(run)
    ]
    return {
        "images": len(records),
        "by_origin": {o: sum(r["origin"] == o for r in records) for o in ("phong", "strauss")},
        "summary": _independence_summary(records),
        "per_image": [
            {"origin": r["origin"], **{k: {kk: r[k][kk] for kk in PER_IMAGE_KEYS} for k, _ in PARAMETERISATIONS}}
            for r in records
        ],
    }


def _problem_with_transparency(converter: Converter) -> Problem:
    """The conversion scene's Strauss problem with t freed too (C, s, m, t), on the pixels
    the conversions fit; its target is replaced per image."""
    base = Material(transparency=0.0)
    height, width = converter.scene.shape
    dummy = Target(np.ones((height, width, 3)), np.ones((height, width), dtype=bool), "<study>", "linear", 0, 0)
    with_t, _, _ = build_problem(
        converter.scene,
        dummy,
        list(REFLECTION_NAMES),
        base,
        plan_render(converter.scene, base, transparent=True),
        FitOptions(edge_pixels="exclude"),  # the pixels the conversions fit
    )
    return with_t


def _independence_images(run: dict[str, Any]) -> list[tuple[str, np.ndarray, dict[str, Any], dict[str, Any]]]:
    """The images part 2 analyses: each conversion that succeeded with an uncertainty, as
    (the model that rendered it, the image, Strauss's values, Phong's values) — the truth
    for the model's own render, the fitted conversion for the other's."""
    converter: Converter = run["converter"]
    images = []
    for entry, result in zip(run["phong_entries"], run["p2s"]):
        if result["status"] == "ok" and result["uncertainty"] is not None:
            images.append(
                ("phong", converter.phong_target(entry.material), result["strauss"], entry.material.to_dict())
            )
    for entry, result in zip(run["strauss_entries"], run["s2p"]):
        if result["status"] == "ok" and result["uncertainty"] is not None:
            images.append(
                ("strauss", converter.strauss_target(entry.material), entry.material.to_dict(), result["phong"])
            )
    return images


def _image_fisher(
    converter: Converter,
    with_t: Problem,
    origin: str,
    target: np.ndarray,
    strauss_values: dict[str, Any],
    phong_values: dict[str, Any],
) -> dict[str, Any]:
    """One image's Fisher metrics in every parameterisation: the Jacobians of Strauss (with
    and without t) and Phong (identifiable products, and as users set it) at their values,
    σ the image's reference noise level."""
    sigma = reference_noise_level(target)
    t_target = jnp.asarray(target)
    s_problem = dataclasses.replace(converter.strauss, target=t_target)
    xs = converter.strauss.layout.join(strauss_values)
    j_s = np.asarray(laplace.jacobian(s_problem, jnp.asarray(xs)))
    xt = with_t.layout.join({**strauss_values, "transparency": 0.0})
    j_t = np.asarray(laplace.jacobian(dataclasses.replace(with_t, target=t_target), jnp.asarray(xt)))
    pm = PhongMaterial.from_dict(phong_values)
    xp = vector_from_material(pm)
    p_problem = dataclasses.replace(converter.phong_template, target=t_target, ambient_ka=jnp.asarray(0.0))
    j_p = np.asarray(laplace.jacobian(p_problem, jnp.asarray(xp)))
    j_u = j_p @ _phong_user_transform(
        xp,
        {
            **phong_values,
            "kd": float(np.max(np.atleast_1d(phong_values["kd"]))),
            "ks": float(np.max(np.atleast_1d(phong_values["ks"]))),
        },
    )
    return {
        "origin": origin,
        "strauss": _fisher_metrics(j_s, sigma, STRAUSS_LABELS),
        "strauss_with_t": _fisher_metrics(j_t, sigma, STRAUSS_T_LABELS),
        "phong": _fisher_metrics(j_p, sigma, PHONG_LABELS),
        "phong_user": _fisher_metrics(j_u, sigma, PHONG_USER_LABELS),
    }


def _independence_summary(records: list[dict[str, Any]]) -> dict[str, Any]:
    """Per parameterisation, the images' Fisher metrics summarised: the share singular,
    the condition numbers' median (and p90), the correlations' medians and the pairs most
    often the most correlated (none without images)."""
    summary = {}
    for key, labels in PARAMETERISATIONS:
        metrics = [r[key] for r in records]
        if not metrics:
            continue
        cond = np.array([m["condition_scale_free"] for m in metrics])
        raw = np.array([m["condition_unit_range"] for m in metrics])
        pairs: dict[str, int] = {}
        for m in metrics:
            name = " / ".join(sorted(m["max_pair"], key=labels.index))
            pairs[name] = pairs.get(name, 0) + 1
        summary[key] = {
            "labels": labels,
            "images": len(metrics),
            "singular_fraction": float(np.mean([m["rank"] < m["parameters"] for m in metrics])),
            "condition_scale_free_median": _finite_median(cond),
            "condition_scale_free_p90": _finite_percentile(cond, 90),
            "condition_unit_range_median": _finite_median(raw),
            "max_abs_correlation_median": float(np.median([m["max_abs_correlation"] for m in metrics])),
            "mean_abs_correlation_median": float(np.median([m["mean_abs_correlation"] for m in metrics])),
            "most_correlated_pairs": dict(sorted(pairs.items(), key=lambda kv: -kv[1])[:3]),
            "median_abs_correlation": np.median(np.array([m["abs_correlation"] for m in metrics]), axis=0)
            .round(4)
            .tolist(),
        }
    return summary


def _finite_percentile(values: np.ndarray, q: float) -> float | None:
    """A percentile that treats infinite values (singular Fisher information) as larger than
    any other; None where it lands on one of them."""
    big = np.finfo(np.float64).max
    value = float(np.percentile(np.where(np.isfinite(values), values, big), q, method="lower"))
    return None if value >= big else value


def _finite_median(values: np.ndarray) -> float | None:
    return _finite_percentile(values, 50.0)


# --- 3. uniformity ----------------------------------------------------------------------------


@eqx.filter_jit
def _render_many(problem, xs):
    """Renders (K, N, 3) of a problem at K physical vectors."""
    return jax.vmap(problem.render_physical)(xs)


def _sweep_images(problem, xs: np.ndarray) -> np.ndarray:
    return np.asarray(_render_many(problem, jnp.asarray(xs)))


def _steps(images: np.ndarray) -> np.ndarray:
    """Mean CIEDE2000 between successive images of a sweep, on a common exposure."""
    scale = max(1.0, float(np.percentile(images, 99)))
    scaled = images / scale
    return np.array([float(np.mean(delta_e_2000(scaled[k + 1], scaled[k]))) for k in range(len(scaled) - 1)])


def _profile_summary(profiles: list[np.ndarray], values: np.ndarray) -> dict[str, Any]:
    profiles = np.asarray(profiles)  # (bases, steps)
    per_base_cv = [float(np.std(p) / np.mean(p)) if np.mean(p) > 0 else None for p in profiles]
    mean_profile = profiles.mean(axis=0)
    mean_step = float(mean_profile.mean())
    largest = int(np.argmax(mean_profile))
    total = float(mean_profile.sum())
    cvs = [c for c in per_base_cv if c is not None]
    return {
        "values": values.tolist(),
        "mean_profile": mean_profile.tolist(),
        "mean_step": mean_step,
        "total": total,
        "cv": float(np.std(mean_profile) / mean_step) if mean_step > 0 else None,
        "cv_median_over_bases": float(np.median(cvs)) if cvs else None,
        "max_over_mean": float(mean_profile.max() / mean_step) if mean_step > 0 else None,
        "largest_step_between": [float(values[largest]), float(values[largest + 1])],
        "largest_step_share": float(mean_profile.max() / total) if total > 0 else None,
    }


def uniformity(config: StudyConfig, rng: np.random.Generator, say: Callable[[str], None]) -> dict[str, Any]:
    k = config.uniformity_steps
    say(f"uniformity: {config.uniformity_bases} base material(s) per model, {k} equal steps per parameter")
    scene = conversion_scene(size=config.uniformity_size)
    converter = Converter(scene, Settings(starts=1))
    base = Material(transparency=0.0)
    height, width = scene.shape
    dummy = Target(np.ones((height, width, 3)), np.ones((height, width), dtype=bool), "<study>", "linear", 0, 0)
    s_problem, _, _ = build_problem(
        scene,
        dummy,
        list(REFLECTION_NAMES),
        base,
        plan_render(scene, base, transparent=True),
        FitOptions(edge_pixels="exclude"),  # the pixels the conversions fit
    )
    p_problem = converter.phong_template
    strauss = draw_strauss(rng, config.uniformity_bases)
    # log-uniform n for the bases: with n uniform in [1, 1000] most bases would have a highlight
    # narrower than a pixel, and ks would barely change the image
    phong = draw_phong(rng, config.uniformity_bases, log_exponent=True)
    unit = np.linspace(0.0, 1.0, k)
    low, high = PHONG_EXPONENT_RANGE
    sweeps = {
        "strauss": dict.fromkeys(FRACTION_NAMES, unit),
        "phong": {
            "kd": unit,
            "ks": unit,
            "exponent (linear steps)": np.linspace(low, high, k),
            "exponent (geometric steps)": np.geomspace(low, high, k),
        },
    }
    profiles: dict[str, dict[str, list]] = {
        "strauss": {p: [] for p in sweeps["strauss"]},
        "phong": {p: [] for p in sweeps["phong"]},
    }
    for b in range(config.uniformity_bases):
        values = {
            "color": strauss["color"][b],
            "smoothness": strauss["smoothness"][b],
            "metalness": strauss["metalness"][b],
            "transparency": 0.0,
        }
        for name, grid in sweeps["strauss"].items():
            xs = np.stack([s_problem.layout.join({**values, name: v}) for v in grid])
            profiles["strauss"][name].append(_steps(_sweep_images(s_problem, xs)))
        kd, ks, n = phong["kd"][b], phong["ks"][b], phong["exponent"][b]
        cd, cs = phong["diffuse_color"][b], phong["specular_color"][b]
        for name, grid in sweeps["phong"].items():
            rows = []
            for v in grid:
                kd_v, ks_v, n_v = (v, ks, n) if name == "kd" else (kd, v, n) if name == "ks" else (kd, ks, v)
                rows.append(np.concatenate([kd_v * cd, ks_v * cs, [math.log(n_v) / LOG_MAX_EXPONENT]]))
            profiles["phong"][name].append(_steps(_sweep_images(p_problem, np.stack(rows))))
    return {
        "steps": k,
        "bases": config.uniformity_bases,
        "image_size": config.uniformity_size,
        "strauss": {
            name: _profile_summary(profiles["strauss"][name], grid) for name, grid in sweeps["strauss"].items()
        },
        "phong": {name: _profile_summary(profiles["phong"][name], grid) for name, grid in sweeps["phong"].items()},
    }


# --- the whole study --------------------------------------------------------------------------


@uses_float64
def run_study(
    config: StudyConfig,
    progress: Callable[[str], None] | None = None,
    *,
    merl_fits: str | Path | None = None,
    capture: str | Path | None = None,
) -> dict[str, Any]:
    """Run the four parts and return every figure (JSON-ready, see
    `strauss_fit.reporting.study_report`). With ``merl_fits`` (bbm's
    ``fits_parsed.json`` or its folder) and ``capture`` (a capture folder or manifest), the
    measured-material parts run too (`strauss_fit.study.real`: the ``merl`` and
    ``capture`` entries; `strauss_fit.study.real_report.write_study_report` writes them
    up)."""
    from .real import capture_models, merl_expressiveness

    say = progress or (lambda message: None)
    started = time.perf_counter()
    seeds = np.random.SeedSequence(config.seed).spawn(3)
    timings = {}
    t0 = time.perf_counter()
    part1 = consistency(config, np.random.default_rng(seeds[0]), say)
    timings["consistency_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    run = conversions(config, np.random.default_rng(seeds[1]), say)
    timings["conversions_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    part2 = independence(run, say)
    timings["independence_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    part3 = uniformity(config, np.random.default_rng(seeds[2]), say)
    timings["uniformity_s"] = time.perf_counter() - t0
    measured = {}
    if merl_fits is not None:
        t0 = time.perf_counter()
        measured["merl"] = merl_expressiveness(merl_fits, size=config.merl_image_size, say=say)
        timings["merl_s"] = time.perf_counter() - t0
    if capture is not None:
        t0 = time.perf_counter()
        measured["capture"] = capture_models(capture, say=say)
        timings["capture_s"] = time.perf_counter() - t0
    timings["total_s"] = time.perf_counter() - started
    from .._version import __version__

    return _finite(
        {
            "format": "strauss-fit study",
            "version": 1,
            "config": config.as_dict(),
            "environment": {
                "strauss_fit": __version__,
                "jax": jax.__version__,
                "python": platform.python_version(),
                "machine": platform.machine(),
            },
            "consistency": part1,
            "independence": part2,
            "uniformity": part3,
            "expressiveness": run["summary"],
            **measured,
            "timing": timings,
        }
    )


def _finite(value: Any) -> Any:
    """The document with every non-finite number replaced by None (JSON has no inf: an
    infinite condition number, i.e. a singular Fisher information, is written as null)."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value
