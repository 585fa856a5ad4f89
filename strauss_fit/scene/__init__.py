"""Scenes: the camera, the lights, the background, and the TOML scene file.

- `camera`: cameras, primary rays, the unit sphere;
- `lights`: ambient, directional and point lights;
- `background`: what rays that miss the sphere see;
- `loading`: `Scene` and the
  strict scene-file reader.

Next in the flow: `strauss_fit.rendering` (shading the sphere into an image).
"""
