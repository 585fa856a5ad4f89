"""Host-only methods of equinox modules are read as plain callables (strauss_fit._host_methods)."""

from __future__ import annotations

import functools

import equinox as eqx
import numpy as np

from strauss_fit import Material
from strauss_fit._host_methods import host_method


class _Box(eqx.Module):
    value: float

    @host_method
    def doubled(self, extra: float = 0.0) -> float:
        """Twice the value, plus ``extra``."""
        return 2 * self.value + extra

    def tripled(self) -> float:
        return 3 * self.value


def test_a_host_method_is_a_partial_not_equinoxs_bound_method():
    box = _Box(1.5)
    read = box.doubled
    assert isinstance(read, functools.partial) and not isinstance(read, eqx.Module)
    assert read(0.25) == 3.25
    assert _Box.doubled(box) == 3.0  # from the class: the function itself
    assert _Box.doubled.__doc__ == "Twice the value, plus ``extra``."
    assert isinstance(box.tripled, eqx.Module)  # a plain method is still equinox's pytree


def test_materials_host_methods_give_their_values():
    material = Material(color=(0.7, 0.4, 0.2), smoothness=0.6, metalness=0.3)
    assert not isinstance(material.to_dict, eqx.Module)
    values = material.to_dict()
    np.testing.assert_allclose(values["color"], [0.7, 0.4, 0.2])
    assert values["smoothness"] == 0.6 and values["metalness"] == 0.3
