"""Shared fixtures: the float64 scope for tests of internal functions, and the scenes.

Scenes: ``data_synth/scenes/key_and_fill.toml`` (two directional lights and ambient light)
is the scene most tests share; :mod:`support` builds its variants (size, material,
background, depth).
"""

from __future__ import annotations

import pytest

import strauss_fit as sf
import support

# the command line's device setup (strauss_fit.runtime.use_cpu_cores), before any JAX work:
# the tests run the kernels where the command runs them
sf.use_cpu_cores()


@pytest.fixture
def x64():
    """JAX float64 for a test, or for every test of a module
    (``pytestmark = pytest.mark.usefixtures("x64")``): the library's entry points switch it
    on themselves
    (:mod:`strauss_fit.precision`), tests that call internal functions or compute with JAX
    directly need it too."""
    with sf.float64():
        yield


@pytest.fixture(scope="session")
def scenes_dir():
    """The folder of the bundled scene files, ``data_synth/scenes``."""
    return support.SCENES


@pytest.fixture(scope="session")
def key_and_fill():
    """``key_and_fill.toml`` (40 × 40 pixels, a grey plastic material) as a scene."""
    return support.key_and_fill_scene()


@pytest.fixture(scope="session")
def mirror_room():
    """``key_and_fill.toml`` over a uniform grey backdrop (a mirror shows it)."""
    return support.key_and_fill_scene(background={"color": [0.6, 0.6, 0.6]}, source="mirror")


@pytest.fixture(scope="session")
def small_key_and_fill():
    """``key_and_fill.toml`` at 24 × 24 pixels with metalness 0.2 (the sampling tests')."""
    return support.key_and_fill_scene(24, material=support.SMALL_MATERIAL, source="test")


@pytest.fixture(scope="session")
def reference(tmp_path_factory):
    """An uninterrupted run of ``support.SYNTH_SPEC``: (spec path, output folder)."""
    from data_synth import generate, load_spec

    root = tmp_path_factory.mktemp("reference")
    spec = support.write_spec(root)
    out = root / "out"
    report = generate(load_spec(spec), out)
    assert report.finished and report.written == support.SYNTH_TOTAL
    return spec, out
