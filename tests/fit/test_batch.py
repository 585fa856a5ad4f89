"""Many targets in one call (issue 16): the engine, :func:`strauss_fit.fit_many`, executors."""

from __future__ import annotations

import numpy as np
import pytest

import strauss_fit as sf
import support
from strauss_fit.engine import Kernel, run, run_batched
from strauss_fit.fitting.batch import FitFailure, FitJob, fit_many

FREE = ("color", "smoothness", "metalness")


def _targets(scene, count, seed=0, noise=0.005):
    rng = np.random.default_rng(seed)
    out = []
    for i in range(count):
        material = sf.Material(
            color=tuple(rng.uniform(0.1, 0.9, 3)),
            smoothness=float(rng.uniform(0.1, 0.9)),
            metalness=float(rng.uniform(0.0, 1.0)),
        )
        image, _ = sf.render(scene, material)
        image = np.asarray(image) + rng.normal(0.0, noise, np.shape(image))
        out.append(sf.Target(image, np.ones(image.shape[:2], dtype=bool), f"t{i}.exr", "linear", 0, 0))
    return out


def _same(a: sf.FitResult, b: sf.FitResult) -> None:
    assert a.free == b.free and a.held.keys() == b.held.keys()
    np.testing.assert_array_equal(np.asarray(a.x), np.asarray(b.x))
    assert [w["code"] for w in a.warnings] == [w["code"] for w in b.warnings]
    np.testing.assert_allclose(a.residual["rms"], b.residual["rms"], rtol=1e-12)


def _identical(a: sf.FitResult, b: sf.FitResult) -> None:
    """The same fit bit for bit: every number it reports (the times aside), its parameters
    and its fitted image."""
    ja, jb = a.to_json(), b.to_json()
    for data in (ja, jb):
        del data["wall_time_s"], data["timing"]
    assert ja == jb
    np.testing.assert_array_equal(np.asarray(a.x), np.asarray(b.x))
    np.testing.assert_array_equal(a.fitted_image, b.fitted_image)


def test_a_targets_fit_is_the_same_in_any_batch_and_compiles_nothing_new():
    """A target's fit does not depend on the batch it runs in: alone (``fit``) or among 1,
    3 or 7 targets, consistent or mismatched (refitted with the Huber loss), bit for bit —
    and once single fits have run, batches of any size compile nothing: every call runs a
    program of its kernel and problem shape, whatever the batch's size, the targets'
    divergence or the loss (:mod:`strauss_fit.engine`)."""
    scene = support.key_and_fill_scene(24, source="batch-sizes")
    data = support.key_and_fill_data(24)
    data["light"][0]["direction"] = [0.0, 0.8, 1.0]  # the key light moved: the model cannot match
    moved = sf.parse_scene(data, source="batch-sizes-moved")
    consistent, mismatched = _targets(scene, 5, seed=4), _targets(moved, 2, seed=5)
    targets = [consistent[0], mismatched[0], consistent[1], consistent[2], mismatched[1], *consistent[3:]]
    options = sf.FitOptions(free=FREE, noise=0.005)
    alone = [sf.fit(scene, target, options) for target in targets]
    assert [r.solver["loss"] for r in alone] == ["linear", "huber", "linear", "linear", "huber", "linear", "linear"]
    batches = {}

    def batched() -> None:
        for count in (1, 3, 7):
            batches[count] = fit_many(targets[:count], scene, options)

    assert support.compiled_during(batched) == []
    for count, results in batches.items():
        assert len(results) == count
        for result, single in zip(results, alone):
            _identical(result, single)


def test_a_batch_is_padded_to_its_bucket_and_the_padding_of_a_sequential_one_never_runs(x64):
    """:meth:`Kernel.run_many` pads a batch to a power of four (one program for 2 to 4
    items, one for 5 to 16, …); run one item after the other (a CPU), the padding rows are
    not run at all (a kernel that refuses them does not fail); side by side (vmap), they
    are copies of the first item. Either way each item gets what a call of its own gives."""
    import collections

    import equinox as eqx
    import jax

    from strauss_fit.engine import batch_bucket

    assert [batch_bucket(n) for n in (2, 3, 4, 5, 16, 17, 64, 65)] == [4, 4, 4, 16, 16, 64, 64, 256]
    traced = collections.Counter()

    def on_duration(event: str, seconds: float, **details) -> None:
        if event == "/jax/core/compile/jaxpr_trace_duration":
            traced[details.get("fun_name")] += 1

    kernel = Kernel(lambda a, b: eqx.error_if(a, a == 0.0, "a padding row ran") * b, "toy_padding")
    args = [(np.full(3, float(i)), np.arange(3.0)) for i in range(1, 8)]
    alone = [np.asarray(kernel(*a)) for a in args]
    jax.monitoring.register_event_duration_secs_listener(on_duration)
    try:
        for sequential in (True, False):
            for count in (2, 3, 4, 5, 7):
                for one, expected in zip(kernel.run_many(args[:count], sequential=sequential), alone):
                    np.testing.assert_array_equal(one, expected)
    finally:
        jax.monitoring.unregister_event_duration_listener(on_duration)
    assert traced["_batched"] == 4  # sizes 4 and 16, each sequential and side by side


def test_kernels_run_on_the_compute_device_unless_one_was_chosen(x64):
    """Every kernel runs on one device (:func:`strauss_fit.engine.compute_device`: on a CPU
    with several devices the second, the first being left to the eager operations), a
    single call as a batch's, so that they share their programs; a device chosen with
    ``jax.default_device`` is kept."""
    import jax

    from strauss_fit.engine import compute_device

    kernel = Kernel(lambda a: a + 1.0, "toy_where")
    devices = jax.local_devices()
    if jax.default_backend() != "cpu" or len(devices) < 2:
        assert compute_device() is None
        pytest.skip("one device: everything runs on it")
    assert compute_device() == devices[1]
    assert kernel(np.ones(3)).devices() == {devices[1]}
    with jax.default_device(devices[0]):
        assert kernel(np.ones(3)).devices() == {devices[0]}


def test_kernels_give_the_same_values_alone_and_in_a_batch(x64):
    import jax.numpy as jnp

    kernel = Kernel(lambda a, b, scale: jnp.sin(a) * b + scale, "toy")
    args = [(np.full(3, float(i)), np.arange(3.0), 0.5) for i in range(5)]
    batched = kernel.run_many(args)
    for one, (a, b, scale) in zip(batched, args):
        np.testing.assert_array_equal(one, np.asarray(kernel(a, b, scale)))


def test_an_array_shared_by_every_item_is_passed_once_with_the_same_values(x64):
    """A conversion's materials share their problem's prepared geometry: the same array
    object in every item is passed once, unstacked, and each item still gets its own
    result; an equal array that is a different object is stacked as usual."""
    import jax.numpy as jnp

    from strauss_fit.engine import _stack_items, split_arguments

    geometry = np.linspace(0.0, 1.0, 12).reshape(4, 3)
    kernel = Kernel(lambda own, common, power: jnp.sum(own[:, None] * common**power, axis=0), "toy_shared")
    args = [(np.full(4, float(i)), geometry, 2) for i in range(6)]
    stacked, shared = _stack_items([split_arguments(a)[0] for a in args])
    assert stacked[1] is None and shared[1] is geometry and stacked[0].shape == (6, 4) and shared[0] is None
    batched = kernel.run_many(args)
    for one, (own, common, power) in zip(batched, args):
        np.testing.assert_array_equal(one, np.asarray(kernel(own, common, power)))
    copies = [(own, common.copy(), power) for own, common, power in args]
    assert _stack_items([split_arguments(a)[0] for a in copies])[0][1].shape == (6, 4, 3)
    for one, other in zip(batched, kernel.run_many(copies)):
        np.testing.assert_array_equal(one, other)


def test_calls_group_by_structure_static_values_and_shapes(x64):
    """Two calls batch together exactly when their static values, tree structure and array
    shapes agree (:class:`strauss_fit.engine.StaticPart`), whatever the array values."""
    import jax.numpy as jnp

    from strauss_fit.engine import ARRAY_SLOT, batch_key, split_arguments

    kernel = Kernel(lambda a, settings: a * settings["scale"], "toy_key")

    def key(a, settings):
        return batch_key(kernel.call(a, settings))

    base = key(np.zeros(3), {"scale": 2.0, "name": "x"})
    assert key(np.ones(3), {"scale": 2.0, "name": "x"}) == base  # other values: one batch
    assert key(np.ones(4), {"scale": 2.0, "name": "x"}) != base  # other shape
    assert key(np.ones(3), {"scale": 3.0, "name": "x"}) != base  # other static value
    assert key(np.ones(3), {"scale": 2.0, "other": "x"}) != base  # other structure
    arrays, static = split_arguments((np.ones(3), {"scale": 2.0}))
    assert len(arrays) == 1 and static.leaves.count(ARRAY_SLOT) == 1
    np.testing.assert_array_equal(jnp.asarray(static.rebuild([np.arange(3.0)])[0]), np.arange(3.0))
    assert static.describe((float, int, str, bool, type(None))) is not None
    assert split_arguments((np.ones(3), {1, 2}))[1] is None  # a set cannot be hashed: no static part


def test_a_failing_step_generator_fails_alone(x64):
    import jax.numpy as jnp

    double = Kernel(lambda a: 2 * a, "double")

    def steps(value, fail):
        out = yield double.call(jnp.asarray(value))
        if fail:
            raise sf.StraussFitError("broken on purpose")
        out = yield double.call(out)
        return float(out)

    results = run_batched([steps(1.0, False), steps(2.0, True), steps(3.0, False)])
    assert results[0] == 4.0 and results[2] == 12.0
    assert isinstance(results[1], sf.StraussFitError)
    assert run(steps(5.0, False)) == 20.0


def test_a_large_batch_on_its_own_cpu_device_gives_what_run_gives(x64):
    """From 16 items per device on a batch runs on a CPU device after the first, while the
    steps' own eager JAX operations run on the default device and mix with its results."""
    import jax
    import jax.numpy as jnp

    from strauss_fit.engine import cohort_devices

    kernel = Kernel(lambda a, b: jnp.sin(a) * b, "toy_device")

    def steps(value):
        out = yield kernel.call(jnp.full(3, value), np.arange(3.0))
        mixed = jnp.asarray(out) + jnp.ones(3)  # eager, on the default device
        out = yield kernel.call(mixed, np.ones(3))
        return np.asarray(out)

    count = 40
    if jax.local_device_count() >= 2:
        assert all(device is not None and device != jax.devices()[0] for device in cohort_devices(count))
    batched = run_batched([steps(float(i)) for i in range(count)])
    for i, result in enumerate(batched):
        np.testing.assert_array_equal(result, run(steps(float(i))))


def test_an_error_raised_while_a_batch_runs_fails_its_item_alone(x64):
    """Batched calls are dispatched without waiting (:class:`strauss_fit.engine.Pending`):
    an error raised inside the compiled program (equinox's runtime check) surfaces only
    when the results are read. The batch is then run item by item, and only the item that
    raised fails."""
    import equinox as eqx
    import jax.numpy as jnp

    checked = Kernel(lambda a: eqx.error_if(a, a < 0, "negative on purpose") * 2, "checked")

    def steps(value):
        out = yield checked.call(jnp.asarray(value))
        out = yield checked.call(np.asarray(out))
        return float(np.asarray(out))

    values = [1.0, 2.0, -3.0, 4.0, 5.0, 6.0]
    results = run_batched([steps(v) for v in values])
    assert [r for i, r in enumerate(results) if i != 2] == [4.0 * v for v in values if v >= 0]
    assert isinstance(results[2], Exception) and "negative on purpose" in str(results[2])


def test_cohorts_run_on_cpu_devices_after_the_first(monkeypatch):
    """On a CPU with several devices the batches go to the devices after the first (left
    to the eager operations of the Python): as many as the cores less one for a fit's batch
    (its Python needs a core), one per core for a conversion's, one more device per 16
    items, two cohorts at least (as many as items, when fewer); a batch of any size uses
    the first of them, so that its programs do not depend on its size; with one device,
    two cohorts on the default device."""
    import jax

    from strauss_fit import engine

    devices = ["d0", "d1", "d2", "d3", "d4"]
    monkeypatch.setattr(jax, "default_backend", lambda: "cpu")
    monkeypatch.setattr(jax, "local_devices", lambda: devices[:3])
    monkeypatch.setattr(engine, "usable_cores", lambda: 2)  # this machine
    assert engine.cohort_devices(64) == ["d1", "d1"]
    assert engine.cohort_devices(64, python_bound=False) == ["d1", "d2"]
    monkeypatch.setattr(jax, "local_devices", lambda: devices)
    monkeypatch.setattr(engine, "usable_cores", lambda: 4)
    assert engine.cohort_devices(64) == ["d1", "d2", "d3"]
    assert engine.cohort_devices(64, python_bound=False) == ["d1", "d2", "d3", "d4"]
    assert engine.cohort_devices(40, python_bound=False) == ["d1", "d2"]
    assert engine.cohort_devices(16, python_bound=False) == ["d1", "d1"]
    assert engine.cohort_devices(8) == ["d1", "d1"]  # small batches too: the same device
    assert engine.cohort_devices(1) == ["d1"]
    monkeypatch.setattr(jax, "local_devices", lambda: ["d0"])
    assert engine.cohort_devices(64) == [None, None]
    assert engine.cohort_devices(64, cohorts=3) == [None, None, None]


def test_cpu_devices_are_asked_for_by_use_cpu_cores_not_by_importing_the_package():
    """``import strauss_fit`` leaves JAX's device count alone; ``use_cpu_cores()`` asks for
    one CPU device per core and one more, before JAX starts (by the environment) or after
    its import (by ``jax.config``), keeps a count the user chose, and cannot change it once
    JAX ran something."""
    import os
    import subprocess
    import sys

    from strauss_fit.runtime import MAX_COMPUTE_DEVICES, usable_cores

    wanted = min(usable_cores(), MAX_COMPUTE_DEVICES) + 1
    env = {k: v for k, v in os.environ.items() if k not in ("JAX_NUM_CPU_DEVICES", "XLA_FLAGS")}
    env["JAX_PLATFORMS"] = "cpu"
    count = "print(jax.local_device_count())"
    programs = {
        f"import strauss_fit, os, jax; print('JAX_NUM_CPU_DEVICES' in os.environ); {count}": "False\n1",
        f"import strauss_fit as sf; print(sf.use_cpu_cores()); import jax; {count}": f"True\n{wanted}",
        f"import jax, strauss_fit as sf; print(sf.use_cpu_cores()); {count}": f"True\n{wanted}",
        f"import jax, strauss_fit as sf; jax.numpy.ones(1).block_until_ready(); print(sf.use_cpu_cores()); {count}": (
            "False\n1"
        ),
    }
    for code, expected in programs.items():
        done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
        assert done.stdout.strip() == expected, code
    chosen = subprocess.run(
        [sys.executable, "-c", f"import strauss_fit as sf, jax; print(sf.use_cpu_cores()); {count}"],
        env={**env, "JAX_NUM_CPU_DEVICES": "1"},
        capture_output=True,
        text=True,
        check=True,
    )
    assert chosen.stdout.strip() == "False\n1"


def test_fit_many_gives_what_fit_gives_each_target_and_isolates_failures(tmp_path):
    scene = support.key_and_fill_scene(32, source="batch")
    targets = _targets(scene, 5)
    black = sf.Target(np.zeros((32, 32, 3)), np.ones((32, 32), dtype=bool), "black.exr", "linear", 0, 0)
    jobs = [*targets[:3], black, str(tmp_path / "missing.exr"), *targets[3:]]
    options = sf.FitOptions(noise=0.005)
    results = fit_many(jobs, scene, options, chunk_size=4)
    assert len(results) == len(jobs)
    failures = [r for r in results if isinstance(r, FitFailure)]
    assert [f.target for f in failures] == ["black.exr", str(tmp_path / "missing.exr")]
    assert "black" in failures[0].message and "not found" in failures[1].message
    fitted = [r for r in results if not isinstance(r, FitFailure)]
    for batched, target in zip(fitted, targets):
        _same(batched, sf.fit(scene, target, options))


def test_fit_many_takes_per_target_scenes_and_options_and_reports_progress():
    small = support.key_and_fill_scene(24, source="small")
    large = support.key_and_fill_scene(32, source="large")
    targets = _targets(small, 2) + _targets(large, 2, seed=1)
    options = [sf.FitOptions(free=FREE, noise=0.005), sf.FitOptions(noise=0.005)] * 2
    seen = []
    results = fit_many(targets, [small, small, large, large], options, progress=seen.append)
    assert [p.done for p in seen] == [1, 2, 3, 4] and seen[-1].total == 4 and seen[-1].failed == 0
    assert results[0].free == list(FREE)
    for result, target, scene, option in zip(results, targets, [small, small, large, large], options):
        _same(result, sf.fit(scene, target, option))


def test_fit_many_on_a_two_worker_dask_cluster_equals_the_in_process_results():
    pytest.importorskip("dask.distributed")
    from strauss_fit.fitting.executors import DaskExecutor

    scene = support.key_and_fill_scene(24, source="dask")
    targets = _targets(scene, 4, seed=2)
    options = sf.FitOptions(noise=0.005, free=FREE)
    here = fit_many(targets, scene, options, chunk_size=2)
    there = fit_many(
        [FitJob(t, scene, options) for t in targets], scene, options, chunk_size=2, executor=DaskExecutor(workers=2)
    )
    for a, b in zip(here, there):
        assert not isinstance(b, FitFailure), b
        ja, jb = a.to_json(), b.to_json()
        assert ja["free"] == jb["free"] and ja["held"].keys() == jb["held"].keys()
        assert [w["code"] for w in ja["warnings"]] == [w["code"] for w in jb["warnings"]]
        # the same fit in another process: equal up to the last digits (a worker's XLA may
        # sum the pixels in another order), a million times below the reported deviations
        for key in ("color", "smoothness", "metalness"):
            np.testing.assert_allclose(ja[key], jb[key], rtol=1e-6, atol=1e-9)
            np.testing.assert_allclose(ja["uncertainty"][key], jb["uncertainty"][key], rtol=1e-4, atol=1e-12)
        np.testing.assert_allclose(a.fitted_image, b.fitted_image, rtol=1e-5, atol=1e-7)
