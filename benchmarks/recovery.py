"""Recovery of known materials: how often a fit lands within tolerance of the truth.

    .venv/bin/python benchmarks/recovery.py [--quick] [--draws N] [--json PATH]

Ground truth is rendered with the project's renderer and recorded through the data_synth
sensor model (Gaussian read noise at a stated fraction of the image's 98th percentile) as
HDR (linear float) and LDR (8-bit sRGB through colour-science, clipped pixels excluded by
the fit) targets, in two scenes:

- ``opaque``: the bundled ``two_lights.toml`` lighting (warm key, cool fill, ambient) over
  a grey backdrop, 64×64; materials over s ∈ {0, 0.3, 0.7, 1}, m ∈ {0, 0.5, 1} and two
  colours (t = 0);
- ``glass``: a sphere before a checkerboard (depth 2), t ∈ {0, 0.5, 1}, n ∈ {1.3, 1.7}.

Every case is rendered noise-free and at 1 % noise, the noisy ones in ``--draws`` (3)
independent noise draws. Each target is fitted with the settings of
``bench_common.LEGACY_FIT`` (4 starts, tolerances 1e-6/1e-8: ``FitOptions()``'s defaults until
they became the ``balanced`` preset, kept so that the numbers stay comparable). For every
parameter the fit chose to *constrain* (``free``), the error |fitted − true| is compared with the
tolerance (0.005 noise-free, 0.02 at 1 % noise; colour per channel); held parameters
are counted separately with their reasons. Where the fit reports a mirror whose metalness
and colour trade off (it holds m at 1), the tint m·(C − 1) — what such an image pins — is
compared instead of C. With noise, the table also gives how often the error lies within
twice the fit's own Laplace deviation (every entry of a colour), i.e. whether the error
bars the fit reports can be trusted. Prints a Markdown table, writes JSON.
"""

from __future__ import annotations

import argparse
import itertools
import statistics
import sys
import time
import tomllib
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench_common import legacy_options, machine, write_json  # noqa: E402

import strauss_fit as sf  # noqa: E402
from data_synth.sensor import Sensor, encode_ldr  # noqa: E402
from strauss_fit import fit, parse_scene  # noqa: E402
from strauss_fit.color import srgb_decode  # noqa: E402
from strauss_fit.fitting.identifiability import MIRROR_SMOOTHNESS  # noqa: E402
from strauss_fit.io.targets import Target  # noqa: E402

TOLERANCE = {0.0: 0.005, 0.01: 0.02}

OPAQUE = tomllib.loads((ROOT / "data_synth" / "scenes" / "two_lights.toml").read_text())
OPAQUE["background"] = {"color": [0.3, 0.3, 0.3]}
GLASS = tomllib.loads("""
[camera]
width = 64
height = 64
[[light]]
kind = "directional"
direction = [-0.5, 0.6, 1.0]
intensity = 0.9
[[light]]
kind = "ambient"
intensity = 0.08
[background]
kind = "checkerboard"
point = [0.0, 0.0, -3.0]
square_size = 0.5
colors = [[0.9, 0.8, 0.3], [0.1, 0.2, 0.6]]
sharpness = 4.0
[render]
depth = 2
""")


def materials(quick: bool):
    colours = [(0.8, 0.3, 0.2), (0.2, 0.5, 0.9)]
    s_values = (0.0, 0.3, 0.7, 1.0)
    m_values = (0.0, 0.5, 1.0)
    opaque = [
        ("opaque", dict(color=c, smoothness=s, metalness=m))
        for c, s, m in itertools.product(colours[:1] if quick else colours, s_values, m_values)
    ]
    glass = [
        ("glass", dict(color=(0.9, 0.85, 0.7), smoothness=0.6, transparency=t, ior=n))
        for t, n in itertools.product((0.0, 0.5, 1.0), (1.3, 1.7))
    ]
    return opaque + (glass[2:4] if quick else glass)


def make_target(scene, truth: sf.Material, noise: float, ldr: bool, seed: int) -> Target:
    image, mask = sf.render(scene, truth)
    radiance = np.asarray(image)
    sigma = noise * float(np.percentile(radiance[np.asarray(mask)], 98)) if noise else 0.0
    recorded = Sensor(read_noise=sigma).apply(radiance, np.random.default_rng(seed)) if sigma else radiance
    if not ldr:
        return Target(recorded, np.ones(mask.shape, bool), "hdr", "linear", 0, 0)
    codes, clipped = encode_ldr(recorded)
    return Target(srgb_decode(codes / 255.0), ~clipped, "ldr", "srgb", int(clipped.sum()), 0)


def _z(difference, deviation) -> float:
    """The largest |error| / (the fit's Laplace deviation) over the entries (inf where the
    deviation is 0 and the error is not, 0 where both are)."""
    difference = np.abs(np.atleast_1d(np.asarray(difference, dtype=float)))
    deviation = np.atleast_1d(np.asarray(deviation, dtype=float))
    ratio = np.divide(difference, deviation, out=np.where(difference > 0, np.inf, 0.0), where=deviation > 0)
    return float(np.max(ratio))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a smaller grid (smoke test)")
    parser.add_argument("--json", default=str(ROOT / "benchmarks" / "results" / "recovery.json"))
    parser.add_argument(
        "--draws",
        type=int,
        default=3,
        help="noise draws per noisy case (default 3; the first is the one earlier runs used)",
    )
    args = parser.parse_args()
    info = machine()
    scenes = {"opaque": parse_scene(OPAQUE, source="opaque"), "glass": parse_scene(GLASS, source="glass")}
    records = []
    base = [
        (scene, params, noise, ldr)
        for scene, params in materials(args.quick)
        for noise in TOLERANCE
        for ldr in (False, True)
        if not (scene == "glass" and ldr)
    ]
    # a noisy case gets several draws: one draw per cell is too few to tell 95 % from 92 %;
    # draw 0 keeps the seed of earlier runs (the case's number), draw d adds 1000 d
    cases = [
        (case, number + 1000 * draw)
        for number, case in enumerate(base, start=1)
        for draw in range(args.draws if case[2] else 1)
    ]
    started = time.perf_counter()
    for number, ((scene_name, params, noise, ldr), seed) in enumerate(cases, start=1):
        truth = sf.Material(**params)
        scene = scenes[scene_name]
        target = make_target(scene, truth, noise, ldr, seed=seed)
        try:
            result = fit(scene, target, legacy_options())
        except sf.StraussFitError as exc:  # e.g. a target with nothing visible
            records.append(dict(scene=scene_name, truth=truth.to_dict(), noise=noise, ldr=ldr, error=str(exc)))
            print(f"[{number}/{len(cases)}] {scene_name} {params} noise={noise} ldr={ldr}: {exc}", file=sys.stderr)
            continue
        errors, z_scores = {}, {}
        mirror_tint = (
            "color" in result.free
            and "metalness" in result.held
            and float(result.material.smoothness) >= MIRROR_SMOOTHNESS
        )
        for name in result.free:
            if name == "color" and mirror_tint:
                # a mirror over a uniform backdrop pins only the tint m·(C − 1) (the fit
                # says so and holds m at 1): compare that, not C
                tint = float(result.material.metalness) * (np.asarray(result.material.color) - 1.0)
                true_tint = float(truth.metalness) * (np.asarray(truth.color) - 1.0)
                errors["mirror tint m(C-1)"] = float(np.max(np.abs(tint - true_tint)))
                # m is held at 1, so the tint is C − 1 and has the colour's deviation
                z_scores["mirror tint m(C-1)"] = _z(tint - true_tint, result.uncertainty["color"])
            elif name == "color":
                difference = np.asarray(result.material.color) - np.asarray(truth.color)
                errors[name] = float(np.max(np.abs(difference)))
                z_scores[name] = _z(difference, result.uncertainty[name])
            else:
                difference = float(getattr(result.material, name)) - float(getattr(truth, name))
                errors[name] = abs(difference)
                z_scores[name] = _z(difference, result.uncertainty[name])
        records.append(
            dict(
                scene=scene_name,
                truth=truth.to_dict(),
                noise=noise,
                ldr=ldr,
                seed=seed,
                errors=errors,
                z=z_scores,
                held={k: v["reason"] for k, v in result.held.items()},
                status=result.solver["status"],
                wall_time_s=result.wall_time_s,
            )
        )
        worst = max(errors.values()) if errors else 0.0
        print(
            f"[{number}/{len(cases)}] {scene_name} {params} noise={noise} {'LDR' if ldr else 'HDR'}: "
            f"worst error {worst:.1e}, free {result.free}",
            file=sys.stderr,
        )
    elapsed = time.perf_counter() - started

    rows = []
    print(
        "\n| scene | noise | format | parameter | fits | within tolerance | within the fit's 2σ | median error | "
        "95th pct error |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    groups, z_groups = defaultdict(list), defaultdict(list)
    for r in records:
        for name, e in r.get("errors", {}).items():
            key = (r["scene"], r["noise"], "LDR" if r["ldr"] else "HDR", name)
            groups[key].append(e)
            z_groups[key].append(r["z"][name])
    for key, errs in sorted(groups.items()):
        scene_name, noise, fmt, name = key
        tol = TOLERANCE[noise]
        within = sum(e <= tol for e in errs) / len(errs)
        # the fit's own error bar (Laplace) means something only with noise in the image
        covered = sum(z <= 2.0 for z in z_groups[key]) / len(errs) if noise else None
        row = dict(
            scene=scene_name,
            noise=noise,
            format=fmt,
            parameter=name,
            fits=len(errs),
            tolerance=tol,
            within=within,
            within_2sd=covered,
            median=statistics.median(errs),
            p95=float(np.percentile(errs, 95)),
        )
        rows.append(row)
        print(
            f"| {scene_name} | {noise:.0%} | {fmt} | {name} | {len(errs)} | {within:.0%} (≤ {tol}) | "
            f"{'-' if covered is None else f'{covered:.0%}'} | {row['median']:.1e} | {row['p95']:.1e} |"
        )
    held = defaultdict(int)
    for r in records:
        for name in r.get("held", {}):
            held[(r["scene"], name)] += 1
    print(
        "\nheld (not constrained by the image), count of fits: "
        + ", ".join(f"{s}/{n}: {c}" for (s, n), c in sorted(held.items()))
    )
    failures = [r for r in records if "error" in r]
    print(f"fits refused: {len(failures)}; total time {elapsed:.0f} s for {len(cases)} fits")
    write_json(args.json, dict(machine=info, rows=rows, records=records, elapsed_s=elapsed))


if __name__ == "__main__":
    with sf.float64():  # all of it in float64 (importing strauss_fit no longer switches it on)
        main()
