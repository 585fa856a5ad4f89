"""Kernels kept on disk with jax.export (:mod:`strauss_fit.export_cache`): what a later
process loads gives what tracing gives, and whatever goes wrong with the folder only costs
time."""

from __future__ import annotations

import errno
import os
import pickle

import numpy as np
import pytest

import strauss_fit as sf
import support
from strauss_fit import export_cache
from strauss_fit.engine import Kernel


def _probe(a, b, label):
    """A kernel with an array output and a non-array one (rebuilt without tracing)."""
    import jax.numpy as jnp

    out = {"value": jnp.sin(a) * b + 1.0, "sum": jnp.sum(a)}
    if label is not None:  # not batched (lax.map carries arrays only)
        out["label"] = label + "!"
    return out


def _with_callback(a):
    import jax

    jax.debug.callback(lambda x: None, a)  # a host callback: jax.export refuses it
    return a * 2


def _address(a, thing):
    return a * 3


# Test functions pose as library functions: only those are kept on disk (their source is
# in the cache key).
for _fn in (_probe, _with_callback, _address):
    _fn.__module__ = "strauss_fit.export_cache_probe"


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """The export cache on, beside a compilation cache folder in tmp_path; off afterwards."""
    monkeypatch.delenv("STRAUSS_FIT_EXPORT_CACHE", raising=False)
    before = export_cache.folder()
    folder = export_cache.configure(tmp_path / "jax")
    assert folder == tmp_path / "jax-export" and folder.is_dir()
    yield folder
    export_cache._folder = before


def _programs(folder):
    return sorted(p for p in folder.iterdir() if p.suffix == ".pkl")


def _never_export(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("exported again instead of loading the kept program")

    monkeypatch.setattr(export_cache.ExportedKernel, "_export", refuse)


def test_only_module_level_library_functions_are_kept():
    from strauss_fit.fitting.solvers import _solve_starts

    assert export_cache.kernel_identity(_solve_starts) == "strauss_fit.fitting.solvers._solve_starts"
    assert export_cache.kernel_identity(lambda a: a) is None
    assert export_cache.kernel_identity(np.sin) is None

    scale = 2.0

    def closure(a):
        return a * scale

    closure.__module__ = "strauss_fit.somewhere"
    assert export_cache.kernel_identity(closure) is None


def test_a_kept_program_gives_what_tracing_gives_alone_and_batched(cache, monkeypatch, x64):
    args = [(np.full(3, float(i)), np.arange(3.0), None) for i in range(4)]
    export_cache._folder = None
    plain = Kernel(_probe)
    expected_one = plain(args[0][0], args[0][1], "x")
    expected_many = plain.run_many(args)

    export_cache._folder = cache
    kept = Kernel(_probe)
    one = kept(args[0][0], args[0][1], "x")
    many = kept.run_many(args)
    assert len(_programs(cache)) == 2  # one program alone, one batched
    _never_export(monkeypatch)
    reloaded = Kernel(_probe)  # a new process: nothing in memory, everything on disk
    for result in (one, reloaded(args[0][0], args[0][1], "x")):
        np.testing.assert_array_equal(result["value"], expected_one["value"])
        np.testing.assert_array_equal(result["sum"], expected_one["sum"])
        assert result["label"] == "x!"
    for results in (many, reloaded.run_many(args)):
        for result, expected in zip(results, expected_many):
            np.testing.assert_array_equal(result["value"], expected["value"])
            assert "label" not in result
    # another shape is another program
    reloaded_shape = Kernel(_probe)
    monkeypatch.undo()
    np.testing.assert_array_equal(reloaded_shape(np.ones(5), np.ones(5), "y")["value"], np.sin(np.ones(5)) + 1.0)
    assert len(_programs(cache)) == 3


def test_a_fit_through_kept_programs_equals_the_traced_fit(tmp_path, monkeypatch):
    scene = support.key_and_fill_scene(24, source="test")
    image, mask = sf.render(scene, sf.Material(color=(0.6, 0.3, 0.2), smoothness=0.5, metalness=0.3))
    target = sf.Target(np.asarray(image), np.asarray(mask), "t.exr", "linear", 0, 0)
    options = sf.FitOptions(free=("color", "smoothness", "metalness"))
    before = export_cache.folder()
    try:
        export_cache._folder = None
        traced = sf.fit(scene, target, options)
        first = export_cache.configure(tmp_path / "a")
        exported = sf.fit(scene, target, options)
        kept = _programs(first)
        assert kept
        # a later process: the same files in a new folder, nothing in memory for it
        second = export_cache.configure(tmp_path / "b")
        for path in kept:
            (second / path.name).write_bytes(path.read_bytes())
        _never_export(monkeypatch)
        reloaded = sf.fit(scene, target, options)
    finally:
        export_cache._folder = before
    for result in (exported, reloaded):
        assert result.free == traced.free and result.held.keys() == traced.held.keys()
        np.testing.assert_allclose(np.asarray(result.x), np.asarray(traced.x), rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(result.residual["rms"], traced.residual["rms"], rtol=1e-10)


def test_a_kernel_with_a_host_callback_runs_traced_and_is_not_tried_again(cache, monkeypatch, x64):
    np.testing.assert_array_equal(Kernel(_with_callback)(np.arange(3.0)), 2 * np.arange(3.0))
    (path,) = _programs(cache)
    assert pickle.loads(path.read_bytes())["unsupported"]
    _never_export(monkeypatch)
    np.testing.assert_array_equal(Kernel(_with_callback)(np.arange(3.0)), 2 * np.arange(3.0))


def test_static_arguments_without_a_stable_description_are_not_kept(cache, x64):
    class Opaque:  # hashable, but its repr shows an address that changes between processes
        pass

    np.testing.assert_array_equal(Kernel(_address)(np.ones(2), Opaque()), 3 * np.ones(2))
    assert _programs(cache) == []


@pytest.mark.parametrize(
    "damage",
    [b"not a pickle", pickle.dumps({"exported": b"not a program"}), pickle.dumps(["a", "foreign", "pickle"])],
    ids=["not-a-pickle", "not-a-program", "foreign"],
)
def test_a_damaged_file_is_exported_again(cache, damage, x64):
    args = (np.ones(3), np.ones(3), "z")
    Kernel(_probe)(*args)
    (path,) = _programs(cache)
    path.write_bytes(damage)
    result = Kernel(_probe)(*args)
    np.testing.assert_array_equal(result["value"], np.sin(np.ones(3)) + 1.0)
    assert "exported" in pickle.loads(path.read_bytes())


def test_a_kept_program_that_fails_to_run_here_falls_back_to_tracing(cache, monkeypatch, x64):
    args = (np.ones(3), np.ones(3), "v")
    Kernel(_probe)(*args)

    def broken(stored):
        def run(*leaves):
            raise RuntimeError("cannot compile this program here")

        return run, export_cache.jax.tree.structure(stored["out_template"]), stored["rest"]

    monkeypatch.setattr(export_cache, "_loaded", broken)
    kernel = Kernel(_probe)
    for _ in range(2):  # the second call goes straight to tracing
        np.testing.assert_array_equal(kernel(*args)["value"], np.sin(np.ones(3)) + 1.0)


def test_a_full_disk_only_costs_time(cache, monkeypatch, x64):
    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(export_cache.os, "replace", full)
    result = Kernel(_probe)(np.ones(3), np.ones(3), "w")
    np.testing.assert_array_equal(result["value"], np.sin(np.ones(3)) + 1.0)
    assert list(cache.iterdir()) == []  # no program, no temporary file left behind


def test_the_environment_turns_it_off_or_moves_it(tmp_path, monkeypatch):
    before = export_cache.folder()
    try:
        monkeypatch.setenv("STRAUSS_FIT_EXPORT_CACHE", "off")
        assert export_cache.configure(tmp_path / "jax") is None and export_cache.folder() is None
        monkeypatch.setenv("STRAUSS_FIT_EXPORT_CACHE", str(tmp_path / "elsewhere"))
        assert export_cache.configure(tmp_path / "jax") == tmp_path / "elsewhere"
        monkeypatch.delenv("STRAUSS_FIT_EXPORT_CACHE")
        assert export_cache.configure(None) is None  # no compilation cache, no export cache
        assert not os.path.exists(tmp_path / "jax-export")
    finally:
        export_cache._folder = before


def test_a_large_batch_runs_kept_programs_on_its_cpu_devices(cache, x64):
    """From 16 items per device a batch runs on the CPU devices after the first
    (:func:`strauss_fit.engine.cohort_devices`): the kept programs run there too."""
    import jax

    from strauss_fit.engine import cohort_devices, run, run_batched

    kernel = Kernel(_probe)

    def steps(value):
        out = yield kernel.call(np.full(3, value), np.arange(3.0), None)
        out = yield kernel.call(np.asarray(out["value"]) + 1.0, np.ones(3), None)
        return np.asarray(out["value"])

    count = 40
    if jax.local_device_count() >= 2:
        assert all(device is not None and device != jax.devices()[0] for device in cohort_devices(count))
    batched = run_batched([steps(float(i)) for i in range(count)])
    assert _programs(cache)
    export_cache._folder = None
    for i, result in enumerate(batched):
        np.testing.assert_array_equal(result, run(steps(float(i))))


def test_one_kept_program_serves_every_cpu_device(cache, x64):
    import jax

    if jax.local_device_count() < 3:
        pytest.skip("no CPU device besides the default and the kernels' own")
    kernel = Kernel(_probe)
    args = [(np.full(3, float(i)), np.arange(3.0), None) for i in range(4)]
    expected = kernel.run_many(args)  # on the kernels' device (strauss_fit.engine.compute_device)
    with jax.default_device(jax.devices()[2]):
        elsewhere = Kernel(_probe).run_many(args)
    assert len(_programs(cache)) == 1
    for result, wanted in zip(elsewhere, expected):
        np.testing.assert_array_equal(result["value"], wanted["value"])


_SECOND_PROCESS = """
import json, sys
import numpy as np
sys.path.insert(0, sys.argv[1])
import jax
import strauss_fit as sf
import support
from strauss_fit.runtime import enable_compilation_cache

enable_compilation_cache()
misses = []
jax.monitoring.register_event_listener(
    lambda event, **details: misses.append(event) if event == "/jax/compilation_cache/cache_misses" else None
)
scene = support.key_and_fill_scene(24, source="second-process")
data = support.key_and_fill_data(24)
data["light"][0]["direction"] = [0.0, 0.8, 1.0]  # the key light moved: a mismatch, refitted with Huber
targets = []
for index, where in enumerate((scene, sf.parse_scene(data, source="moved"))):
    image, _ = sf.render(where, sf.Material(color=(0.6, 0.4, 0.3), smoothness=0.6, metalness=0.3))
    image = np.asarray(image) + np.random.default_rng(index).normal(0.0, 0.005, np.shape(image))
    targets.append(sf.Target(image, np.ones(image.shape[:2], dtype=bool), f"t{index}.exr", "linear", 0, 0))
order = [int(i) for i in sys.argv[2].split(",")]
results = sf.fit_many([targets[i] for i in order], scene, sf.FitOptions(free=("color", "smoothness", "metalness")))
print(json.dumps({"misses": len(misses), "losses": [r.solver["loss"] for r in results]}))
"""


def test_a_second_process_compiles_nothing_whatever_its_batch_size(tmp_path):
    """Every program of a batch is kept on disk (the XLA program in the compilation cache,
    the traced one here): a later process fitting the same kind of targets compiles nothing
    and exports nothing, in a batch of another size than the first process's."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    env = {**os.environ, "STRAUSS_FIT_CACHE_DIR": str(tmp_path / "jax")}
    env.pop("STRAUSS_FIT_EXPORT_CACHE", None)

    def run(order: str) -> dict:
        command = [sys.executable, "-c", _SECOND_PROCESS, str(Path(__file__).resolve().parent), order]
        done = subprocess.run(command, env=env, capture_output=True, text=True, check=True)
        return json.loads(done.stdout.strip().splitlines()[-1])

    def kept() -> set[str]:
        return {p.name for folder in (tmp_path / "jax", tmp_path / "jax-export") for p in folder.iterdir()}

    first = run("0,1")
    assert first["losses"] == ["linear", "huber"] and first["misses"] > 0
    before = kept()
    second = run("1,0,0,1,0")
    assert second == {"misses": 0, "losses": ["huber", "linear", "linear", "huber", "linear"]}
    assert kept() == before
