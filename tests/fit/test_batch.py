"""Many targets in one call (issue 16): the engine, :func:`strauss_fit.fit_many`, executors."""

from __future__ import annotations

import numpy as np
import pytest

import strauss_fit as sf
import support
from strauss_fit.engine import Kernel, run, run_batched
from strauss_fit.fit.batch import FitFailure, FitJob, fit_many

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


def test_kernels_give_the_same_values_alone_and_in_a_batch(x64):
    import jax.numpy as jnp

    kernel = Kernel(lambda a, b, scale: jnp.sin(a) * b + scale, "toy")
    args = [(np.full(3, float(i)), np.arange(3.0), 0.5) for i in range(5)]
    batched = kernel.run_many(args)
    for one, (a, b, scale) in zip(batched, args):
        np.testing.assert_array_equal(one, np.asarray(kernel(a, b, scale)))


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
    from strauss_fit.fit.executors import DaskExecutor

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
