"""Lights measured on a real mirror ball: the University of Washington photometric-stereo
set ("psmImages": 12 photographs of a chrome ball, ``chrome.N.tga``, its mask
``chrome.mask.tga`` and the course's reference directions ``lights.txt``; the data is not
part of strauss-fit and may not be redistributed: pass the folder that holds it).

For each image it prints the direction strauss-fit measures
(:func:`strauss_fit.capture._mirror.estimate_lights`, orthographic unless ``--camera
perspective --focal-px F``), the reference, the angle between them and the reported
standard deviation; then the median and maximum angle.

Two diagnostics say which of the two is off where they disagree:

- *the reference's circle*: the ball (centre, radius) that would turn the measured
  highlight pixels into the reference directions, by least squares (orthographic), and the
  rms pixel residual. Compared with the circle the mask shows, it tells whether the
  reference was computed with another ball outline;
- *the grey sphere* (``gray.N.tga``, ``gray.mask.tga``, when present: the same 12 lights on
  a matte sphere): per image the direction of the Lambertian least-squares fit
  I = n · L over the lit, unsaturated pixels (more than 10 % of the image's brightest,
  2 px inside the outline), and its angle to the measured and to the reference direction.
  The camera's response is not documented (README: mildly non-linear), so this is a
  coarse, independent check, not a truth.

    .venv/bin/python benchmarks/real_lights.py PATH/TO/uw-psm-gray-chrome [--json OUT]
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import bench_common
import numpy as np

from strauss_fit.capture._mirror import estimate_lights
from strauss_fit.capture._sphere import Camera, circle_from_mask, sphere_geometry
from strauss_fit.io.images import read_image

ROOT = Path(__file__).resolve().parents[1]
COUNT = 12


def angle_deg(a, b) -> float:
    a = np.asarray(a, dtype=float) / np.linalg.norm(a)
    b = np.asarray(b, dtype=float) / np.linalg.norm(b)
    return math.degrees(math.atan2(float(np.linalg.norm(np.cross(a, b))), float(a @ b)))


def reference_circle(pixels: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, float]:
    """(cx, cy, r) minimising |pixel − (cx + r n_x, cy − r n_y)|², n = normalise(l + v)
    the normal that reflects the view v = (0, 0, 1) into the reference light l; and the rms
    residual in pixels."""
    normals = reference + np.array([0.0, 0.0, 1.0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    a = np.zeros((2 * len(pixels), 3))
    b = np.zeros(2 * len(pixels))
    a[0::2, 0], a[0::2, 2], b[0::2] = 1.0, normals[:, 0], pixels[:, 0]
    a[1::2, 1], a[1::2, 2], b[1::2] = 1.0, -normals[:, 1], pixels[:, 1]
    solution, *_ = np.linalg.lstsq(a, b, rcond=None)
    return solution, float(np.sqrt(np.mean((a @ solution - b) ** 2)))


def grey_directions(folder: Path) -> list[np.ndarray] | None:
    """Per image, the Lambertian least-squares light direction on the grey sphere."""
    if not (folder / "gray.mask.tga").is_file():
        return None
    mask = read_image(folder / "gray.mask.tga", encoding="linear").pixels.max(axis=-1)
    mask = mask >= 0.5 * mask.max()
    geometry = sphere_geometry(circle_from_mask(mask), mask.shape, margin=2.0)
    keep = mask[geometry.rows, geometry.cols]
    normals = geometry.normals[keep]
    out = []
    for k in range(COUNT):
        image = read_image(folder / f"gray.{k}.tga", encoding="linear").pixels.mean(axis=-1)
        values = image[geometry.rows, geometry.cols][keep]
        lit = (values > 0.1 * values.max()) & (values < 1.0)
        scaled, *_ = np.linalg.lstsq(normals[lit], values[lit], rcond=None)
        out.append(scaled / np.linalg.norm(scaled))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", type=Path, help="the uw-psm-gray-chrome folder")
    parser.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "real_lights.json")
    parser.add_argument("--camera", choices=("orthographic", "perspective"), default="orthographic")
    parser.add_argument("--focal-px", type=float, help="perspective: the focal length in pixels")
    args = parser.parse_args()
    camera = Camera(args.camera, args.focal_px)
    machine = bench_common.machine()

    folder = args.folder
    lines = (folder / "lights.txt").read_text().split()
    reference = np.array([float(v) for v in lines[1:]]).reshape(int(lines[0]), 3)
    reference /= np.linalg.norm(reference, axis=1, keepdims=True)
    paths = [folder / f"chrome.{k}.tga" for k in range(COUNT)]
    started = time.perf_counter()
    estimates = estimate_lights(paths, mask_path=folder / "chrome.mask.tga", camera=camera)
    seconds = time.perf_counter() - started
    circle = estimates[0].circle
    grey = grey_directions(folder)

    print(f"mirror ball ({camera.kind}): {circle.describe()}; {seconds:.2f} s for {COUNT} images\n")
    header = (
        f"{'image':14} {'measured direction':27} {'reference':27} {'error°':>6} {'sd°':>6} "
        f"{'highlight px':>16} {'sat':>4}"
    )
    if grey:
        header += f" {'grey→meas°':>10} {'grey→ref°':>9}"
    print(header)
    rows = []
    for k, (estimate, ref) in enumerate(zip(estimates, reference)):
        error = angle_deg(estimate.direction, ref)
        row = {
            "image": paths[k].name,
            "direction": list(estimate.direction),
            "reference": ref.tolist(),
            "error_deg": error,
            "direction_sd_deg": estimate.direction_sd_deg,
            "pixel": list(estimate.pixel),
            "pixel_sd": list(estimate.pixel_sd),
            "saturated_pixels": estimate.saturated_pixels,
            "notes": list(estimate.notes),
        }
        direction = "(" + ", ".join(f"{v:+.3f}" for v in estimate.direction) + ")"
        ref_text = "(" + ", ".join(f"{v:+.3f}" for v in ref) + ")"
        line = (
            f"{paths[k].name:14} {direction:27} {ref_text:27} {error:6.2f} {estimate.direction_sd_deg:6.3f} "
            f"({estimate.pixel[0]:6.2f}, {estimate.pixel[1]:6.2f}) {estimate.saturated_pixels:4d}"
        )
        if grey:
            row["grey_direction"] = grey[k].tolist()
            row["grey_to_measured_deg"] = angle_deg(grey[k], estimate.direction)
            row["grey_to_reference_deg"] = angle_deg(grey[k], ref)
            line += f" {row['grey_to_measured_deg']:10.2f} {row['grey_to_reference_deg']:9.2f}"
        rows.append(row)
        print(line)
    errors = [row["error_deg"] for row in rows]
    summary = {
        "median_error_deg": float(np.median(errors)),
        "max_error_deg": float(np.max(errors)),
        "median_sd_deg": float(np.median([row["direction_sd_deg"] for row in rows])),
    }
    print(
        f"\nmeasured vs reference: median {summary['median_error_deg']:.2f}°, max {summary['max_error_deg']:.2f}° "
        f"(reported sd: median {summary['median_sd_deg']:.3f}°)"
    )
    if not camera.perspective:
        fitted, rms = reference_circle(np.array([row["pixel"] for row in rows]), reference)
        summary["reference_circle"] = {"center": fitted[:2].tolist(), "radius": float(fitted[2]), "rms_px": rms}
        print(
            f"the reference directions fit a ball of centre ({fitted[0]:.1f}, {fitted[1]:.1f}), "
            f"radius {fitted[2]:.1f} px (rms {rms:.2f} px); the mask shows "
            f"({circle.center[0]:.1f}, {circle.center[1]:.1f}), radius {circle.radius:.1f} px"
        )
    if grey:
        to_measured = [row["grey_to_measured_deg"] for row in rows]
        to_reference = [row["grey_to_reference_deg"] for row in rows]
        closer = sum(m < r for m, r in zip(to_measured, to_reference))
        summary["grey_check"] = {
            "median_to_measured_deg": float(np.median(to_measured)),
            "median_to_reference_deg": float(np.median(to_reference)),
            "measured_closer": closer,
        }
        print(
            f"grey-sphere Lambertian directions: median {np.median(to_measured):.2f}° from the measured, "
            f"{np.median(to_reference):.2f}° from the reference; the measured is closer in {closer} of {COUNT} images"
        )
    payload = {
        "benchmark": "real_lights",
        "date": time.strftime("%Y-%m-%d"),
        "machine": machine,
        "data": folder.name,
        "camera": camera.to_dict(),
        "circle": circle.to_dict(),
        "seconds": seconds,
        "summary": summary,
        "rows": rows,
    }
    bench_common.write_json(args.json, payload)


if __name__ == "__main__":
    main()
