"""What the benchmarks share (a library, not a benchmark): the fit settings they were
calibrated with, and the scene file most of them use.

``LEGACY_FIT`` holds the settings that were ``FitOptions()``'s defaults until they became
the ``balanced`` preset (4 starts, 100 polish steps, rtol 1e-6, atol 1e-8); the benchmarks
pass them explicitly, so that their numbers stay comparable with the tables in docs/benchmarks.md.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import strauss_fit as sf

ROOT = Path(__file__).resolve().parents[1]
#: Two directional lights (a key and a fill) and ambient light over black.
KEY_AND_FILL = ROOT / "data_synth" / "scenes" / "key_and_fill.toml"
#: ``FitOptions()``'s defaults before they became the balanced preset.
LEGACY_FIT = dict(starts=4, max_steps=100, rtol=1e-6, atol=1e-8)


def legacy_options(**fields: Any) -> sf.FitOptions:
    """:class:`strauss_fit.FitOptions` with :data:`LEGACY_FIT` and ``fields``."""
    return sf.FitOptions(**{**LEGACY_FIT, **fields})


def key_and_fill_scene(
    size: int,
    *,
    material: dict[str, Any] | None = None,
    background: dict[str, Any] | None = None,
    depth: int | None = None,
    source: str = "benchmark",
) -> sf.Scene:
    """``key_and_fill.toml`` at ``size`` × ``size`` pixels, with its ``[material]``
    replaced and a ``[background]`` and ``[render] depth`` added when given."""
    data = tomllib.loads(KEY_AND_FILL.read_text())
    data["camera"].update(width=size, height=size)
    if material is not None:
        data["material"] = dict(material)
    if background is not None:
        data["background"] = dict(background)
    if depth is not None:
        data["render"] = {"depth": depth}
    return sf.parse_scene(data, source=source)
