"""strauss_fit.numerics: the Jacobian by columns gives what jax.jacfwd gives."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from strauss_fit.numerics import value_and_jacobian_columns


def _curve(x):
    # nonlinear in every entry, with cross terms, so that each column differs
    return jnp.concatenate([jnp.sin(x) * x[0], jnp.exp(x[1] * x) + x[2] ** 3, jnp.array([x @ x])])


def test_value_and_jacobian_columns_match_jacfwd(x64):
    x = jnp.asarray([0.3, -0.7, 1.1, 0.2])
    value, columns = value_and_jacobian_columns(_curve, x)
    assert columns.shape == (4, 9)
    np.testing.assert_allclose(np.asarray(value), np.asarray(_curve(x)), rtol=1e-15)
    np.testing.assert_allclose(np.asarray(columns), np.asarray(jax.jacfwd(_curve)(x)).T, rtol=1e-14, atol=1e-15)


def test_value_and_jacobian_columns_batch_over_points(x64):
    """vmapped over points (as a batch of fits runs it), each point's own Jacobian."""
    points = jnp.asarray([[0.3, -0.7, 1.1, 0.2], [1.0, 0.5, -0.4, 2.0]])
    values, columns = jax.jit(jax.vmap(lambda x: value_and_jacobian_columns(_curve, x)))(points)
    for point, value, column in zip(points, values, columns):
        np.testing.assert_allclose(np.asarray(value), np.asarray(_curve(point)), rtol=1e-15)
        np.testing.assert_allclose(np.asarray(column), np.asarray(jax.jacfwd(_curve)(point)).T, rtol=1e-14, atol=1e-15)


def test_value_and_jacobian_columns_without_parameters(x64):
    """P = 0 (a problem with nothing free): the value and an empty (0, M) Jacobian, as
    jax.jacfwd gives (M, 0)."""
    value, columns = value_and_jacobian_columns(lambda z: jnp.ones(6) * (1.0 + z.sum()), jnp.zeros(0))
    np.testing.assert_array_equal(np.asarray(value), np.ones(6))
    assert columns.shape == (0, 6)
