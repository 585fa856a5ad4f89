"""Float64 without a global side effect: importing the package leaves JAX's default
precision alone, and the library still computes in float64 (:mod:`strauss_fit.precision`)."""

import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np

import strauss_fit as sf
from support import key_and_fill_scene, noisy_target


def test_importing_strauss_fit_does_not_enable_x64():
    code = (
        "import jax; before = jax.config.jax_enable_x64; import strauss_fit, strauss_fit_cli.main, data_synth; "
        "import strauss_fit.inference.sampler, strauss_fit.reporting.fit_report, strauss_fit.study.study; "
        "print(before, jax.config.jax_enable_x64, jax.numpy.asarray(0.1).dtype)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["False", "False", "float32"]
    assert not jax.config.jax_enable_x64  # nor in this process, outside a scope


def test_a_fit_runs_in_float64_outside_any_scope():
    assert not jax.config.jax_enable_x64
    scene = key_and_fill_scene(16, source="precision")
    assert scene.camera.position.dtype == jnp.float64 and scene.lights.directional.direction.dtype == jnp.float64
    target = noisy_target(scene, sf.Material(color=(0.7, 0.4, 0.2), smoothness=0.6, metalness=0.3))
    assert target.pixels.dtype == np.float64
    result = sf.fit(scene, target, sf.FitOptions(free=("color", "smoothness", "metalness")))
    assert result.problem.target.dtype == jnp.float64 and result.x.dtype == np.float64
    assert result.settings["precision"] == "float64"
    assert float(result.material.smoothness) == np.float64(result.to_json()["smoothness"])
    assert result.residual["rms"] < 1e-6  # a noise-free render is fitted to float64 accuracy
    assert not jax.config.jax_enable_x64


def test_the_scope_is_explicit_and_nests():
    assert jnp.asarray(0.1).dtype == jnp.float32
    with sf.float64():
        assert jnp.asarray(0.1).dtype == jnp.float64
        with sf.float64():
            assert jax.config.jax_enable_x64
        assert jax.config.jax_enable_x64
    assert not jax.config.jax_enable_x64
    image, _ = sf.render(key_and_fill_scene(8))
    assert image.dtype == jnp.float64  # created inside the library's scope, it stays float64
    image32, _ = sf.render(key_and_fill_scene(8), dtype=jnp.float32)
    assert image32.dtype == jnp.float32
