"""Rendering the sphere of a scene into an image.

- `strauss`: the Strauss model, local and global (reflection and
  refraction traced, only as deep as it can change the image:
  `effective_depth`), in two stages so that a fit
  prepares the geometry once;
- `phong`: the Phong model (local only).

Next in the flow: `strauss_fit.io` (images and targets) and `strauss_fit.fitting`.
"""
