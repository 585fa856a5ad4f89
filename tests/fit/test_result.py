"""FitResult and its JSON: from_json is the one reader of a fit result, and reading back
what to_json wrote (with the keys the command line adds) gives the same document."""

import json

import numpy as np
import pytest

import strauss_fit as sf
from strauss_fit.fitting.result import FitResult, FitResultError
from support import key_and_fill_scene, legacy_options, noisy_target


@pytest.fixture(scope="module")
def payload():
    scene = key_and_fill_scene(16, source="result")
    target = noisy_target(scene, sf.Material(color=(0.7, 0.4, 0.2), smoothness=0.6, metalness=0.3), 0.01, 4)
    result = sf.fit(scene, target, legacy_options(free=("color", "smoothness", "metalness")))
    document = result.to_json()
    document.update(target="t.exr", scene="s.toml", mask=None, encoding="auto")
    return json.loads(json.dumps(document))  # as read from a file


def test_reading_back_a_fit_result_gives_the_same_document(payload):
    result = FitResult.from_json(payload)
    assert result.to_json() == payload and list(result.to_json()) == list(payload)
    assert result.free == ["color", "smoothness", "metalness"] and result.problem is None
    assert result.extra == {"target": "t.exr", "scene": "s.toml", "mask": None, "encoding": "auto"}
    np.testing.assert_array_equal(np.asarray(result.material.color), payload["color"])
    assert result.value("smoothness") == payload["smoothness"] and result.at_bound == payload["solver"]["at_bound"]
    assert FitResult.from_json(result) is result


@pytest.mark.parametrize(
    "document,pattern",
    [
        ({"hello": 1}, r"missing or bad 'free'"),
        ([1, 2], "not a JSON object"),
        ({"free": ["color"], "color": [0.5, 0.5, 0.5]}, r"missing or bad 'smoothness'"),
    ],
)
def test_what_is_not_a_fit_result_is_a_one_line_error(document, pattern):
    with pytest.raises(FitResultError, match=pattern) as info:
        FitResult.from_json(document)
    assert "\n" not in str(info.value) and isinstance(info.value, sf.StraussFitError)


def test_values_out_of_range_name_the_field(payload):
    with pytest.raises(sf.MaterialError, match="smoothness"):
        FitResult.from_json(dict(payload, smoothness=1.5))


@pytest.mark.parametrize(
    "change,pattern",
    [
        (dict(free=["<b>x</b>"]), r"frees '<b>x</b>', of which it records no value"),
        (dict(free=["color", "directional_intensity_9"]), r"frees 'directional_intensity_9'"),
        (dict(free="smoothness"), r"'free' is not a list"),
        (dict(uncertainty={"smoothness": "abc"}), r"uncertainty of 'smoothness' is not a finite number"),
        (dict(uncertainty={"color": [0.1, 0.2]}), r"uncertainty of 'color'"),
        (dict(correlation={"labels": ["x"], "matrix": [[1, 2], [3]]}), r"correlation is not a square matrix"),
        (dict(correlation={"names": ["x"]}), r"correlation is not a square matrix"),
        (dict(exposure=float("nan")), r"exposure is not a positive finite number"),
        (dict(exposure=-1.0), r"exposure is not a positive finite number"),
        (dict(lights={"x": "y"}), r"a bad value: could not convert"),
    ],
)
def test_what_the_readers_rely_on_is_checked_when_read(payload, change, pattern):
    """The report and ``sample --fit`` read these fields: a bad one is a one-line error here,
    not a traceback there (a hostile-user pass found KeyError and ValueError tracebacks)."""
    with pytest.raises(FitResultError, match=pattern) as info:
        FitResult.from_json(dict(payload, **change))
    assert "\n" not in str(info.value)
