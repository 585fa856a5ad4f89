"""The one expand-then-bisect search of both equivalence ranges (a single image's and a
capture's), on distances whose crossing is known by hand."""

from __future__ import annotations

import pytest

from strauss_fit.engine import run
from strauss_fit.fitting.equivalence import range_end_steps


def linear_distance(centre: float, slope: float, calls: list):
    """|v − centre|·slope, as steps that run no Call; the warm value passed is recorded."""

    def steps(v: float, warm):
        calls.append((v, warm))
        return abs(v - centre) * slope, ("solution at", v)
        yield  # unreachable: a generator

    return steps


@pytest.mark.parametrize("direction, bound", [(-1.0, -10.0), (1.0, 10.0)])
def test_the_end_is_within_the_last_step_halved_bisections_times_and_never_beyond(direction, bound):
    calls = []
    # crossing at centre ± 0.3: steps 0.02, 0.04, 0.08, 0.16 inside, 0.32 outside
    end = run(range_end_steps(linear_distance(0.5, 10.0, calls), 0.5, bound + 0.5, direction, 0.02, 3.0, 10, "w0"))
    exact = 0.5 + direction * 0.3
    assert abs(end - exact) <= 0.16 / 2**10 + 1e-15
    assert abs(end - 0.5) <= 0.3 + 1e-15  # inside: the distance there is within the threshold
    assert len(calls) == 5 + 10  # five doublings (the fifth crosses), ten bisections
    assert calls[0] == (0.5 + direction * 0.02, "w0")
    # each evaluation is warm-started from the solution at the last point found inside
    inside_points = [v for v, _ in calls if abs(v - 0.5) * 10.0 <= 3.0]
    assert calls[1][1] == ("solution at", inside_points[0])


def test_a_bound_within_the_threshold_is_the_end():
    calls = []
    end = run(range_end_steps(linear_distance(0.9, 1.0, calls), 0.9, 1.0, 1.0, 0.02, 1.0, 10, None))
    assert end == 1.0
    assert [v for v, _ in calls] == pytest.approx([0.92, 0.94, 0.98, 1.0])


def test_a_centre_on_its_bound_is_its_own_end():
    calls = []
    end = run(range_end_steps(linear_distance(0.0, 1.0, calls), 0.0, 0.0, -1.0, 0.02, 1.0, 10, None))
    assert end == 0.0 and [v for v, _ in calls] == [0.0]
