"""strauss-fit: fit the Strauss (1990) lighting model to images.

The data flow, and the subpackage of each step:

scene → geometry → shading → image → fit → uncertainty → report

- :mod:`strauss_fit.models`: the Strauss and Phong shading models and materials;
- :mod:`strauss_fit.scene`: camera, lights, background, the scene file;
- :mod:`strauss_fit.render`: rendering the sphere (Strauss with its global model, Phong);
- :mod:`strauss_fit.io`: images, fit targets, material tables, safe writes;
- :mod:`strauss_fit.stats`: Laplace and sandwich covariances, the target's noise;
- :mod:`strauss_fit.fit`: least-squares recovery of the material;
- :mod:`strauss_fit.inference`: the posterior, emcee sampling;
- :mod:`strauss_fit.reporting`: the uncertainty report and the study's report;
- :mod:`strauss_fit.convert`: Phong ↔ Strauss conversion; :mod:`strauss_fit.study`: the
  intuitive-parameter study.

The whole workflow is importable from here::

    import strauss_fit as sf

    scene = sf.load_scene("data_synth/scenes/two_lights.toml")
    target = sf.load_target("data_synth/bundled/strauss-noisy-0000.exr")
    scene, _ = sf.match_scene(scene, target)
    result = sf.fit(scene, target, sf.FitOptions.preset("balanced"))
    print(result.to_json()["smoothness"], result.uncertainty["smoothness"])

Precision: importing the package does not touch ``jax_enable_x64``; the library runs its
own computations in float64 inside a scope (:mod:`strauss_fit.precision`, and
:func:`float64` for your code).

``strauss_fit.fit`` and ``strauss_fit.render`` are the functions; their subpackages are
imported as ``from strauss_fit.fit import options`` (or ``from strauss_fit.fit.options
import FitOptions``). Every public name is imported on first use, so that
``import strauss_fit`` stays light (no JAX until something needs it).
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import TYPE_CHECKING, Any

from ._version import __version__ as __version__
from .errors import ImageError, MaterialError, OutputExistsError, SceneError, StraussFitError
from .runtime import use_cpu_cores as use_cpu_cores

if TYPE_CHECKING:
    from .convert.converter import phong_to_strauss, strauss_to_phong
    from .fit.api import fit
    from .fit.batch import BatchProgress, FitFailure, FitJob, fit_many
    from .fit.executors import DaskExecutor, InProcessExecutor
    from .fit.options import QUALITY_PRESETS, FitOptions
    from .fit.result import FitResult
    from .inference.sampler import Chain, SampleResult, SampleSettings, load_chain, sample
    from .io.images import read_image, write_image
    from .io.targets import Target, load_target, match_scene
    from .models.material import Material
    from .models.phong import PhongMaterial, phong_shade
    from .models.strauss import K_F, K_G, K_J, MODES, fresnel, shade, shadow
    from .precision import float64, uses_float64
    from .render.phong import render_phong
    from .render.strauss import RenderPlan, plan_render, render
    from .reporting.fit_report import Report, build_report, report_from_files, write_report
    from .scene.background import Background
    from .scene.camera import Camera
    from .scene.lights import DirectionalLights, Lights, PointLights
    from .scene.loading import Scene, load_scene, parse_scene
    from .study.study import run_study, study_config

#: Every public name and the module it comes from (relative to this package), imported on
#: first use: ``import strauss_fit`` (and ``strauss-fit --help``) loads no JAX.
_LAZY = {
    **dict.fromkeys(("float64", "uses_float64"), ".precision"),
    **dict.fromkeys(("K_F", "K_G", "K_J", "MODES", "fresnel", "shade", "shadow"), ".models.strauss"),
    "Material": ".models.material",
    **dict.fromkeys(("PhongMaterial", "phong_shade"), ".models.phong"),
    "Background": ".scene.background",
    "Camera": ".scene.camera",
    **dict.fromkeys(("DirectionalLights", "Lights", "PointLights"), ".scene.lights"),
    **dict.fromkeys(("Scene", "load_scene", "parse_scene"), ".scene.loading"),
    **dict.fromkeys(("RenderPlan", "plan_render", "render"), ".render.strauss"),
    "render_phong": ".render.phong",
    **dict.fromkeys(("Target", "load_target", "match_scene"), ".io.targets"),
    **dict.fromkeys(("read_image", "write_image"), ".io.images"),
    **dict.fromkeys(("QUALITY_PRESETS", "FitOptions"), ".fit.options"),
    "FitResult": ".fit.result",
    "fit": ".fit.api",
    **dict.fromkeys(("fit_many", "FitJob", "FitFailure", "BatchProgress"), ".fit.batch"),
    **dict.fromkeys(("DaskExecutor", "InProcessExecutor"), ".fit.executors"),
    **dict.fromkeys(("sample", "SampleSettings", "SampleResult", "Chain", "load_chain"), ".inference.sampler"),
    **dict.fromkeys(("Report", "build_report", "write_report", "report_from_files"), ".reporting.fit_report"),
    **dict.fromkeys(("phong_to_strauss", "strauss_to_phong"), ".convert.converter"),
    **dict.fromkeys(("run_study", "study_config"), ".study.study"),
}
#: Public names that are also subpackages: the attribute stays the function.
_FUNCTIONS_NAMED_LIKE_SUBPACKAGES = ("fit", "render")


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name], __name__), name)
        object.__setattr__(sys.modules[__name__], name, value)
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


class _Package(types.ModuleType):
    """The package's module type: importing the subpackage ``strauss_fit.fit`` (or
    ``.render``) must not replace the function ``strauss_fit.fit`` (``render``) of the same
    name, which Python's import system would otherwise do when it binds a loaded
    subpackage to its parent."""

    def __setattr__(self, name: str, value: Any) -> None:
        if name in _FUNCTIONS_NAMED_LIKE_SUBPACKAGES and isinstance(value, types.ModuleType):
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package

__all__ = [
    # errors and precision
    "ImageError",
    "MaterialError",
    "OutputExistsError",
    "SceneError",
    "StraussFitError",
    "float64",
    "uses_float64",
    "__version__",
    # models
    "K_F",
    "K_G",
    "K_J",
    "MODES",
    "Material",
    "PhongMaterial",
    "fresnel",
    "phong_shade",
    "shade",
    "shadow",
    # scenes
    "Background",
    "Camera",
    "DirectionalLights",
    "Lights",
    "PointLights",
    "Scene",
    "load_scene",
    "parse_scene",
    # rendering
    "RenderPlan",
    "plan_render",
    "render",
    "render_phong",
    # images and targets
    "Target",
    "load_target",
    "match_scene",
    "read_image",
    "write_image",
    # fitting
    "QUALITY_PRESETS",
    "FitOptions",
    "FitResult",
    "fit_many",
    "FitJob",
    "FitFailure",
    "BatchProgress",
    "DaskExecutor",
    "InProcessExecutor",
    "fit",
    # uncertainty
    "Chain",
    "SampleResult",
    "SampleSettings",
    "load_chain",
    "sample",
    # reports
    "Report",
    "build_report",
    "report_from_files",
    "write_report",
    # conversion and study
    "phong_to_strauss",
    "strauss_to_phong",
    "run_study",
    "study_config",
]
