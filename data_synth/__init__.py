"""Synthetic sphere datasets with ground truth, rendered by Strauss or by Phong.

A TOML *dataset spec* (:mod:`data_synth.spec`) names the model, the scenes, a grid or a
seeded random draw over the model's parameters (:mod:`data_synth.params`), a sensor
(:mod:`data_synth.sensor`) and the output formats. :func:`generate` renders every sample
(:mod:`data_synth.plan`), writes an image, a JSON sidecar with the exact parameters, and
keeps ``index.json`` listing the complete samples (:mod:`data_synth.index`), so that a run
can be interrupted and resumed. The command line is ``strauss-fit synth``.

Example::

    from data_synth import generate, load_spec
    report = generate(load_spec("data_synth/specs/bundled.toml"), "out/", force=True)

``data_synth/bundled/`` holds a small dataset generated from ``specs/bundled.toml``;
:data:`BUNDLED` is its folder.
"""

from pathlib import Path

from .generate import GenerationError, Progress, Report, generate, render_clean, render_model
from .index import Sample, load_sample, read_index
from .params import MODELS, SpecError
from .plan import SamplePlan, plan_samples
from .sensor import Sensor, encode_ldr
from .spec import DatasetSpec, load_spec, parse_spec

#: Folder of the bundled dataset (``index.json``, images and sidecars).
BUNDLED = Path(__file__).with_name("bundled")
#: Folder of the example dataset specs.
SPECS = Path(__file__).with_name("specs")
#: Folder of the bundled scene files.
SCENES = Path(__file__).with_name("scenes")

__all__ = [
    "BUNDLED",
    "DatasetSpec",
    "GenerationError",
    "MODELS",
    "Progress",
    "Report",
    "SCENES",
    "SPECS",
    "Sample",
    "SamplePlan",
    "Sensor",
    "SpecError",
    "encode_ldr",
    "generate",
    "load_sample",
    "load_spec",
    "parse_spec",
    "plan_samples",
    "read_index",
    "render_clean",
    "render_model",
]
