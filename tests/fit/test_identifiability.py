"""The numerical half of the identifiability analysis, on hand-made Jacobians."""

import numpy as np

from strauss_fit.fitting.identifiability import numerical_decision
from strauss_fit.fitting.parameters import Layout


def test_an_exact_degeneracy_is_unconstrained_not_pinned():
    # metalness moves the image exactly as a combination of the colour channels does: a
    # pseudo-inverse would drop that direction and report tiny deviations for both
    rng = np.random.default_rng(0)
    color = rng.normal(size=(300, 3))
    smoothness = rng.normal(size=(300, 1))
    metalness = color @ np.array([[0.5], [-1.0], [2.0]])
    jacobian = np.hstack([color, smoothness, metalness])
    layout = Layout(("color", "smoothness", "metalness"))
    probe = np.array([0.5, 0.5, 0.5, 0.5, 0.5])
    decision = numerical_decision(layout, jacobian, probe, sigma=0.01)
    assert decision.free == ["color", "smoothness"]
    assert decision.partner["metalness"] == "color"
    assert "trades off with color" in decision.held["metalness"]


def test_well_conditioned_parameters_are_all_fitted_and_a_dead_one_is_held():
    rng = np.random.default_rng(1)
    jacobian = rng.normal(size=(400, 5))
    layout = Layout(("color", "smoothness", "metalness"))
    probe = np.full(5, 0.5)
    assert numerical_decision(layout, jacobian, probe, sigma=0.01).free == ["color", "smoothness", "metalness"]
    jacobian[:, 3] = 0.0  # the image does not depend on smoothness at all
    decision = numerical_decision(layout, jacobian, probe, sigma=0.01)
    assert decision.free == ["color", "metalness"]
    assert decision.held["smoothness"] == "the image does not change with it at all"
    assert decision.partner["smoothness"] is None
