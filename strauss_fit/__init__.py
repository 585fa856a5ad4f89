"""strauss-fit: fit the Strauss (1990) lighting model to images.

The data flow, and the subpackage of each step:

scene → geometry → shading → image → fit → uncertainty → report

- `strauss_fit.models`: the Strauss and Phong shading models and materials;
- `strauss_fit.scene`: camera, lights, background, the scene file;
- `strauss_fit.rendering`: rendering the sphere (Strauss with its global model, Phong);
- `strauss_fit.io`: images, fit targets, material tables, safe writes;
- `strauss_fit.stats`: Laplace and sandwich covariances, the target's noise;
- `strauss_fit.fitting`: least-squares recovery of the material;
- `strauss_fit.inference`: the posterior, emcee sampling;
- `strauss_fit.reporting`: the uncertainty report and the study's report;
- `strauss_fit.convert`: Phong ↔ Strauss conversion; `strauss_fit.study`: the
  intuitive-parameter study.

The whole workflow is importable from here:

    import strauss_fit as sf

    scene = sf.load_scene("data_synth/scenes/two_lights.toml")
    target = sf.load_target("data_synth/bundled/strauss-noisy-0000.exr")
    scene, _ = sf.match_scene(scene, target)
    result = sf.fit(scene, target, sf.FitOptions.preset("balanced"))
    print(result.to_json()["smoothness"], result.uncertainty["smoothness"])

Precision: importing the package does not touch ``jax_enable_x64``; the library runs its
own computations in float64 inside a scope (`strauss_fit.precision`, and
`float64` for your code). Nor does it touch JAX's CPU device count:
`use_cpu_cores` asks for one device per core (the command line and the first batch
call it; see `strauss_fit.runtime`). The fitting functions set the C library's allocator to
keep freed memory for their next call (`keep_freed_memory`, once per process; see
`strauss_fit.runtime`).

Every public name is listed once, in `_PUBLIC` (name → module), and imported on first
use, so that ``import strauss_fit`` stays light: no JAX until something needs it (the
command line's ``--help`` and its errors load none). The block under ``TYPE_CHECKING``
states the same re-exports for type checkers and editors (``X as X``, the optimistix
convention); a test keeps the two equal.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from ._version import __version__ as __version__
from .errors import ImageError as ImageError
from .errors import MaterialError as MaterialError
from .errors import OutputExistsError as OutputExistsError
from .errors import SceneError as SceneError
from .errors import StraussFitError as StraussFitError
from .runtime import keep_freed_memory as keep_freed_memory
from .runtime import use_cpu_cores as use_cpu_cores

if TYPE_CHECKING:
    from .convert.converter import phong_to_strauss as phong_to_strauss
    from .convert.converter import strauss_to_phong as strauss_to_phong
    from .fitting.api import fit as fit
    from .fitting.batch import BatchProgress as BatchProgress
    from .fitting.batch import FitFailure as FitFailure
    from .fitting.batch import FitJob as FitJob
    from .fitting.batch import fit_many as fit_many
    from .fitting.executors import DaskExecutor as DaskExecutor
    from .fitting.executors import InProcessExecutor as InProcessExecutor
    from .fitting.options import QUALITY_PRESETS as QUALITY_PRESETS
    from .fitting.options import FitOptions as FitOptions
    from .fitting.result import FitResult as FitResult
    from .inference.sampler import Chain as Chain
    from .inference.sampler import SampleResult as SampleResult
    from .inference.sampler import SampleSettings as SampleSettings
    from .inference.sampler import load_chain as load_chain
    from .inference.sampler import sample as sample
    from .io.images import read_image as read_image
    from .io.images import write_image as write_image
    from .io.targets import Target as Target
    from .io.targets import load_target as load_target
    from .io.targets import match_scene as match_scene
    from .models.material import Material as Material
    from .models.phong import PhongMaterial as PhongMaterial
    from .models.phong import phong_shade as phong_shade
    from .models.strauss import K_F as K_F
    from .models.strauss import K_G as K_G
    from .models.strauss import K_J as K_J
    from .models.strauss import MODES as MODES
    from .models.strauss import fresnel as fresnel
    from .models.strauss import shade as shade
    from .models.strauss import shadow as shadow
    from .precision import float64 as float64
    from .precision import uses_float64 as uses_float64
    from .rendering.phong import render_phong as render_phong
    from .rendering.strauss import RenderPlan as RenderPlan
    from .rendering.strauss import plan_render as plan_render
    from .rendering.strauss import render as render
    from .reporting.fit_report import Report as Report
    from .reporting.fit_report import build_report as build_report
    from .reporting.fit_report import report_from_files as report_from_files
    from .reporting.fit_report import write_report as write_report
    from .scene.background import Background as Background
    from .scene.camera import Camera as Camera
    from .scene.lights import DirectionalLights as DirectionalLights
    from .scene.lights import Lights as Lights
    from .scene.lights import PointLights as PointLights
    from .scene.loading import Scene as Scene
    from .scene.loading import load_scene as load_scene
    from .scene.loading import parse_scene as parse_scene
    from .study.study import run_study as run_study
    from .study.study import study_config as study_config

#: The public names imported on first use, by module (relative to this package), in the
#: order of the flow: precision, models, scenes, rendering, images and targets, fitting,
#: uncertainty, reports, conversion and study.
_PUBLIC: dict[str, tuple[str, ...]] = {
    ".precision": ("float64", "uses_float64"),
    ".models.strauss": ("K_F", "K_G", "K_J", "MODES", "fresnel", "shade", "shadow"),
    ".models.material": ("Material",),
    ".models.phong": ("PhongMaterial", "phong_shade"),
    ".scene.background": ("Background",),
    ".scene.camera": ("Camera",),
    ".scene.lights": ("DirectionalLights", "Lights", "PointLights"),
    ".scene.loading": ("Scene", "load_scene", "parse_scene"),
    ".rendering.strauss": ("RenderPlan", "plan_render", "render"),
    ".rendering.phong": ("render_phong",),
    ".io.targets": ("Target", "load_target", "match_scene"),
    ".io.images": ("read_image", "write_image"),
    ".fitting.options": ("QUALITY_PRESETS", "FitOptions"),
    ".fitting.result": ("FitResult",),
    ".fitting.api": ("fit",),
    ".fitting.batch": ("fit_many", "FitJob", "FitFailure", "BatchProgress"),
    ".fitting.executors": ("DaskExecutor", "InProcessExecutor"),
    ".inference.sampler": ("sample", "SampleSettings", "SampleResult", "Chain", "load_chain"),
    ".reporting.fit_report": ("Report", "build_report", "write_report", "report_from_files"),
    ".convert.converter": ("phong_to_strauss", "strauss_to_phong"),
    ".study.study": ("run_study", "study_config"),
}
_LAZY = {name: module for module, names in _PUBLIC.items() for name in names}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name], __name__), name)
        globals()[name] = value  # later lookups skip this function
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


__all__ = [
    "__version__",
    "ImageError",
    "MaterialError",
    "OutputExistsError",
    "SceneError",
    "StraussFitError",
    "keep_freed_memory",
    "use_cpu_cores",
    *_LAZY,
]
