"""strauss_fit.numerics: the Jacobian by columns and by vmapped rows give what jax.jacfwd gives."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from strauss_fit.numerics import value_and_jacobian_columns, value_and_jacobian_rows

BOTH = pytest.mark.parametrize("value_and_jacobian", [value_and_jacobian_columns, value_and_jacobian_rows])


def _curve(x):
    # nonlinear in every entry, with cross terms, so that each column differs
    return jnp.concatenate([jnp.sin(x) * x[0], jnp.exp(x[1] * x) + x[2] ** 3, jnp.array([x @ x])])


@BOTH
def test_value_and_jacobian_match_jacfwd(x64, value_and_jacobian):
    x = jnp.asarray([0.3, -0.7, 1.1, 0.2])
    value, columns = jax.jit(lambda z: value_and_jacobian(_curve, z))(x)
    assert columns.shape == (4, 9)
    np.testing.assert_allclose(np.asarray(value), np.asarray(_curve(x)), rtol=1e-15)
    np.testing.assert_allclose(np.asarray(columns), np.asarray(jax.jacfwd(_curve)(x)).T, rtol=1e-14, atol=1e-15)


@BOTH
def test_value_and_jacobian_batch_over_points(x64, value_and_jacobian):
    """vmapped over points (as a batch of fits runs it), each point's own Jacobian."""
    points = jnp.asarray([[0.3, -0.7, 1.1, 0.2], [1.0, 0.5, -0.4, 2.0]])
    values, columns = jax.jit(jax.vmap(lambda x: value_and_jacobian(_curve, x)))(points)
    for point, value, column in zip(points, values, columns):
        np.testing.assert_allclose(np.asarray(value), np.asarray(_curve(point)), rtol=1e-15)
        np.testing.assert_allclose(np.asarray(column), np.asarray(jax.jacfwd(_curve)(point)).T, rtol=1e-14, atol=1e-15)


@BOTH
def test_value_and_jacobian_without_parameters(x64, value_and_jacobian):
    """P = 0 (a problem with nothing free): the value and an empty (0, M) Jacobian, as
    jax.jacfwd gives (M, 0)."""
    value, columns = value_and_jacobian(lambda z: jnp.ones(6) * (1.0 + z.sum()), jnp.zeros(0))
    np.testing.assert_array_equal(np.asarray(value), np.ones(6))
    assert columns.shape == (0, 6)


def test_high_percentile_is_numpys_percentile_exactly():
    """`high_percentile` narrows to the values above a sampled threshold: the same number
    as ``np.percentile`` for every shape of data — ties, a constant image, heavy tails,
    sorted and reversed values, the largest values where the sample cannot see them, and
    where it sees only them (then it falls back) — and NaN and infinities as NumPy has them."""
    from strauss_fit.numerics import high_percentile

    rng = np.random.default_rng(7)
    n = 50_000
    cases = {
        "uniform": rng.random(n),
        "heavy tail": rng.pareto(1.5, n),
        "ties": rng.integers(0, 5, n).astype(float),
        "constant": np.full(n, 0.25),
        "sorted": np.sort(rng.random(n)),
        "reversed": np.sort(rng.random(n))[::-1].copy(),
        "image": rng.random((128, 129, 3)),
    }
    hidden = rng.random(n) + 1.0
    hidden[::16] = 0.0  # every sampled value is below every other
    cases["largest unsampled"] = hidden
    seen = np.zeros(n)
    seen[::16] = 10.0
    cases["sample sees only the largest"] = seen
    for name, values in cases.items():
        for q in (50, 90, 98, 99, 99.9, 100):
            assert high_percentile(values, q) == np.percentile(values, q), (name, q)
    small = rng.random(100)
    assert high_percentile(small, 98) == np.percentile(small, 98)
    with_nan, with_inf = rng.random(n), rng.random(n)
    with_nan[3], with_inf[5] = np.nan, np.inf
    assert np.isnan(high_percentile(with_nan, 98))
    with np.errstate(invalid="ignore"):  # NumPy's own answers (NaN at 100: inf − inf)
        for q in (98, 100):
            np.testing.assert_equal(high_percentile(with_inf, q), np.percentile(with_inf, q))
    single = rng.random(n).astype(np.float32)  # NumPy interpolates float32 in float32
    assert high_percentile(single, 98) == np.percentile(single, 98)
    for q in (101, -1, float("nan")):
        with pytest.raises(ValueError):
            high_percentile(rng.random(n), q)
