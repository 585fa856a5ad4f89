"""Helpers shared by the test modules (on ``sys.path`` through pytest's ``pythonpath``).

The fixtures built on them are in ``conftest.py``.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

import data_synth
import strauss_fit as sf

#: The bundled scene files.
SCENES = Path(data_synth.__file__).resolve().parent / "scenes"
#: The scene most tests and benchmarks share (two directional lights and ambient light).
KEY_AND_FILL = SCENES / "key_and_fill.toml"
#: The fit settings that were ``FitOptions()``'s defaults before they became the
#: ``balanced`` preset, and before partly covered silhouette pixels were left out; tests
#: written against them pass them explicitly, so that their numbers stay what they were.
LEGACY_FIT = dict(starts=4, max_steps=100, rtol=1e-6, atol=1e-8, edge_pixels="include")


#: The material of the small key-and-fill scene of the sampling and report tests.
SMALL_MATERIAL = dict(color=[0.5, 0.5, 0.5], smoothness=0.5, metalness=0.2)


def legacy_options(**fields: Any) -> sf.FitOptions:
    """:class:`~strauss_fit.FitOptions` with :data:`LEGACY_FIT` and ``fields``."""
    return sf.FitOptions(**{**LEGACY_FIT, **fields})


def key_and_fill_data(
    size: int | None = None,
    *,
    material: dict[str, Any] | None = None,
    no_material: bool = False,
    background: dict[str, Any] | None = None,
    depth: int | None = None,
) -> dict[str, Any]:
    """The parsed TOML of ``key_and_fill.toml``: at ``size`` × ``size`` pixels, with its
    ``[material]`` replaced (``material``) or removed (``no_material``), and with a
    ``[background]`` and a ``[render] depth``."""
    data = tomllib.loads(KEY_AND_FILL.read_text())
    if size is not None:
        data["camera"].update(width=size, height=size)
    if no_material:
        del data["material"]
    elif material is not None:
        data["material"] = dict(material)
    if background is not None:
        data["background"] = dict(background)
    if depth is not None:
        data["render"] = {"depth": depth}
    return data


def key_and_fill_scene(size: int | None = None, source: str = "key-and-fill", **changes: Any) -> sf.Scene:
    """:func:`key_and_fill_data` parsed into a :class:`~strauss_fit.Scene`."""
    return sf.parse_scene(key_and_fill_data(size, **changes), source=source)


def key_and_fill_toml(size: int, *, material: dict[str, Any] | None = None) -> str:
    """``key_and_fill.toml`` as text (for the command line), at ``size`` × ``size`` pixels
    and with its ``[material]`` replaced by ``material``."""
    text = KEY_AND_FILL.read_text().replace("width = 40", f"width = {size}").replace("height = 40", f"height = {size}")
    if material is not None:
        head, rest = text.split("[material]\n", 1)
        rest = rest.split("\n\n", 1)[1]
        lines = "".join(f"{k} = {list(v) if isinstance(v, tuple) else v}\n" for k, v in material.items())
        text = f"{head}[material]\n{lines}\n{rest}"
    return text


def noisy_target(
    scene: sf.Scene, material: sf.Material, noise: float = 0.0, seed: int = 0, path: str = "synthetic"
) -> sf.Target:
    """A rendering of ``material`` in ``scene`` plus Gaussian noise, as a fit target (every
    pixel usable) named ``path``."""
    image, mask = sf.render(scene, material)
    pixels = np.asarray(image)
    if noise:
        pixels = pixels + noise * np.random.default_rng(seed).normal(size=pixels.shape)
    return sf.Target(pixels, np.ones(mask.shape, bool), path, "linear", 0, 0)


# --- the extremes of the stability tests (tests/*/test_*_stability.py) -----------------------

DTYPES = (jnp.float32, jnp.float64)
EXTREMES = (0.0, 1e-6, 0.5, 1 - 1e-6, 1.0)
GRAZING = 90.0 - 1e-6
UP = np.array([0.0, 0.0, 1.0])


def direction_at(angle_deg: float, azimuth_deg: float = 0.0) -> np.ndarray:
    """Unit vector at ``angle_deg`` from +z; exactly 90° gives z = 0 exactly (math.cos(π/2)
    is 6e-17, which would count as lit)."""
    a, b = math.radians(angle_deg), math.radians(azimuth_deg)
    z = 0.0 if angle_deg == 90.0 else math.cos(a)
    return np.array([math.sin(a) * math.cos(b), math.sin(a) * math.sin(b), z])


def material_grid() -> np.ndarray:
    """All (s, m, t) combinations of :data:`EXTREMES`, shape (125, 3)."""
    s, m, t = np.meshgrid(EXTREMES, EXTREMES, EXTREMES, indexing="ij")
    return np.stack([s.ravel(), m.ravel(), t.ravel()], axis=-1)


GRID = material_grid()


def assert_all_finite(tree, what: str) -> None:
    for leaf in jax.tree_util.tree_leaves(tree):
        array = np.asarray(leaf)
        assert np.all(np.isfinite(array)), f"{what}: {np.size(array) - np.count_nonzero(np.isfinite(array))} non-finite"


#: Random materials over the whole range (hypothesis).
unit_floats = st.floats(0.0, 1.0, allow_nan=False)
materials = st.fixed_dictionaries(
    {
        "color": st.tuples(unit_floats, unit_floats, unit_floats),
        "smoothness": unit_floats,
        "metalness": unit_floats,
        "transparency": unit_floats,
        "ior": st.floats(1.0, 3.0, allow_nan=False),
    }
)
#: Derandomised, so that CI is reproducible.
PROPERTY = settings(max_examples=60, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])


# --- the synthetic dataset of the data_synth tests (tests/data_synth, tests/cli) -----------------

SYNTH_SPEC = f"""
seed = 7
description = "test dataset"

[[group]]
name = "s"
model = "strauss"
scenes = ["{SCENES / "two_lights.toml"}"]
size = [16, 16]
sampling = "random"
count = 1
formats = ["exr", "png"]

[group.parameters]
color = {{ low = 0.2, high = 0.8 }}
smoothness = {{ low = 0.0, high = 1.0 }}
metalness = {{ low = 0.0, high = 1.0 }}
transparency = 0.0

[group.sensor]
exposure = 2.0
gain = 500.0
read_noise = 0.01

[[group]]
name = "p"
model = "phong"
scenes = ["{SCENES / "two_lights.toml"}", "{SCENES / "point_light.toml"}"]
size = [16, 16]
formats = ["exr"]

[group.parameters]
exponent = [5.0, 50.0]
kd = {{ values = [0.3, [0.2, 0.5, 0.9]] }}
diffuse_color = [0.1, 0.2, 0.30000000000000004]
"""
#: 4 corners of (s, m) + 1 draw, in one scene; 2 x 2 Phong parameter sets in two scenes.
SYNTH_TOTAL = 5 + 8


def write_spec(folder: Path, text: str = SYNTH_SPEC, name: str = "spec.toml") -> Path:
    path = folder / name
    path.write_text(text)
    return path


def files_of(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def compiled_during(action) -> list[str]:
    """The programs JAX compiled while ``action()`` ran (its log of compilations)."""
    import logging

    messages: list[str] = []

    class Collect(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            messages.append(record.getMessage())

    handler = Collect()
    logger = logging.getLogger("jax")
    logger.addHandler(handler)
    jax.config.update("jax_log_compiles", True)
    try:
        action()
    finally:
        jax.config.update("jax_log_compiles", False)
        logger.removeHandler(handler)
    return [m for m in messages if m.startswith("Compiling")]
