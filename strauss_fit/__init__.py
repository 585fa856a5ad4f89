"""strauss-fit: fit the Strauss (1990) lighting model to images.

Importing the package enables JAX's float64 support (``jax_enable_x64``): fits run in
float64, and every function takes its precision from its inputs or a ``dtype`` argument,
so float32 stays available.
"""

import jax

jax.config.update("jax_enable_x64", True)

from .background import Background  # noqa: E402
from .camera import Camera  # noqa: E402
from .errors import ImageError, MaterialError, OutputExistsError, SceneError, StraussFitError  # noqa: E402
from .lights import DirectionalLights, Lights, PointLights  # noqa: E402
from .material import Material  # noqa: E402
from .model import K_F, K_G, K_J, MODES, fresnel, shade, shadow  # noqa: E402
from .phong import PhongMaterial, phong_shade, render_phong  # noqa: E402
from .render import RenderPlan, plan_render, render  # noqa: E402
from .scene import Scene, load_scene, parse_scene  # noqa: E402

__version__ = "0.1.0"

__all__ = [
    "Background", "Camera", "DirectionalLights", "ImageError", "K_F", "K_G", "K_J", "Lights",
    "MODES", "Material", "MaterialError", "OutputExistsError", "PhongMaterial", "PointLights", "RenderPlan",
    "Scene", "SceneError", "StraussFitError", "fresnel", "load_scene", "parse_scene",
    "phong_shade", "plan_render", "render", "render_phong", "shade", "shadow",
]
