"""The dataset index ``index.json`` and reading samples back.

.. code-block:: json

    {
      "format": "strauss-fit synth index",
      "version": 1,
      "spec": "bundled.toml",
      "description": "...",
      "seed": 1990,
      "plan_sha256": "…",
      "total": 32,
      "complete": 32,
      "pending": [],
      "samples": [
        {"id": "strauss-extremes-0000", "group": "strauss-extremes", "model": "strauss",
         "scene": "key_light", "parameters": {"color": [0.8, 0.3, 0.2], "smoothness": 0.0, "...": "..."},
         "files": {"exr": "….exr", "png": "….png", "clip_mask": "….clip.png", "sidecar": "….json"},
         "sha256": {"….exr": "…", "...": "..."}}
      ]
    }

``samples`` lists exactly the complete samples, in dataset order; ``pending`` the ids of
the others. ``plan_sha256`` identifies the dataset (every sample's parameters, scene,
sensor, formats and seed): a run can only be resumed into an index with the same value.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple

from strauss_fit.errors import StraussFitError
from strauss_fit.io.files import read_json, write_json

INDEX_NAME = "index.json"
INDEX_FORMAT = "strauss-fit synth index"
INDEX_VERSION = 1


def build_index(spec: Any, digest: str, order: list[str], entries: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """The index mapping for the complete ``entries`` of a dataset whose ids are ``order``."""
    return {
        "format": INDEX_FORMAT,
        "version": INDEX_VERSION,
        "spec": Path(spec.source).name,
        "description": spec.description,
        "seed": spec.seed,
        "plan_sha256": digest,
        "total": len(order),
        "complete": len(entries),
        "pending": [i for i in order if i not in entries],
        "samples": [entries[i] for i in order if i in entries],
    }


def write_index(output: Path, index: dict[str, Any]) -> None:
    """Replace ``output/index.json`` atomically."""
    write_json(output / INDEX_NAME, index, force=True)


def read_index(folder: str | Path) -> dict[str, Any]:
    """Read and check a dataset folder's index."""
    path = Path(folder) / INDEX_NAME
    index = read_json(path, "dataset index")
    if not isinstance(index, dict) or index.get("format") != INDEX_FORMAT:
        raise StraussFitError(f"{path} is not a strauss-fit synth index")
    if index.get("version") != INDEX_VERSION:
        raise StraussFitError(f"{path}: unsupported index version {index.get('version')!r}")
    return index


#: Models whose samples are rendered outside strauss-fit: their sidecars have synth's shape,
#: but ``parameters`` is not a strauss-fit material (``"mitsuba"``: a Mitsuba 3 BSDF, see
#: `data_synth.mitsuba_backend` and `data_synth.make_bundled_mitsuba`).
EXTERNAL_MODELS = ("mitsuba",)


class Sample(NamedTuple):
    """A sample read back: its sidecar, the scene and material it was rendered with (the
    scene's ``material`` is the sample's for Strauss), and the paths of its files. For a
    registry model (``"lambert"``, ``"cook-torrance"``, …) ``material`` is the checked
    values dict that `render_model` takes. For a Mitsuba sample
    (``sidecar["model"] == "mitsuba"``) ``material`` is None: no Strauss or Phong material
    is the truth (the scene keeps its default material); the BSDF is
    ``sidecar["parameters"]`` and ``files`` holds ``exr``, ``coverage`` and ``mask``."""

    sidecar: dict[str, Any]
    scene: Any
    material: Any
    files: dict[str, Path]


def load_sample(sidecar_path: str | Path, scene_dir: str | Path | None = None) -> Sample:
    """Rebuild a sample from its sidecar. ``scene_dir`` resolves relative paths inside the
    scene definition (an environment image); by default the sidecar's folder.

    Reads the sidecars of `data_synth.generate` (every model of
    `MODELS`) and of the bundled Mitsuba targets (model
    ``mitsuba``: the BSDF is checked with `validate_bsdf`,
    which needs no Mitsuba, and ``material`` is None)."""
    import equinox as eqx

    from strauss_fit.scene.loading import parse_scene

    from .params import MODELS

    sidecar_path = Path(sidecar_path)
    sidecar = read_json(sidecar_path, "sample sidecar")
    if (
        not isinstance(sidecar, dict)
        or sidecar.get("model") not in (*MODELS, *EXTERNAL_MODELS)
        or not isinstance(sidecar.get("parameters"), dict)
        or not isinstance(sidecar.get("scene"), dict)
    ):
        raise StraussFitError(f"{sidecar_path} is not a strauss-fit synth sample sidecar")
    if sidecar["model"] == "mitsuba":
        from .mitsuba_backend import validate_bsdf

        validate_bsdf(sidecar["parameters"], f"{sidecar_path}: parameters")
        material = None
    else:
        material = MODELS[sidecar["model"]].make_material(dict(sidecar["parameters"]))
    base = Path(scene_dir) if scene_dir is not None else sidecar_path.parent
    scene = parse_scene(dict(sidecar["scene"]["definition"]), source=str(sidecar_path), base_dir=base)
    if sidecar["model"] == "strauss":
        scene = eqx.tree_at(lambda s: s.material, scene, material)
    files = {role: sidecar_path.parent / name for role, name in sidecar.get("files", {}).items()}
    return Sample(sidecar, scene, material, files)
