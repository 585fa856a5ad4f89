"""Noise levels at the edges of float64 (issue 24, item 4): a ``--noise`` (one value or
R, G, B), ``--reference-noise`` or ``sample --sigma`` whose square or inverse square leaves
float64's range is a one-line error before any work, never a fit whose deviations come out
NaN; the noise sandwich does not depend on the scale the residuals were divided by; and a
fit result never hands NaN or infinity on (to a JSON writer or to anyone).
"""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest

import strauss_fit as sf
from strauss_fit.fitting.problem import build_problem
from strauss_fit.fitting.result import FitResult, FitResultError, finite_or_none, nonfinite_entry
from strauss_fit.io.images import write_image
from strauss_fit.rendering.strauss import plan_render
from strauss_fit.stats.laplace import problem_sandwich
from strauss_fit.stats.noise import NOISE_RANGE, check_noise_level, describe_noise
from strauss_fit_cli.main import main
from support import SMALL_MATERIAL, key_and_fill_scene, key_and_fill_toml

RANGE_MESSAGE = "from 1e-100 to 1e+100"


@pytest.fixture
def inputs(tmp_path):
    (tmp_path / "scene.toml").write_text(key_and_fill_toml(24, material=SMALL_MATERIAL))
    write_image(tmp_path / "target.exr", np.full((24, 24, 3), 0.3))
    return tmp_path


def one_line_error(capsys, folder, argv, *expected):
    before = sorted(p.name for p in folder.iterdir())
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("strauss-fit: error: "), err
    assert "Traceback" not in err
    for text in expected:
        assert text in lines[0], err
    assert sorted(p.name for p in folder.iterdir()) == before  # nothing written


@pytest.mark.parametrize(
    "option,value,shown",
    [
        ("--noise", "1e300", "1e+300"),  # σ² overflowed: every deviation NaN, JSON refused it
        ("--noise", "1e-300", "1e-300"),  # σ² underflowed to 0
        ("--noise", "1e300,0.01,0.01", "1e+300, 0.01, 0.01"),  # one channel is enough
        ("--noise", "0.01,1e-120,0.01", "0.01, 1e-120, 0.01"),
        ("--reference-noise", "1e300", "1e+300"),  # the identifiability analysis overflowed
        ("--reference-noise", "1e-300", "1e-300"),  # every start "diverged"
    ],
)
def test_fit_refuses_a_noise_level_beyond_float64_in_one_line(capsys, inputs, option, value, shown):
    argv = ["fit", inputs / "target.exr", "--scene", inputs / "scene.toml", "-o", inputs / "r.json"]
    one_line_error(capsys, inputs, argv + [option, value], option, RANGE_MESSAGE, f"got {shown}")


@pytest.mark.parametrize("value", ["1e300", "1e-300"])
def test_sample_refuses_a_sigma_beyond_float64_in_one_line(capsys, inputs, value):
    argv = ["sample", inputs / "target.exr", "--scene", inputs / "scene.toml", "-o", inputs / "c.h5"]
    one_line_error(capsys, inputs, argv + ["--sigma", value], "--sigma", RANGE_MESSAGE)


def test_the_noise_range_leaves_float64_room_on_both_sides():
    low, high = NOISE_RANGE
    for sigma in (low, high):
        assert math.isfinite(sigma**2) and sigma**2 > 1e-300 and math.isfinite(1 / sigma**2)
    np.testing.assert_array_equal(check_noise_level(low), np.full(3, low))
    np.testing.assert_array_equal(check_noise_level((high, 0.5, low)), [high, 0.5, low])
    for bad in (high * 10, low / 10, (0.1, 0.1), float("nan"), -1.0, 0.0):
        with pytest.raises(sf.StraussFitError, match="the noise level must"):
            check_noise_level(bad)


def test_a_given_or_recorded_noise_beyond_the_range_is_not_used(tmp_path):
    pixels = np.full((8, 8, 3), 0.3)
    usable = np.ones((8, 8), dtype=bool)
    with pytest.raises(sf.StraussFitError, match=re.escape(RANGE_MESSAGE)):
        describe_noise(pixels, usable, given=1e300)
    # a sidecar's measured noise or sensor beyond the range is ignored, as a malformed one is
    for sidecar in ({"noise": {"per_channel": [1e300, 0.01, 0.01]}}, {"sensor": {"gain": 1e-300, "read_noise": 0}}):
        model = describe_noise(pixels, usable, sidecar={"format": "strauss-fit synth sample", **sidecar})
        assert model.source != "sensor" and np.all(np.isfinite(model.b)) and np.all(np.isfinite(model.a))
    usable_sidecar = {"format": "strauss-fit synth sample", "sensor": {"gain": 2000.0, "read_noise": 0.004}}
    assert describe_noise(pixels, usable, sidecar=usable_sidecar).source == "sensor"


@pytest.mark.usefixtures("x64")
def test_the_noise_sandwich_does_not_depend_on_the_scale_of_the_residuals():
    """The residuals a fit minimises are divided by the reference noise: with one of 1e-100
    the sandwich's meat overflowed and every deviation came out NaN."""
    truth = dict(color=(0.6, 0.4, 0.3), smoothness=0.6, metalness=0.3)
    scene = key_and_fill_scene(24, material=truth)
    image, mask = sf.render(scene, sf.Material(**truth))
    image = np.asarray(image) + np.random.default_rng(5).normal(0.0, 0.004, np.shape(image))
    target = sf.Target(image, np.ones(np.shape(mask), bool), "synthetic.exr", "linear", 0, 0)
    material = sf.Material(**truth)
    plan = plan_render(scene, material, transparent=False)
    free = ["color", "smoothness", "metalness"]
    x = np.array([0.6, 0.4, 0.3, 0.6, 0.3])
    covariances = []
    for reference in (0.004, 1e-100, 1e100):
        problem = build_problem(scene, target, free, material, plan, sf.FitOptions(), reference)[0]
        _, _, cov, extra = problem_sandwich(problem, x, np.full(problem.target.size, 0.004))
        assert np.all(np.isfinite(cov)) and np.all(np.isfinite(extra["curvature_eigenvalues"]))
        covariances.append(cov)
    np.testing.assert_allclose(covariances[1], covariances[0], rtol=1e-9, atol=0)
    np.testing.assert_allclose(covariances[2], covariances[0], rtol=1e-9, atol=0)


def test_a_fit_result_never_hands_on_a_nan():
    result = FitResult(
        material=sf.Material(color=(0.5, 0.5, 0.5), smoothness=0.5),
        free=["color", "smoothness"],
        uncertainty={"color": [0.01, 0.01, 0.01], "smoothness": float("nan")},
    )
    with pytest.raises(FitResultError, match=r"the fit result's uncertainty\.smoothness is nan") as raised:
        result.to_json()
    assert "\n" not in str(raised.value)
    result.uncertainty["smoothness"] = 0.02
    result.residual = {"noise": [np.float64(np.inf), 0.01, 0.01]}
    with pytest.raises(FitResultError, match=r"residual\.noise\[0\] is inf"):
        result.to_json()
    result.residual = {"noise": [0.01, 0.01, 0.01]}
    json.dumps(result.to_json(), allow_nan=False)  # finite: written as it is
    assert nonfinite_entry({"a": [1.0, {"b": np.array([0.0, -np.inf])}]}) == ("a[1].b[1]", -np.inf)


def test_a_start_that_diverged_is_written_with_null_figures():
    record = {"start": {"smoothness": 0.5}, "end": {"color": [np.nan, 0.2, 0.3], "smoothness": np.inf}, "cost": np.nan}
    assert finite_or_none(record) == {
        "start": {"smoothness": 0.5},
        "end": {"color": [None, 0.2, 0.3], "smoothness": None},
        "cost": None,
    }
