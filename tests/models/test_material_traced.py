"""Materials built from traced values (a custom loss under jax.grad): no validation error,
and gradients equal to finite differences; concrete values are still validated."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import strauss_fit as sf
from strauss_fit.errors import MaterialError

pytestmark = pytest.mark.usefixtures("x64")

N = jnp.array([0.0, 0.6, 0.8])
L = jnp.array([0.3, 0.2, 0.9327379053088815])
V = jnp.array([0.0, 0.0, 1.0])


def strauss_loss(p):
    material = sf.Material(color=(p[0], p[1], p[2]), smoothness=p[3], metalness=p[4])
    return jnp.sum((sf.shade(material, N, L, V) - 0.3) ** 2)


def phong_loss(p):
    material = sf.PhongMaterial(kd=(p[0], p[1], p[2]), ks=p[3], exponent=p[4], diffuse_color=(p[0], 1.0, 1.0))
    return jnp.sum((sf.phong_shade(material, N, L, V) - 0.3) ** 2)


@pytest.mark.parametrize(
    "loss,point",
    [
        (strauss_loss, [0.6, 0.4, 0.2, 0.5, 0.3]),
        (phong_loss, [0.6, 0.4, 0.2, 0.5, 12.0]),
    ],
)
def test_gradient_through_a_material_of_traced_values_matches_finite_differences(loss, point):
    p = jnp.array(point)
    gradient = np.asarray(jax.grad(loss)(p))
    step = 1e-6
    numeric = [(float(loss(p.at[i].add(step))) - float(loss(p.at[i].add(-step)))) / (2 * step) for i in range(p.size)]
    np.testing.assert_allclose(gradient, numeric, rtol=1e-5, atol=1e-9)
    assert np.all(np.isfinite(np.asarray(jax.jit(jax.grad(loss))(p))))


def test_concrete_values_are_still_validated():
    with pytest.raises(MaterialError, match="color"):
        sf.Material(color=(0.5, 1.5, 0.2))
    with pytest.raises(MaterialError, match="smoothness"):
        sf.Material(smoothness=float("nan"))
    with pytest.raises(MaterialError, match="kd"):
        sf.PhongMaterial(kd=(0.5, -1.0, 0.2))
