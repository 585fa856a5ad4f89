r"""A capture's pixels: every image decoded, the sphere located once, its pixels' normals.

The fit of a capture works on one set of sphere pixels shared by all images (the camera does
not move): per pixel p a normal `n_p` and a view vector `v_p`
(`strauss_fit.capture._sphere`), per image l and pixel p the observed linear radiance
`I_{lp}` (RGB) and which of its channels are usable, and per image its lights. Nothing
is cropped or resampled: the pixels are read where they lie in the frame.

Decoding of a stored value x (a fraction of full scale, as the file holds it):

- saturated where x ≥ ``saturation`` (per channel; by default within
  `SATURATION_MARGIN` of the largest code of an integer file), under-exposed where
  the decoded value is below ``dark`` (by default: code 0 of an integer file, which clips
  the noise at black); both are left out of the fit. Why judged by the neighbours: a
  value near a clip is censored by its own noise (those pushed over are lost, the rest
  kept), so leaving a pixel out for its *own* value biases the ones kept. The neighbours'
  noise is independent of its own, so a rule on them keeps what is kept unbiased. A sphere
  pixel is saturated when it is itself at the largest code (its value is unknown) or most
  of its eight neighbours on the sphere lie in the saturated band (most, not any one: at a
  highlight's steep edge one neighbour in the band says little about this pixel);
  under-exposed when any neighbour is at code 0 (how far from black clipping starts grows
  with the noise, and so does the ring this leaves out). A pixel without sphere neighbours
  is judged by its own value;
- decoded: linear files as stored, sRGB files through the sRGB transfer curve, then the
  black level subtracted and the result divided by the image's known exposure.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..color import srgb_decode
from ..errors import CaptureError
from ..io.images import read_image
from ._manifest import Capture, CaptureImage
from ._sphere import Camera, Circle, circle_from_images, circle_from_mask, sphere_geometry

#: Pixels this close to the silhouette (in pixels) are left out: they blend sphere and
#: background, which the model of one surface point does not describe.
RIM_MARGIN_PX = 1.0
#: Below the largest code of an integer file, the band (fraction of full scale) left out
#: with the saturated values by default.
SATURATION_MARGIN = 0.02
#: Background pixels (evenly spread) its level and noise are measured on.
BACKGROUND_PIXELS = 20_000


@dataclass(frozen=True)
class CaptureSamples:
    """The pixels of a capture, ready to fit. L images, P sphere pixels, K lights per image
    (images with fewer lights are padded with lights of intensity 0).

    ``light_dirs`` and ``light_rgb`` have shape (L, K, Q, 3) with Q = 1 for directional
    lights (the same for every pixel) or Q = P when a point light's direction and falloff
    vary over the sphere."""

    files: tuple[str, ...]
    shape: tuple[int, int]
    rows: np.ndarray
    cols: np.ndarray
    normals: np.ndarray
    views: np.ndarray
    values: np.ndarray
    usable: np.ndarray
    light_dirs: np.ndarray
    light_rgb: np.ndarray
    #: Per image: channels left out as saturated, and as under-exposed.
    saturated: np.ndarray
    dark: np.ndarray
    #: Per image and channel: the median of the frame away from the sphere (after decoding).
    background: np.ndarray
    #: Per channel: the noise of the background, from the differences between images of
    #: the same background pixels (a floor for the noise on the sphere: read noise, no shot
    #: noise); None when the frame has no background.
    background_noise: np.ndarray | None
    #: Per channel: the noise level of one stored step (quantisation), linear units at mid grey.
    quantisation: np.ndarray
    #: (L, P, 3): the five-point Laplacian 4 I(p) − Σ I(neighbours) of each image at each
    #: pixel whose four neighbours are sphere pixels and usable; NaN elsewhere. Noise of
    #: level σ gives it a spread of √20 σ; the image's own curvature only adds to it, so it
    #: bounds the noise from above (`strauss_fit.fitting.capture_result.noise_bound`).
    laplacian: np.ndarray
    circle: Circle
    camera: Camera
    encodings: tuple[str, ...]
    #: How each image's lights were given (per image, the CaptureImage).
    images: tuple[CaptureImage, ...]
    #: Per image and channel, a known ambient light reaching every point (a scene's ambient
    #: light, `strauss_fit.fitting.scene_samples`); None when the images state none.
    ambient_light: np.ndarray | None = None

    @property
    def count(self) -> int:
        return len(self.files)

    def select(self, indices: Sequence[int]) -> CaptureSamples:
        """The same pixels, only the images at ``indices`` (0-based)."""
        idx = np.asarray(list(indices), dtype=int)
        return replace(
            self,
            files=tuple(self.files[i] for i in idx),
            values=self.values[idx],
            usable=self.usable[idx],
            laplacian=self.laplacian[idx],
            light_dirs=self.light_dirs[idx],
            light_rgb=self.light_rgb[idx],
            saturated=self.saturated[idx],
            dark=self.dark[idx],
            background=self.background[idx],
            encodings=tuple(self.encodings[i] for i in idx),
            images=tuple(self.images[i] for i in idx),
            ambient_light=None if self.ambient_light is None else self.ambient_light[idx],
        )

    def pixels(self, index: np.ndarray) -> CaptureSamples:
        """The same images at the sphere pixels ``index`` only (a subsample)."""
        index = np.asarray(index, dtype=int)

        def per_pixel(a: np.ndarray) -> np.ndarray:
            return a if a.shape[2] == 1 else a[:, :, index]

        return replace(
            self,
            rows=self.rows[index],
            cols=self.cols[index],
            normals=self.normals[index],
            views=self.views[index],
            values=self.values[:, index],
            usable=self.usable[:, index],
            laplacian=self.laplacian[:, index],
            light_dirs=per_pixel(self.light_dirs),
            light_rgb=per_pixel(self.light_rgb),
        )

    def image(self, values: np.ndarray, fill: float = 0.0) -> np.ndarray:
        """Per-pixel values (..., P, 3) placed back into frames (..., H, W, 3)."""
        values = np.asarray(values)
        out = np.full(values.shape[:-2] + self.shape + (3,), fill, dtype=np.float64)
        out[..., self.rows, self.cols, :] = values
        return out


def _decoded(pixels: np.ndarray, encoding: str, black: float, exposure: float) -> np.ndarray:
    linear = srgb_decode(pixels) if encoding == "srgb" else pixels
    return (linear - black) / exposure


def _light_arrays(images: Sequence[CaptureImage], normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(L, K, Q, 3) directions toward the lights and RGB intensities at each pixel."""
    count = max(len(image.lights) for image in images)
    varies = any(light.position is not None for image in images for light in image.lights)
    q = len(normals) if varies else 1
    dirs = np.zeros((len(images), count, q, 3))
    rgb = np.zeros((len(images), count, q, 3))
    dirs[..., 2] = 1.0  # the padding lights: any unit vector, intensity 0
    for i, image in enumerate(images):
        for k, light in enumerate(image.lights):
            intensity = np.asarray(light.intensity, dtype=np.float64)
            if light.direction is not None:
                dirs[i, k] = np.asarray(light.direction)
                rgb[i, k] = intensity
            else:
                # a point light in sphere radii from the centre; the surface point of a unit
                # sphere is its normal. The intensity is the irradiance at the centre.
                offset = np.asarray(light.position)[None, :] - normals
                distance = np.linalg.norm(offset, axis=-1, keepdims=True)
                dirs[i, k] = offset / distance
                rgb[i, k] = intensity * (np.linalg.norm(light.position) / distance) ** 2
    return dirs, rgb


def _camera(capture: Capture) -> Camera:
    spec = capture.camera
    return Camera(kind=spec.kind, focal_px=spec.focal_px, principal_point=spec.principal_point)


def _read_mask(path: Path, shape: tuple[int, int]) -> np.ndarray:
    mask = read_image(path, encoding="linear")
    if mask.pixels.shape[:2] != shape:
        raise CaptureError(
            f"the mask {path} is {mask.pixels.shape[1]}×{mask.pixels.shape[0]}, the images {shape[1]}×{shape[0]}"
        )
    # an anti-aliased mask's grey rim counts where it is at least half on (as circle_from_mask)
    level = mask.pixels.max(axis=-1)
    return level >= 0.5 * max(float(level.max()), 1e-300)


def _background_noise(frames: list[np.ndarray], outside: np.ndarray) -> np.ndarray | None:
    """Per channel: the noise of the background pixels, from the differences of consecutive
    images (a static background differs only by noise; the MAD makes stray highlights and
    reflections of single images count little)."""
    if len(frames) < 2 or outside.sum() < 100:
        return None
    diffs = np.concatenate([(frames[i + 1][outside] - frames[i][outside]) for i in range(min(len(frames) - 1, 16))])
    mad = np.median(np.abs(diffs - np.median(diffs, axis=0)), axis=0)
    return 1.4826 * mad / np.sqrt(2.0)


def load_samples(
    capture: Capture,
    *,
    margin: float = RIM_MARGIN_PX,
    progress: Callable[[int, int], Any] | None = None,
) -> CaptureSamples:
    """Read every image of ``capture``, locate the sphere (the manifest's circle, else from
    the mask, else from the images) and gather the sphere's pixels."""
    frames: list[np.ndarray] = []
    saturated_maps: list[np.ndarray] = []
    encodings: list[str] = []
    bits_seen: list[int | None] = []
    shape: tuple[int, int] | None = None
    for i, image in enumerate(capture.images):
        loaded = read_image(image.path, encoding="linear")
        if shape is None:
            shape = loaded.pixels.shape[:2]
        elif loaded.pixels.shape[:2] != shape:
            raise CaptureError(
                f"{image.path} is {loaded.pixels.shape[1]}×{loaded.pixels.shape[0]}; the capture's first image is "
                f"{shape[1]}×{shape[0]}: all images of a capture come from one camera"
            )
        stored = loaded.pixels
        if not np.isfinite(stored).all():
            raise CaptureError(f"{image.path} holds values that are not finite numbers")
        encoding = capture.encoding or ("srgb" if loaded.bits == 8 else "linear")
        if capture.saturation is not None:
            saturated = stored >= capture.saturation
        elif loaded.bits is not None:
            # a value near the clip is censored by its own noise (those pushed over are
            # lost, the rest kept): the band below the largest code goes too
            saturated = stored >= 1.0 - SATURATION_MARGIN
        else:
            saturated = np.zeros(stored.shape, dtype=bool)
        decoded = _decoded(stored, encoding, capture.black_level, image.exposure)
        if capture.dark is not None:
            dark = decoded < capture.dark
        elif loaded.bits is not None:
            dark = stored <= 0.0
        else:
            dark = np.zeros(stored.shape, dtype=bool)
        frames.append(decoded)
        at_clip = stored >= 1.0 if capture.saturation is None and loaded.bits is not None else saturated
        saturated_maps.append(np.stack([saturated, dark, at_clip]))
        encodings.append(encoding)
        bits_seen.append(loaded.bits)
        if progress is not None:
            progress(i + 1, len(capture.images))
    assert shape is not None
    camera = _camera(capture)
    mask = _read_mask(capture.mask, shape) if capture.mask is not None else None
    if capture.circle is not None:
        circle = Circle.given(capture.circle["center"], capture.circle["radius"], camera, shape)
    elif mask is not None:
        circle = circle_from_mask(mask, camera)
    else:
        circle = circle_from_images(frames, camera)
    geometry = sphere_geometry(circle, shape, camera, margin=margin)
    rows, cols = geometry.rows, geometry.cols
    if mask is not None:
        keep = mask[rows, cols]
        rows, cols = rows[keep], cols[keep]
        normals, views = geometry.normals[keep], geometry.views[keep]
    else:
        normals, views = geometry.normals, geometry.views
    if len(rows) < 10:
        raise CaptureError(f"the sphere ({circle.describe()}) covers only {len(rows)} usable pixels")
    values = np.stack([frame[rows, cols] for frame in frames])
    flags = np.stack([_censored(m, rows, cols) for m in saturated_maps])  # (L, 2, P, 3)
    usable = ~(flags[:, 0] | flags[:, 1])
    dirs, rgb = _light_arrays(capture.images, normals)
    laplacian = five_point_laplacian(frames, [~(m[0] | m[1]) for m in saturated_maps], rows, cols, shape)
    del saturated_maps
    outside = _outside(shape, circle, camera, mask)
    # the background's statistics from an even spread of at most BACKGROUND_PIXELS of its pixels
    # (a median over the whole frame of every image would cost more than the fit)
    spots = np.flatnonzero(outside)
    spots = spots[:: max(1, len(spots) // BACKGROUND_PIXELS)]
    picked = np.zeros(shape, dtype=bool)
    picked.flat[spots] = True
    outside = picked
    background = np.stack([np.median(frame[outside], axis=0) if outside.any() else np.zeros(3) for frame in frames])
    step = np.array([_quantisation(bits, enc) for bits, enc in zip(bits_seen, encodings)]).max()
    return CaptureSamples(
        files=tuple(str(image.path) for image in capture.images),
        shape=shape,
        rows=rows,
        cols=cols,
        normals=normals,
        views=views,
        values=values,
        usable=usable,
        light_dirs=dirs,
        light_rgb=rgb,
        saturated=flags[:, 0].any(axis=-1).sum(axis=-1),
        dark=flags[:, 1].any(axis=-1).sum(axis=-1),
        background=background,
        background_noise=_background_noise(frames, outside),
        quantisation=np.full(3, step),
        laplacian=laplacian,
        circle=circle,
        camera=camera,
        encodings=tuple(encodings),
        images=tuple(capture.images),
    )


def _censored(maps: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Per sphere pixel and channel (2, P, 3): saturated, under-exposed, judged by the
    neighbours (module docstring). ``maps`` (3, H, W, 3): in the saturated band, in the dark
    band, at the largest code."""
    height, width = maps.shape[1:3]
    on_sphere = np.zeros((height, width), dtype=bool)
    on_sphere[rows, cols] = True
    band = np.zeros((2, len(rows), 3), dtype=bool)
    in_band = np.zeros((len(rows), 3))
    neighbours = np.zeros(len(rows), dtype=int)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if dr == 0 and dc == 0:
                continue
            r, c = rows + dr, cols + dc
            inside = (r >= 0) & (r < height) & (c >= 0) & (c < width)
            r, c = np.where(inside, r, 0), np.where(inside, c, 0)
            counts = inside & on_sphere[r, c]
            neighbours += counts
            in_band += maps[0, r, c] & counts[:, None]
            band[1] |= maps[1, r, c] & counts[:, None]
    alone = neighbours == 0
    band[0] = in_band > 0.5 * np.maximum(neighbours, 1)[:, None]
    own = maps[:2, rows, cols]
    band |= own & alone[None, :, None]
    band[0] |= maps[2, rows, cols]
    return band


def five_point_laplacian(
    frames: list[np.ndarray], usable_maps: list[np.ndarray], rows: np.ndarray, cols: np.ndarray, shape: tuple[int, int]
) -> np.ndarray:
    """Per image, the five-point Laplacian at the sphere pixels whose four neighbours are
    sphere pixels too (NaN where a neighbour is missing or not usable)."""
    on_sphere = np.zeros(shape, dtype=bool)
    on_sphere[rows, cols] = True
    height, width = shape
    inner = (rows > 0) & (rows < height - 1) & (cols > 0) & (cols < width - 1)
    r, c = np.where(inner, rows, 1), np.where(inner, cols, 1)
    neighbours = [(r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1)]
    complete = inner & np.all([on_sphere[nr, nc] for nr, nc in neighbours], axis=0)
    out = np.full((len(frames), len(rows), 3), np.nan)
    for i, (frame, usable) in enumerate(zip(frames, usable_maps)):
        ok = usable[r, c] & complete[:, None]
        value = 4 * frame[r, c]
        for nr, nc in neighbours:
            ok &= usable[nr, nc]
            value = value - frame[nr, nc]
        out[i] = np.where(ok, value, np.nan)
    return out


def _quantisation(bits: int | None, encoding: str) -> float:
    """The standard deviation of rounding to one stored step, in linear units at mid grey
    (sRGB steps are stretched by the curve's slope there, about 0.5)."""
    if bits is None:
        return 0.0
    step = 1.0 / (2**bits - 1)
    slope = float(srgb_decode(np.array([0.5 + step / 2]))[0] - srgb_decode(np.array([0.5 - step / 2]))[0]) / step
    return step / np.sqrt(12.0) * (slope if encoding == "srgb" else 1.0)


def _outside(shape: tuple[int, int], circle: Circle, camera: Camera, mask: np.ndarray | None) -> np.ndarray:
    """Background pixels: well away from the sphere (a margin of a tenth of its radius,
    at least 3 px) and outside the mask."""
    grow = max(3.0, 0.1 * circle.radius)
    inside = np.zeros(shape, dtype=bool)
    grown = sphere_geometry(circle.grown(grow), shape, camera, margin=0.0, clip=True)
    inside[grown.rows, grown.cols] = True
    if mask is not None:
        inside |= mask
    return ~inside
