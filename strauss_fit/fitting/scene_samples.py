"""One image and its scene as a capture of one image: how any reflectance model is fitted
to a single target.

The Strauss fit of a single target (`strauss_fit.fitting.api`) is built around the Strauss
material (transparency, refraction, a global model). The other reflectance models are opaque
and local, and the capture fitter (`strauss_fit.fitting.capture`) already fits them: one
image is a capture of one image. This module turns a scene and a target into the capture's
pixels: the pixels whose whole footprint shows the sphere (silhouette blends left out),
their normals and view vectors from the scene's camera, every directional and point light as
seen from each point (direction, attenuated intensity × colour), and the scene's ambient
light as a known ambient term. Nothing is cropped or resampled.

The sphere's place is exact here (the scene states it), so the circle carries no
uncertainty.
"""

from __future__ import annotations

import math
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from ..capture._manifest import CaptureImage
from ..capture._samples import CaptureSamples, five_point_laplacian
from ..capture._sphere import Camera as CaptureCamera
from ..capture._sphere import Circle
from ..errors import StraussFitError
from ..io.targets import Target, match_scene
from ..precision import float64
from ..rendering.coverage import fully_covered
from ..scene.camera import intersect_unit_sphere, primary_rays
from ..scene.lights import sample_lights
from ..scene.loading import Scene


def samples_from_scene(scene: Scene, target: Target) -> CaptureSamples:
    """The capture's pixels of ``target`` seen as ``scene`` states it (module docstring)."""
    scene, _ = match_scene(scene, target)
    camera = scene.camera
    height, width = target.pixels.shape[:2]
    with float64():
        rays = primary_rays(camera, jnp.float64)
        hit = intersect_unit_sphere(rays)
        covered = np.asarray(fully_covered(camera)) & np.asarray(hit.hit)
        use = covered & np.asarray(target.usable)
        rows, cols = np.nonzero(use)
        if len(rows) < 10:
            raise StraussFitError(
                f"only {len(rows)} usable pixels of {target.path} show the sphere fully: nothing to fit"
            )
        points = np.asarray(hit.point)[rows, cols]
        views = -np.asarray(rays.direction)[rows, cols]
        seen = sample_lights(scene.lights, jnp.asarray(points))
    if seen is None:
        raise StraussFitError("the scene has no directional or point light: only ambient light, nothing to fit")
    to_light = np.asarray(seen.to_light)
    strength = np.asarray(seen.irradiance)[..., None] * np.asarray(seen.color)  # (K, 3) or (P, K, 3)
    if to_light.ndim == 2:  # directional only: the same for every pixel
        light_dirs = to_light[None, :, None, :]
        light_rgb = strength[None, :, None, :]
    else:
        light_dirs = np.moveaxis(to_light, 0, 1)[None]
        light_rgb = np.moveaxis(strength, 0, 1)[None]
    values = np.asarray(target.pixels, dtype=np.float64)[rows, cols][None]
    if not float(np.max(values)) > 0:  # as the Strauss fit says (a relative RMS would be 0/0)
        raise StraussFitError(f"target {target.path} is black on every usable sphere pixel: nothing to fit")
    usable = np.ones(values.shape, dtype=bool)
    frame = np.asarray(target.pixels, dtype=np.float64)
    laplacian = five_point_laplacian(
        [frame], [np.broadcast_to(use[..., None], frame.shape)], rows, cols, (height, width)
    )
    outside = ~np.asarray(hit.hit) & np.asarray(target.usable)
    background = np.median(frame[outside], axis=0)[None] if outside.any() else np.zeros((1, 3))
    ambient = scene.lights.ambient
    ambient_light = None if ambient is None else np.full((1, 3), float(np.asarray(ambient)))
    circle = Circle(
        center=(float(np.mean(cols)) + 0.5, float(np.mean(rows)) + 0.5),
        radius=max(math.sqrt(float(covered.sum()) / math.pi), 1.0),
        source="given",
    )
    if camera.projection == "perspective":
        focal = (height / 2) / math.tan(math.radians(float(np.asarray(camera.fov_deg))) / 2)
        capture_camera = CaptureCamera("perspective", focal_px=focal)
    else:
        capture_camera = CaptureCamera("orthographic")
    return CaptureSamples(
        files=(str(target.path),),
        shape=(height, width),
        rows=rows,
        cols=cols,
        normals=points,
        views=views,
        values=values,
        usable=usable,
        light_dirs=light_dirs,
        light_rgb=light_rgb,
        saturated=np.zeros(1, dtype=int),
        dark=np.zeros(1, dtype=int),
        background=background,
        background_noise=None,
        quantisation=np.zeros(3),
        laplacian=laplacian,
        circle=circle,
        camera=capture_camera,
        encodings=(str(target.encoding),),
        images=(CaptureImage(Path(target.path), ()),),
        ambient_light=ambient_light,
    )
