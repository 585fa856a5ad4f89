"""Equivalence ranges and stability of a capture's fit (issue 25, items 1 and 6)."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from data_synth.capture import example_capture_spec, write_capture
from strauss_fit.capture import load_samples, open_capture
from strauss_fit.fitting.capture import CaptureFitOptions, fit_capture_samples
from strauss_fit.fitting.capture_equivalence import capture_equivalence
from strauss_fit.fitting.capture_stability import _degenerate, halves

SMALL = dict(frame=(120, 96), center_px=(60.3, 47.8), radius_px=30.0, supersample=1, seed=5)


@pytest.fixture(scope="module")
def plastic(tmp_path_factory):
    folder = tmp_path_factory.mktemp("plastic")
    write_capture(example_capture_spec("plastic", noise_sd=0.003, **SMALL), folder)
    samples = load_samples(open_capture([folder]))
    return folder, samples, fit_capture_samples(samples, CaptureFitOptions())


def test_equivalence_ranges_hold_the_fit_and_nest_with_the_threshold(plastic):
    _, samples, fit = plastic
    wide = capture_equivalence(samples, fit)
    narrow = capture_equivalence(samples, fit, delta_e=0.1)
    values = fit.values()
    for name in ("smoothness", "metalness"):
        low, high = narrow[name]
        assert low <= values[name] <= high
        # a stricter threshold can only shrink the range
        assert wide[name][0] <= low + 1e-9 and high <= wide[name][1] + 1e-9
    # one tenth of a JND leaves a narrow smoothness range on a capture with 12 highlights
    assert narrow["smoothness"][1] - narrow["smoothness"][0] < 0.2
    for k in range(3):
        assert narrow["color"][k][0] <= values["color"][k] <= narrow["color"][k][1]


def test_two_halves_of_a_consistent_capture_are_stable(plastic):
    _, samples, _ = plastic
    out = halves(samples, CaptureFitOptions(), delta_e=0.5)
    assert out["stable"] and set(out["agree"]) == {"smoothness", "metalness"}
    odd, even = out["halves"]
    assert not set(odd["images"]) & set(even["images"])
    assert len(odd["images"]) + len(even["images"]) == samples.count
    assert abs(odd["values"]["smoothness"] - even["values"]["smoothness"]) < 0.02


def test_a_back_light_is_named_degenerate(tmp_path):
    # one image lit from 130° off the view axis: (1 + cos 130°)/2 = 18 % of the disc is lit
    angle = math.radians(130)
    lights = [[{"direction": [math.sin(angle), 0.0, math.cos(angle)], "intensity": 1.0}]]
    write_capture(example_capture_spec("plastic", lights=lights, noise_sd=0.002, exposure=[1.0], **SMALL), tmp_path)
    samples = load_samples(open_capture([tmp_path]))
    fit = fit_capture_samples(samples, CaptureFitOptions())
    reasons = _degenerate(samples, 0, fit, ("smoothness", "metalness"))
    assert any("grazes" in r for r in reasons), reasons
    share = float(reasons[0].split(": ")[1].split(" %")[0])
    assert 14 <= share <= 22


def test_cli_equivalence_and_stability(plastic, tmp_path):
    folder, _, _ = plastic
    out = tmp_path / "fit.json"
    run = subprocess.run(
        [sys.executable, "-m", "strauss_fit_cli.main", "fit", "--capture", str(folder), "--equivalence",
         "--equivalence-de", "0.5", "--stability", "-o", str(out), "--quiet"],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    result = json.loads(out.read_text())
    assert result["equivalence_delta_e"] == 0.5
    low, high = result["equivalence"]["smoothness"]
    assert low <= result["smoothness"] <= high
    single = result["stability"]["single_images"]
    assert len(single["fits"]) == result["images_fitted"]
    assert single["disagreeing"] == sum(1 for row in single["fits"] if row.get("disagrees"))
    assert "looks the same" in run.stdout and "stability, two halves" in run.stdout
    assert np.isfinite(result["stability"]["halves"][0]["values"]["smoothness"])
