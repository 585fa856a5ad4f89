"""Silhouette pixels: fit them as sphere pixels, or leave them out? The measurement behind
``FitOptions.edge_pixels``.

A renderer that integrates over each pixel's area (Mitsuba's box filter, a camera, any
anti-aliased image) records along the silhouette a mix of sphere and background;
strauss-fit's model samples each pixel at its centre. This fits, with each rule
(``include``: every pixel whose centre shows the sphere; ``exclude``: only pixels whose
whole footprint does; ``auto``, the default: include them when the target's silhouette is
point-sampled, see :func:`strauss_fit.rendering.coverage.silhouette_blend`), targets of known
material:

- *anti-aliased*: the bundled Mitsuba Lambertian spheres, and Strauss renders
  box-filtered from 8 × 8 samples per pixel (matte, plastic, glossy, metal; orthographic
  and perspective);
- *point-sampled*: the same Strauss materials rendered at pixel centres, where including
  the edge pixels is exact — what does leaving them out cost?

and reports the errors of s, m and C against the truth, the fit's deviation of s, the
pixels used and, for ``auto``, the rule it chose. A table is printed; ``--json`` (default
``benchmarks/results/silhouette.json``) keeps every fit.

    .venv/bin/python benchmarks/silhouette.py [--size 64] [--supersample 8]
"""

from __future__ import annotations

import argparse
import json
import time
import tomllib
from pathlib import Path

import bench_common
import numpy as np

import strauss_fit as sf

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "data_synth" / "scenes"
MITSUBA = ROOT / "data_synth" / "bundled_mitsuba"
MATERIALS = {
    "matte": dict(color=(0.7, 0.5, 0.3), smoothness=0.0, metalness=0.0),
    "plastic": dict(color=(0.3, 0.5, 0.7), smoothness=0.5, metalness=0.0),
    "glossy": dict(color=(0.6, 0.2, 0.2), smoothness=0.85, metalness=0.0),
    "metal": dict(color=(0.9, 0.7, 0.3), smoothness=0.7, metalness=1.0),
}


def scene_at(name: str, size: int) -> sf.Scene:
    data = tomllib.loads((SCENES / f"{name}.toml").read_text())
    data["camera"].update(width=size, height=size)
    return sf.parse_scene(data, base_dir=SCENES)


def strauss_target(scene_name: str, material: dict, size: int, supersample: int) -> sf.Target:
    """The material rendered at pixel centres (``supersample`` 1) or box-filtered from
    ``supersample``² samples per pixel; only the sphere's partly covered pixels differ
    at the silhouette, every pixel where the image varies within it."""
    scene = scene_at(scene_name, size * supersample)
    image, _ = sf.render(scene, sf.Material(**material))
    image = np.asarray(image, dtype=np.float64)
    if supersample > 1:
        image = image.reshape(size, supersample, size, supersample, 3).mean(axis=(1, 3))
    label = f"{scene_name}-{'aa' if supersample > 1 else 'point'}"
    return sf.Target(image, np.ones((size, size), dtype=bool), label, "linear", 0, 0)


def fit_row(case: str, kind: str, scene: sf.Scene, target: sf.Target, truth: dict, rule: str) -> dict:
    started = time.perf_counter()
    # the noise level is given (these targets are noise-free): what is measured is bias
    result = sf.fit(scene, target, sf.FitOptions(edge_pixels=rule, noise=1e-3, loss="linear"))
    found = result.material.to_dict()
    smoothness_sd = result.uncertainty.get("smoothness") if "smoothness" in result.free else None
    return {
        "case": case,
        "kind": kind,
        "rule": rule,
        "pixels": result.pixels_used,
        "resolved": result.to_json()["settings"]["edge_pixels"],
        "smoothness": found["smoothness"],
        "smoothness_error": found["smoothness"] - truth["smoothness"],
        "smoothness_sd": smoothness_sd,
        "metalness_error": found["metalness"] - truth["metalness"],
        "color_error": float(np.max(np.abs(np.asarray(found["color"]) - np.asarray(truth["color"])))),
        "held": sorted(result.held),
        "seconds": time.perf_counter() - started,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--supersample", type=int, default=8)
    parser.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "silhouette.json")
    args = parser.parse_args()
    machine = bench_common.machine()
    rows = []
    cases = []
    for sidecar_path in sorted(MITSUBA.glob("mitsuba-diffuse*.json")):
        sidecar = json.loads(sidecar_path.read_text())
        scene = sf.parse_scene(sidecar["scene"]["definition"], base_dir=MITSUBA)
        truth = dict(color=tuple(sidecar["parameters"]["reflectance"]), smoothness=0.0, metalness=0.0)
        cases.append(
            (sidecar["id"], "Mitsuba, box filter", scene, sf.load_target(MITSUBA / sidecar["files"]["exr"]), truth)
        )
    for scene_name in ("key_light", "point_light"):
        for name, material in MATERIALS.items():
            scene = scene_at(scene_name, args.size)
            for supersample, kind in ((args.supersample, "Strauss, box filter"), (1, "Strauss, pixel centres")):
                target = strauss_target(scene_name, material, args.size, supersample)
                cases.append((f"{name} {scene_name}", kind, scene, target, material))
    print(
        f"{'case':28} {'target':24} {'rule':8} {'pixels':>6} {'s':>7} {'s error':>9} {'sd(s)':>8} "
        f"{'m error':>8} {'C error':>8}  held"
    )
    for case, kind, scene, target, truth in cases:
        for rule in ("include", "exclude", "auto"):
            row = fit_row(case, kind, scene, target, truth, rule)
            rows.append(row)
            sd = "-" if row["smoothness_sd"] is None else f"{row['smoothness_sd']:.2g}"
            print(
                f"{case:28} {kind:24} {rule:8} {row['pixels']:6d} {row['smoothness']:7.4f} "
                f"{row['smoothness_error']:+9.4f} {sd:>8} {row['metalness_error']:+8.4f} {row['color_error']:8.4f}"
                f"  {','.join(row['held'])}" + (f"  (auto: {row['resolved']})" if rule == "auto" else ""),
                flush=True,
            )
    for kind in ("Mitsuba, box filter", "Strauss, box filter", "Strauss, pixel centres"):
        for rule in ("include", "exclude", "auto"):
            mine = [r for r in rows if r["kind"] == kind and r["rule"] == rule]
            print(
                f"{kind:24} {rule:8}: median |s error| {np.median([abs(r['smoothness_error']) for r in mine]):.4f}"
                f", worst {max(abs(r['smoothness_error']) for r in mine):.4f}; "
                f"median C error {np.median([r['color_error'] for r in mine]):.4f}"
                + (f"; auto chose {sorted({r['resolved'] for r in mine})}" if rule == "auto" else "")
            )
    payload = {"benchmark": "silhouette", "date": time.strftime("%Y-%m-%d"), "machine": machine, "rows": rows}
    bench_common.write_json(args.json, payload)


if __name__ == "__main__":
    main()
