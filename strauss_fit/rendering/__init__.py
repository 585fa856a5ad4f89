"""Rendering the sphere of a scene into an image.

- :mod:`~strauss_fit.rendering.strauss`: the Strauss model, local and global (reflection and
  refraction traced, only as deep as it can change the image:
  :func:`~strauss_fit.rendering.strauss.effective_depth`), in two stages so that a fit
  prepares the geometry once;
- :mod:`~strauss_fit.rendering.phong`: the Phong model (local only).

Next in the flow: :mod:`strauss_fit.io` (images and targets) and :mod:`strauss_fit.fitting`.
"""
