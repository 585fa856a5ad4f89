"""`strauss_fit.numerics.device_array` and `ones_like`: the arrays ``jnp.asarray`` and
``jnp.ones_like`` give (values, dtype, weak type, shape), in float64 and float32 scopes,
without a compiled program for concrete values — and what builds scenes and materials uses
them (a parsed scene and a material trace nothing)."""

from __future__ import annotations

import itertools
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import strauss_fit as sf
from strauss_fit.numerics import device_array, ones_like

VALUES = [
    0.5,
    3,
    True,
    2 + 1j,
    (0.1, 0.2, 0.3),
    [1, 2],
    [1, 2.5],
    [[1.0, 2.0], [3.0, 4.0]],
    (True, False),
    np.float32(0.5),
    np.float64(0.25),
    np.int32(3),
    np.bool_(True),
    np.array([1.0, 2.0]),
    np.array([1, 2], np.int8),
    np.zeros((2, 3), np.float32),
    [],
    [np.float32(1.0), 2.0],  # a mixed list: JAX's own dtype rule (float32), not NumPy's
    [2**40, 3],  # too large for int32: JAX refuses it where NumPy would wrap it
    np.array([2**40, 3]),
]
DTYPES = [None, np.float32, np.float64, jnp.float32, float, "float32", np.int32]


class Traces:
    """Counts the functions JAX traces (each a program to compile or to read from a cache)."""

    def __enter__(self):
        self.count = 0

        def on_duration(event: str, duration: float, **_: object) -> None:
            if event == "/jax/core/compile/jaxpr_trace_duration":
                self.count += 1

        self._listener = on_duration
        jax.monitoring.register_event_duration_secs_listener(on_duration)
        return self

    def __exit__(self, *exc):
        jax.monitoring.unregister_event_duration_listener(self._listener)


def same(a, b) -> bool:
    return (
        a.dtype == b.dtype
        and a.weak_type == b.weak_type
        and a.shape == b.shape
        and np.array_equal(np.asarray(a), np.asarray(b))
    )


@pytest.mark.parametrize("x64", [True, False])
def test_device_array_is_jnp_asarray(x64):
    scope = sf.float64() if x64 else jax.enable_x64(False)
    with scope:
        for value, dtype in itertools.product(VALUES, DTYPES):
            if not x64 and dtype in (np.float64, float):
                continue  # jnp.asarray warns there, and truncates as device_array does
            try:
                expected = jnp.asarray(value, dtype=dtype)
            except (TypeError, OverflowError) as refused:  # refused by both, the same way
                with pytest.raises(type(refused)):
                    device_array(value, dtype)
                continue
            assert same(device_array(value, dtype), expected), (value, dtype)


def test_device_array_compiles_nothing_for_concrete_values(x64):
    # shapes no other test uses, so that nothing is already in JAX's in-memory caches
    fresh = [np.arange(7.0 * 11).reshape(7, 11), [[0.5] * 13] * 3, 0.125, np.full((5, 17), 3, np.int16)]
    with Traces() as traces:
        made = [device_array(value) for value in fresh] + [device_array(fresh[0], np.float32)]
        made += [ones_like(array) for array in made]
    assert traces.count == 0
    with Traces() as traces:  # what it replaces does compile (the test measures something)
        jnp.asarray(np.arange(19.0 * 3).reshape(19, 3), dtype=np.float32)
        jnp.zeros((3, 19))
    assert traces.count >= 1


def test_ones_like_is_jnp_ones_like(x64):
    weak_vector = jnp.broadcast_to(jax.device_put(0.5), (3,))
    assert weak_vector.weak_type
    for value in (
        jax.device_put(0.5),
        jnp.asarray(np.array([1.0, 2.0])),
        jnp.asarray(np.zeros((2, 2), np.int32)),
        weak_vector,
    ):
        assert same(ones_like(value), jnp.ones_like(value))
    with jax.enable_x64(False):
        weak32 = jax.device_put(0.5)
        assert weak32.dtype == np.float32 and same(ones_like(weak32), jnp.ones_like(weak32))


def test_traced_values_go_through_jax(x64):
    # a tuple of traced numbers (a material built inside jax.grad) and a traced array
    def loss(p):
        color = device_array((p[0], p[1], p[2]))
        return jnp.sum(color * ones_like(p[:3]) * device_array(p, jnp.float64))

    gradient = jax.grad(loss)(jnp.array([1.0, 2.0, 3.0]))
    np.testing.assert_allclose(np.asarray(gradient), [2.0, 4.0, 6.0])  # d(sum p_i²)/dp


# In a process of its own: JAX's in-memory caches would hide a program another test compiled.
SET_UP = """
import sys, jax, numpy as np, strauss_fit as sf
traces = []
jax.monitoring.register_event_duration_secs_listener(
    lambda event, duration, **_: traces.append(event) if event == "/jax/core/compile/jaxpr_trace_duration" else None
)
with sf.float64():
    scene = sf.load_scene(sys.argv[1])
    material = sf.Material(color=(0.2, 0.3, 0.4), smoothness=0.7, metalness=1, transparency=0.0, ior=1.5)
    material.astype(np.float32)
print(len(traces))
"""


@pytest.mark.parametrize("name", ["two_lights.toml", "key_light.toml"])
def test_scene_and_material_set_up_compiles_nothing(scenes_dir, name):
    done = subprocess.run(
        [sys.executable, "-c", SET_UP, str(scenes_dir / name)], capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["0"]


def test_a_device_array_does_not_share_the_callers_buffer(x64):
    # jax.device_put may use a NumPy array's memory as it is on a CPU: a material made from a
    # row of the caller's array would change with it (the review of 2026-12-04 saw it)
    colors = np.random.default_rng(0).random((20000, 3))
    materials = [sf.Material(color=colors[i]) for i in range(32)]
    arrays = [device_array(colors[i]) for i in range(32)]
    expected = colors[:32].copy()
    colors[:] = 0.0
    for i in range(32):
        np.testing.assert_array_equal(np.asarray(materials[i].color), expected[i])
        np.testing.assert_array_equal(np.asarray(arrays[i]), expected[i])


def test_a_material_of_integers_is_what_it_was(x64):
    # Material(metalness=1) (a TOML "metalness = 1"): the default float, not weakly typed
    material = sf.Material(color=(1, 0, 1), smoothness=0, metalness=1)
    for leaf in (material.color, material.smoothness, material.metalness):
        assert leaf.dtype == np.float64 and not leaf.weak_type
    with jax.enable_x64(False):
        assert sf.models.material._as_float(1, None).dtype == np.float32


def test_astype_keeps_a_material_where_it_was_placed(x64):
    device = jax.devices()[-1]
    material = sf.Material(color=(0.2, 0.3, 0.4), smoothness=0.5)
    placed = jax.tree_util.tree_map(lambda leaf: jax.device_put(leaf, device), material)
    cast = placed.astype(np.float32)
    for leaf in jax.tree_util.tree_leaves(cast):
        assert leaf.dtype == np.float32 and leaf.devices() == {device} and leaf.committed
    same = material.astype(np.float64)
    assert same.color is material.color  # already float64, strongly typed: untouched
