"""The shading models, independent of scenes and images.

- `material`: the Strauss material (C, s, m, t, n) and its ranges;
- `strauss`: the local Strauss (1990) model — F, G, the angular
  terms and `shade`;
- `phong`: the Phong material and model;
- `albedo`: directional-hemispherical reflectance of both;
- `reflectance`: Strauss, Lambert, Phong, normalised Blinn–Phong and
  Cook–Torrance behind one interface (`ReflectanceModel`),
  with the registry `REFLECTANCE_MODELS`.

Next in the flow: `strauss_fit.scene` (where the sphere is seen from and lit).
"""
