"""The shading models, independent of scenes and images.

- :mod:`~strauss_fit.models.material`: the Strauss material (C, s, m, t, n) and its ranges;
- :mod:`~strauss_fit.models.strauss`: the local Strauss (1990) model — F, G, the angular
  terms and :func:`~strauss_fit.models.strauss.shade`;
- :mod:`~strauss_fit.models.phong`: the Phong material and model;
- :mod:`~strauss_fit.models.albedo`: directional-hemispherical reflectance of both;
- :mod:`~strauss_fit.models.reflectance`: Strauss, Lambert, Phong, normalised Blinn–Phong and
  Cook–Torrance behind one interface (:class:`~strauss_fit.models.reflectance.ReflectanceModel`),
  with the registry :data:`~strauss_fit.models.reflectance.REFLECTANCE_MODELS`.

Next in the flow: :mod:`strauss_fit.scene` (where the sphere is seen from and lit).
"""
