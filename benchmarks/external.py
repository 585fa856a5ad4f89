"""Fits of targets strauss-fit did not render: the bundled Mitsuba 3 set, per loss.

For every physically based target in ``data_synth/bundled_mitsuba/`` (Lambertian, smooth
and rough plastics, rough gold and copper, a silver mirror in a studio, Disney principled
materials, glass before a checkerboard; see docs/datasets.md) and every loss of
``strauss_fit.fitting.problem.LOSSES`` plus ``auto`` (the default), it fits the scene's Strauss
material with the ``balanced`` preset and measures what a person sees:

- ``dE``: mean and 95th percentile CIEDE2000 between the fitted image and the target over
  the pixels used;
- ``body``: the mean CIEDE2000 over the *body* (away from the highlights and the rim,
  :func:`strauss_fit.fitting.diagnosis.pixel_regions`), and the body colour's error — the
  fitted diffuse albedo (1 − m·s)(1 − s³)(1 − t)·C against the body's albedo as Mitsuba
  renders it (the sidecar's ``reference.diffuse_albedo``, for the Lambertian, plastic and
  principled dielectric targets) as the largest relative error over the channels;
- ``highlight``: the distance (pixels) between the target's and the fit's brightest pixel
  near a light's mirror direction, and the ratio of the highlight's areas above half its
  height over the body (fit/target: < 1 the fit's highlight is narrower);

plus the verdict, the warning codes and the time. A table is printed; ``--json`` (default
``benchmarks/results/external.json``) keeps every fit.

    .venv/bin/python benchmarks/external.py [--losses linear,perceptual,huber,cauchy,auto] [--cases GLOB]
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import time
from pathlib import Path

import bench_common
import numpy as np

import strauss_fit as sf
from strauss_fit.color import delta_e_2000
from strauss_fit.fitting.diagnosis import pixel_regions
from strauss_fit.fitting.problem import LOSSES

ROOT = Path(__file__).resolve().parents[1]
BUNDLED = ROOT / "data_synth" / "bundled_mitsuba"
#: Luminance weights of linear sRGB (Rec. 709).
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def diffuse_truth(sidecar: dict) -> np.ndarray | None:
    """The body's colour as Mitsuba renders it (the sidecar's ``reference.diffuse_albedo``:
    the BSDF with its specular reflection off, over a white Lambertian), where the material
    has a body a person would call its colour. For a rough plastic this is well below its
    ``diffuse_reflectance`` parameter: Mitsuba's rough coat lets less light in and out."""
    albedo = (sidecar.get("reference") or {}).get("diffuse_albedo")
    return None if albedo is None else np.asarray(albedo, dtype=float)


def body_albedo(result: sf.FitResult) -> np.ndarray:
    """The fitted Strauss diffuse albedo (1 − m·s)(1 − s³)(1 − t)·C."""
    m = result.material.to_dict()
    s, metal, t = m["smoothness"], m["metalness"], m["transparency"]
    return (1 - metal * s) * (1 - s**3) * (1 - t) * np.asarray(m["color"], dtype=float)


def highlight_shape(values: np.ndarray, region: np.ndarray, body: np.ndarray) -> tuple[int | None, int]:
    """The index (into ``values``) of the brightest pixel of ``region`` and the number of
    region pixels above half the way from the body's median to that peak."""
    if not region.any():
        return None, 0
    luminance = values @ LUMINANCE
    inside = np.flatnonzero(region)
    peak = inside[np.argmax(luminance[inside])]
    base = float(np.median(luminance[body])) if body.any() else 0.0
    half = base + 0.5 * (luminance[peak] - base)
    return int(peak), int(np.sum(luminance[inside] > half))


def measure(sidecar_path: Path, loss: str) -> dict:
    sidecar = json.loads(sidecar_path.read_text())
    scene = sf.parse_scene(dict(sidecar["scene"]["definition"]), source=str(sidecar_path), base_dir=BUNDLED)
    target = sf.load_target(BUNDLED / sidecar["files"]["exr"])
    started = time.perf_counter()
    result = sf.fit(scene, target, sf.FitOptions(loss=loss))
    seconds = time.perf_counter() - started
    index = result.used_index
    model = result.fitted_image.reshape(-1, 3)[index]
    observed = target.pixels.reshape(-1, 3)[index]
    # the problem's pixel set may be padded (strauss_fit.fitting.problem.pixel_bucket): its real rows
    regions = {name: result.problem.real(mask) for name, mask in pixel_regions(result.problem.prepared).items()}
    body = regions["body"]
    row = {
        "case": sidecar["id"],
        "bsdf": sidecar["parameters"],
        "scene": sidecar["scene"]["name"],
        "loss": loss,
        "loss_used": result.solver.get("loss"),
        "material": result.material.to_dict(),
        "free": result.free,
        "verdict": result.verdict,
        "chi2_per_dof": result.residual.get("chi2_per_dof"),
        "warnings": [w["code"] for w in result.warnings],
        "delta_e_mean": result.residual["delta_e2000_mean"],
        "delta_e_p95": result.residual["delta_e2000_p95"],
        "body_delta_e": float(np.mean(delta_e_2000(model[body], observed[body]))) if body.any() else None,
        "seconds": seconds,
    }
    truth = diffuse_truth(sidecar)
    if truth is not None:
        albedo = body_albedo(result)
        row["body_albedo"] = albedo.tolist()
        row["body_albedo_error"] = float(np.max(np.abs(albedo - truth) / truth))
    near = regions["highlight"] | regions["highlight wings"]
    target_peak, target_area = highlight_shape(observed, near, body)
    fit_peak, fit_area = highlight_shape(model, near, body)
    if target_peak is not None and target_area > 0:
        width = result.fitted_image.shape[1]
        (tr, tc), (fr, fc) = divmod(int(index[target_peak]), width), divmod(int(index[fit_peak]), width)
        row["highlight_offset_px"] = float(np.hypot(tr - fr, tc - fc))
        row["highlight_area_ratio"] = fit_area / target_area
    return row


def fmt(value, digits=3) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.{digits}g}"
    return str(value)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--losses", default=",".join((*LOSSES, "auto")), help="comma-separated losses")
    parser.add_argument("--cases", default="*", help="glob on the case id (default: all)")
    parser.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "external.json")
    args = parser.parse_args()
    losses = [loss.strip() for loss in args.losses.split(",") if loss.strip()]
    machine = bench_common.machine()
    sidecars = [
        p for p in sorted(BUNDLED.glob("*.json")) if p.name != "index.json" and fnmatch.fnmatch(p.stem, args.cases)
    ]
    rows = []
    header = (
        f"{'case':34} {'loss':10} {'used':10} {'verdict':9} {'dE mean':>7} {'dE p95':>7} {'body dE':>7} "
        f"{'albedo err':>10} {'hl px':>5} {'hl area':>7} {'s':>6} {'m':>6} {'time s':>6}  warnings"
    )
    print(header)
    for sidecar in sidecars:
        for loss in losses:
            row = measure(sidecar, loss)
            rows.append(row)
            print(
                f"{row['case']:34} {loss:10} {fmt(row['loss_used']):10} {fmt(row['verdict']):9} "
                f"{row['delta_e_mean']:7.3f} {row['delta_e_p95']:7.3f} {fmt(row['body_delta_e']):>7} "
                f"{fmt(row.get('body_albedo_error')):>10} {fmt(row.get('highlight_offset_px')):>5} "
                f"{fmt(row.get('highlight_area_ratio')):>7} {row['material']['smoothness']:6.3f} "
                f"{row['material']['metalness']:6.3f} {row['seconds']:6.2f}  {','.join(row['warnings'])}",
                flush=True,
            )
    print("\nper loss (median over cases; albedo error over the plastics and Lambertian surfaces):")
    for loss in losses:
        mine = [r for r in rows if r["loss"] == loss]
        albedo = [r["body_albedo_error"] for r in mine if "body_albedo_error" in r]
        area = [abs(np.log(r["highlight_area_ratio"])) for r in mine if r.get("highlight_area_ratio")]
        print(
            f"  {loss:10} dE mean {np.median([r['delta_e_mean'] for r in mine]):.3f}"
            f"  body dE {np.median([r['body_delta_e'] for r in mine if r['body_delta_e'] is not None]):.3f}"
            f"  albedo error {np.median(albedo) if albedo else float('nan'):.3f} (worst {max(albedo, default=0):.3f})"
            f"  |log area ratio| {np.median(area) if area else float('nan'):.3f}"
            f"  offset px {np.median([r.get('highlight_offset_px', 0) for r in mine]):.1f}"
            f"  time {np.median([r['seconds'] for r in mine]):.2f} s"
        )
    payload = {"benchmark": "external", "date": time.strftime("%Y-%m-%d"), "machine": machine, "rows": rows}
    bench_common.write_json(args.json, payload)


if __name__ == "__main__":
    main()
