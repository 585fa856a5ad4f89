"""A plain NumPy float64 implementation of strauss-fit's local Strauss model.

This is the honest baseline the benchmarks compare strauss-fit against: the formulas of
docs/model.md (and of :mod:`strauss_fit.models.strauss`) written as ordinary,
vectorised-over-pixels NumPy code, with no JIT and no tricks. It renders the canonical
orthographic view of the unit sphere exactly as :func:`strauss_fit.rendering.strauss.render` does for
a scene whose background is black (a constant colour is also accepted; see below):

- pixel (row i, column k) is at x = (k + 0.5)/width·2 − 1, y = 1 − (i + 0.5)/height·2 and
  shows the sphere where x² + y² < 1 (docs/formats.md); there N = (x, y, √(1−x²−y²))
  and V = (0, 0, 1);
- per light: :math:`Q_d C_L + Q_s` times its intensity (a point light's divided by
  :math:`c_0 + c_1 d + c_2 d^2`), nothing where N·L ≤ 0 or N·V ≤ 0;
- plus ambient :math:`I_a r_d C`; pixels off the sphere show the background colour.

With a black background strauss-fit's global model adds nothing (every traced ray ends
on black), so this equals ``render(scene)`` at any ``scene.depth``. A non-black constant
background is mirrored (and, through a transparent material, refracted) by the sphere at
depth > 1, so then this equals ``render`` only at ``depth = 1``.

API
---
- :func:`render_numpy` ``(width, height, color, smoothness, metalness, transparency,
  directions, intensities, light_colors, ambient, *, point_positions=None, ...) ->
  (image (H, W, 3), mask (H, W))``.
- :func:`sphere_normals` ``(width, height) -> (normals (P, 3), mask (H, W))`` and
  :func:`shade_numpy` ``(normals, ...) -> radiance (P, 3)``: the two halves of
  :func:`render_numpy`, for fits that precompute the geometry once.
- :func:`arrays_from_scene` ``(scene, material=None) -> dict`` of the keyword arguments of
  :func:`render_numpy`, taken from a strauss-fit :class:`~strauss_fit.Scene` and
  :class:`~strauss_fit.Material`; ``render_numpy(**arrays_from_scene(scene))``.
- :func:`check_against_strauss_fit` ``(scene, material=None, tol=1e-10) -> float``: the
  largest absolute difference from ``strauss_fit.render`` in float64; raises
  ``AssertionError`` beyond ``tol``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from strauss_fit.models.strauss import K_F, K_G, K_J

__all__ = [
    "arrays_from_scene",
    "check_against_strauss_fit",
    "fresnel",
    "render_numpy",
    "shade_numpy",
    "shadow",
    "sphere_normals",
]

_F_SCALE = (1 - K_F) ** -2 - K_F**-2
_G_SCALE = (1 - K_G) ** -2 - K_G**-2


def fresnel(x: np.ndarray) -> np.ndarray:
    """F(x) = [(x − k_f)⁻² − k_f⁻²] / [(1 − k_f)⁻² − k_f⁻²], x = 2θ/π in [0, 1]."""
    return ((x - K_F) ** -2 - K_F**-2) / _F_SCALE


def shadow(x: np.ndarray) -> np.ndarray:
    """G(x) = [(1 − k_g)⁻² − (x − k_g)⁻²] / [(1 − k_g)⁻² − k_g⁻²], x = 2θ/π in [0, 1]."""
    return ((1 - K_G) ** -2 - (x - K_G) ** -2) / _G_SCALE


def _normalised_angle(cosine: np.ndarray) -> np.ndarray:
    """2·acos(c)/π for c clamped to [0, 1]."""
    return np.arccos(np.clip(cosine, 0.0, 1.0)) * (2.0 / np.pi)


def sphere_normals(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (P, 3) at the P pixel centres that show the sphere, and the (H, W) mask.

    The normals are listed in row-major pixel order (``image[mask] = radiance``).
    """
    x = (np.arange(width) + 0.5) / width * 2 - 1
    y = 1 - (np.arange(height) + 0.5) / height * 2
    xx, yy = np.meshgrid(x, y)
    rho2 = xx * xx + yy * yy
    mask = rho2 < 1.0
    px, py = xx[mask], yy[mask]
    pz = np.sqrt(1.0 - rho2[mask])
    normals = np.stack([px, py, pz], axis=-1)
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    return normals, mask


def _one_light(normals, to_light, n_dot_v, x_gamma_g, color, s, m, r_d, r_n, light_color):
    """Q_d C_L + Q_s (P, 3) of one light per unit intensity; ``to_light`` (P, 3) or (3,)."""
    n_dot_l = np.sum(normals * to_light, axis=-1)
    lit = (n_dot_l > 0) & (n_dot_v > 0)
    # cos beta = R.V with R = 2 N (N.L) - L and V = (0, 0, 1)
    to_light_z = to_light[..., 2]
    cos_beta = np.clip(2 * n_dot_l * normals[:, 2] - to_light_z, 0.0, 1.0)
    cos_alpha = np.where(lit, np.clip(n_dot_l, 0.0, 1.0), 0.0)
    x_alpha = _normalised_angle(n_dot_l)
    f_alpha = fresnel(x_alpha)
    j = np.where(lit, f_alpha * shadow(x_alpha) * x_gamma_g, 0.0)
    r_j = np.minimum(1.0, r_n + j * (r_n + K_J))
    if s < 1:
        h = 3.0 / (1.0 - s)
        falloff = np.zeros_like(cos_beta)
        positive = lit & (cos_beta > 0)
        falloff[positive] = cos_beta[positive] ** h
    else:  # s = 1: the highlight is a delta at cos beta = 1
        falloff = np.where(lit & (cos_beta >= 1), 1.0, 0.0)
    r_s = r_j * falloff
    c_s = light_color + (m * (1 - f_alpha))[:, None] * (color - light_color)
    diffuse = (1 - m * s) * r_d * cos_alpha
    return diffuse[:, None] * (color * light_color) + r_s[:, None] * c_s


def shade_numpy(
    normals: np.ndarray,
    color: Any,
    smoothness: float,
    metalness: float,
    transparency: float,
    directions: Any = None,
    intensities: Any = None,
    light_colors: Any = None,
    ambient: float | None = None,
    *,
    point_positions: Any = None,
    point_intensities: Any = None,
    point_colors: Any = None,
    point_attenuation: Any = None,
) -> np.ndarray:
    """Local Strauss radiance (P, 3) at unit ``normals`` (P, 3) on the unit sphere, V = +z.

    ``directions`` (K, 3) unit vectors toward K directional lights, ``intensities`` (K,),
    ``light_colors`` (K, 3) (default white); ``point_positions`` (M, 3),
    ``point_intensities`` (M,), ``point_colors`` (M, 3) (default white) and
    ``point_attenuation`` (M, 3) of (c0, c1, c2) (default (1, 0, 0)); ``ambient`` the
    ambient intensity (``None`` or 0 for none). Scalars are Python floats.
    """
    normals = np.asarray(normals, dtype=np.float64)
    color = np.asarray(color, dtype=np.float64)
    s, m, t = float(smoothness), float(metalness), float(transparency)
    r_d = (1 - s**3) * (1 - t)
    r_n = (1 - t) * s**3
    n_dot_v = normals[:, 2]
    g_gamma = shadow(_normalised_angle(n_dot_v))  # the view factor G(2γ/π) of j, shared by all lights
    radiance = np.zeros_like(normals)

    if directions is not None:
        directions = np.atleast_2d(np.asarray(directions, dtype=np.float64))
        k = directions.shape[0]
        intensities = np.broadcast_to(np.asarray(intensities, dtype=np.float64), (k,))
        colors = (
            np.ones((k, 3))
            if light_colors is None
            else np.broadcast_to(np.asarray(light_colors, dtype=np.float64), (k, 3))
        )
        for direction, intensity, light_color in zip(directions, intensities, colors):
            radiance += intensity * _one_light(normals, direction, n_dot_v, g_gamma, color, s, m, r_d, r_n, light_color)

    if point_positions is not None:
        positions = np.atleast_2d(np.asarray(point_positions, dtype=np.float64))
        k = positions.shape[0]
        intensities = np.broadcast_to(np.asarray(point_intensities, dtype=np.float64), (k,))
        colors = (
            np.ones((k, 3))
            if point_colors is None
            else np.broadcast_to(np.asarray(point_colors, dtype=np.float64), (k, 3))
        )
        attenuation = (
            np.broadcast_to([1.0, 0.0, 0.0], (k, 3))
            if point_attenuation is None
            else np.broadcast_to(np.asarray(point_attenuation, dtype=np.float64), (k, 3))
        )
        for position, intensity, light_color, (c0, c1, c2) in zip(positions, intensities, colors, attenuation):
            offset = position - normals  # the surface point of the unit sphere is its normal
            distance = np.linalg.norm(offset, axis=-1)
            to_light = offset / distance[:, None]
            irradiance = intensity / (c0 + c1 * distance + c2 * distance**2)
            radiance += irradiance[:, None] * _one_light(
                normals, to_light, n_dot_v, g_gamma, color, s, m, r_d, r_n, light_color
            )

    if ambient:
        radiance += float(ambient) * r_d * color
    return radiance


def render_numpy(
    width: int,
    height: int,
    color: Any,
    smoothness: float,
    metalness: float,
    transparency: float,
    directions: Any = None,
    intensities: Any = None,
    light_colors: Any = None,
    ambient: float | None = None,
    *,
    point_positions: Any = None,
    point_intensities: Any = None,
    point_colors: Any = None,
    point_attenuation: Any = None,
    background: Any = (0.0, 0.0, 0.0),
) -> tuple[np.ndarray, np.ndarray]:
    """Render the orthographic unit sphere: float64 image (height, width, 3) and mask.

    Arguments as in :func:`shade_numpy`; ``background`` is the RGB colour of pixels off the
    sphere (black by default).
    """
    normals, mask = sphere_normals(width, height)
    radiance = shade_numpy(
        normals,
        color,
        smoothness,
        metalness,
        transparency,
        directions,
        intensities,
        light_colors,
        ambient,
        point_positions=point_positions,
        point_intensities=point_intensities,
        point_colors=point_colors,
        point_attenuation=point_attenuation,
    )
    image = np.empty((height, width, 3))
    image[...] = np.asarray(background, dtype=np.float64)
    image[mask] = radiance
    return image, mask


def arrays_from_scene(scene, material=None) -> dict[str, Any]:
    """The keyword arguments of :func:`render_numpy` for a strauss-fit scene and material.

    Only what this reference models is accepted: an orthographic camera and a constant
    background colour (raises ``ValueError`` otherwise). ``material`` defaults to the
    scene's.
    """
    material = scene.material if material is None else material
    if scene.camera.projection != "orthographic":
        raise ValueError("the NumPy reference renders the orthographic camera only")
    if scene.background.kind != "color":
        raise ValueError("the NumPy reference supports a constant background colour only")
    lights = scene.lights
    out: dict[str, Any] = {
        "width": scene.camera.width,
        "height": scene.camera.height,
        "color": np.asarray(material.color, dtype=np.float64),
        "smoothness": float(material.smoothness),
        "metalness": float(material.metalness),
        "transparency": float(material.transparency),
        "ambient": None if lights.ambient is None else float(lights.ambient),
        "background": np.asarray(scene.background.color, dtype=np.float64),
    }
    if lights.directional is not None:
        out["directions"] = np.asarray(lights.directional.direction, dtype=np.float64)
        out["intensities"] = np.asarray(lights.directional.intensity, dtype=np.float64)
        out["light_colors"] = np.asarray(lights.directional.color, dtype=np.float64)
    if lights.point is not None:
        out["point_positions"] = np.asarray(lights.point.position, dtype=np.float64)
        out["point_intensities"] = np.asarray(lights.point.intensity, dtype=np.float64)
        out["point_colors"] = np.asarray(lights.point.color, dtype=np.float64)
        out["point_attenuation"] = np.asarray(lights.point.attenuation, dtype=np.float64)
    return out


def check_against_strauss_fit(scene, material=None, tol: float = 1e-10) -> float:
    """Largest absolute difference between :func:`render_numpy` and ``strauss_fit.render``
    (float64, mode "exact") for this scene; ``AssertionError`` if above ``tol`` or if the
    masks differ. The scene's background must be black unless ``scene.depth == 1``."""
    import jax.numpy as jnp

    from strauss_fit import render

    image_np, mask_np = render_numpy(**arrays_from_scene(scene, material))
    image_jax, mask_jax = render(scene, material, mode="exact", dtype=jnp.float64)
    image_jax, mask_jax = np.asarray(image_jax), np.asarray(mask_jax)
    assert mask_np.shape == mask_jax.shape and np.array_equal(mask_np, mask_jax), "sphere masks differ"
    error = float(np.max(np.abs(image_np - image_jax)))
    assert error <= tol, f"NumPy reference differs from strauss_fit.render by {error:.3e} > {tol:.1e}"
    return error
