"""Scenes: the camera, the lights, the background, and the TOML scene file.

- :mod:`~strauss_fit.scene.camera`: cameras, primary rays, the unit sphere;
- :mod:`~strauss_fit.scene.lights`: ambient, directional and point lights;
- :mod:`~strauss_fit.scene.background`: what rays that miss the sphere see;
- :mod:`~strauss_fit.scene.loading`: :class:`~strauss_fit.scene.loading.Scene` and the
  strict scene-file reader.

Next in the flow: :mod:`strauss_fit.rendering` (shading the sphere into an image).
"""
