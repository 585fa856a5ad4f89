"""Reflectance models behind one interface, and their registry.

Every model is a final subclass of `ReflectanceModel` (an abstract equinox module
without fields) with class-level `name`,
`parameters` (`Parameter`),
`bounded_scale` and `nonlinear`; the
registry `REFLECTANCE_MODELS` maps names to instances:

- ``"strauss"``: Strauss (1990), the project's model (`strauss_fit.models.strauss`);
- ``"lambert"``: a perfectly diffuse surface;
- ``"phong"``: Phong, unnormalised (the capture fitter's);
- ``"blinn-phong"``: Blinn–Phong, energy-normalised;
- ``"cook-torrance"``: Cook–Torrance with GGX, Smith shadowing and Schlick's Fresnel.

Formulas, ranges and what each parameter needs from a scene: docs/reflectance-models.md.
"""

from ._base import Parameter, ReflectanceModel
from ._registry import REFLECTANCE_MODELS, reflectance_model

__all__ = ["REFLECTANCE_MODELS", "Parameter", "ReflectanceModel", "reflectance_model"]
