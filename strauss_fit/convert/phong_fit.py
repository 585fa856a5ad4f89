r"""Least-squares fitting of Phong parameters to sphere images (the Strauss → Phong direction).

Only products of Phong's coefficients and colours reach the image: the diffuse term is
`k_d C_d` and the highlight `k_s C_{sp}`, so `k_d` and `C_d` (and
`k_s`, `C_{sp}`) cannot be told apart. The fit therefore works on the
identifiable set

- `D = k_d C_d` (RGB, each in [0, 1]),
- `S = k_s C_{sp}` (RGB, each in [0, 1]),
- `u = \log n / \log 10000` in [0, 1], i.e. the exponent `n = 10000^u \in [1, 10000]`
  on a log scale (a step in u changes the highlight's width by the same factor anywhere),

each through the same smooth sine transform as the Strauss fit
(`strauss_fit.fitting.parameters.Layout`, `x = (1 + \sin\theta)/2`), and reports
`k_d = \max_c D_c`, `C_d = D / k_d` (white when D = 0), likewise for
`k_s`, `C_{sp}`. The ambient coefficient is not fitted: it is given
(``ambient_ka``, a scalar), and the ambient term is `k_a I_a C_d`.

`solve_phong_starts` solves one material from several starts (Levenberg–Marquardt,
optimistix) as a `strauss_fit.engine.Kernel`, so that the conversions run it over
many materials at once (`strauss_fit.convert.converter`).
"""

from __future__ import annotations

import math
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jax import Array

from ..engine import Kernel
from ..fitting.parameters import Layout
from ..fitting.solvers import STRICT_REJECT_RATIO, levenberg_marquardt
from ..models.phong import MAX_EXPONENT, PhongMaterial, coefficient, highlight_power, phong_angles
from ..scene.camera import intersect_unit_sphere, primary_rays
from ..scene.lights import sample_lights
from ..scene.loading import Scene
from ..stats import laplace

#: The fitted vector: D (rgb), S (rgb), u (log exponent), all in [0, 1].
PHONG_LAYOUT = Layout(("diffuse_r", "diffuse_g", "diffuse_b", "specular_r", "specular_g", "specular_b", "log_exponent"))
LOG_MAX_EXPONENT = math.log(MAX_EXPONENT)


def exponent_from_unit(u: Any) -> Any:
    """`n = 10000^u`."""
    return jnp.exp(LOG_MAX_EXPONENT * jnp.asarray(u))


def unit_from_exponent(n: float) -> float:
    """`u = \\log n / \\log 10000`, with n clipped to [1, 10000]."""
    return float(np.log(np.clip(n, 1.0, MAX_EXPONENT)) / LOG_MAX_EXPONENT)


class PhongGeometry(eqx.Module):
    """The material-independent part of a Phong rendering at N pixels: the diffuse part's
    light ``diffuse_light`` = Σ_k E_k cos α_k C_L,k (N, 3); per light (K of them) cos β —
    R·V for Phong, N·H for Blinn–Phong — where the light reaches a surface the viewer sees
    (0 elsewhere, where nothing is reflected) and the attenuated intensity; the lights'
    colours and the ambient light. Why angles, not vectors: the fit's solver renders
    hundreds of times per material, and none of these depend on it."""

    normal: Array
    cos_beta: Array | None
    cos_half: Array | None
    irradiance: Array | None
    diffuse_light: Array | None
    light_color: Array | None
    ambient: Array | None


def phong_geometry(scene: Scene, index: np.ndarray) -> PhongGeometry:
    """`PhongGeometry` of ``scene`` (float64) at the flat pixel ``index``."""
    scene = scene.astype(jnp.float64)
    rays = primary_rays(scene.camera, jnp.float64)
    hits = intersect_unit_sphere(rays)
    index = jnp.asarray(index)

    def take(x):
        return x.reshape((-1,) + x.shape[2:])[index]

    normal, to_eye = take(hits.point), take(-rays.direction)
    samples = sample_lights(scene.lights, hits.point)
    cos_beta = cos_half = irradiance = diffuse_light = color = None
    if samples is not None:
        batch = hits.point.shape[:-1]
        # directional-only scenes give (K, 3) and (K,): broadcast to every pixel first
        to_light = take(jnp.broadcast_to(samples.to_light, batch + samples.to_light.shape[-2:]))
        irradiance = take(jnp.broadcast_to(samples.irradiance, batch + samples.irradiance.shape[-1:]))
        color = samples.color  # (K, 3)
        lit, cos_alpha, cos_beta = phong_angles(normal[:, None, :], to_light, to_eye[:, None, :], False)
        _, _, cos_half = phong_angles(normal[:, None, :], to_light, to_eye[:, None, :], True)
        # 0 where not lit, so that the highlight is 0 there as in phong_shade
        cos_beta, cos_half = jnp.where(lit, cos_beta, 0.0), jnp.where(lit, cos_half, 0.0)
        diffuse_light = jnp.sum((irradiance * cos_alpha)[..., None] * color, axis=-2)
    return PhongGeometry(
        normal=normal,
        cos_beta=cos_beta,
        cos_half=cos_half,
        irradiance=irradiance,
        diffuse_light=diffuse_light,
        light_color=color,
        ambient=scene.lights.ambient,
    )


def shade_geometry(geometry: PhongGeometry, material: PhongMaterial) -> Array:
    r"""Phong radiance (N, 3) at the pixels of ``geometry``, as
    `strauss_fit.rendering.phong.render_phong` renders it:
    `\sum_k E_k C_{L,k} (k_d C_d \cos\alpha_k + k_s C_{sp} \cos^n\beta_k)` plus the
    ambient term (summed in another order: equal to rounding)."""
    radiance = jnp.zeros(geometry.normal.shape, dtype=geometry.normal.dtype)
    if geometry.diffuse_light is not None:
        cos_beta = geometry.cos_half if material.blinn else geometry.cos_beta
        highlight = geometry.irradiance * highlight_power(cos_beta, material.exponent)  # (N, K)
        specular_light = highlight[:, 0, None] * geometry.light_color[0]
        for k in range(1, geometry.light_color.shape[0]):
            specular_light = specular_light + highlight[:, k, None] * geometry.light_color[k]
        radiance = geometry.diffuse_light * (coefficient(material.kd) * material.diffuse_color) + specular_light * (
            coefficient(material.ks) * material.specular_color
        )
    if geometry.ambient is not None:
        ka = material.ka if material.ka.ndim else material.ka[None]
        radiance = radiance + geometry.ambient * ka * material.diffuse_color
    return radiance


def material_from_vector(x: Array, ambient_ka: Any = 0.0, blinn: bool = False) -> PhongMaterial:
    """The Phong material of a physical vector in `PHONG_LAYOUT` order (traceable):
    kd = max D, Cd = D / kd; ks = max S, Cs = S / ks (white where the maximum is 0)."""
    x = jnp.asarray(x)
    d, s, u = x[..., 0:3], x[..., 3:6], x[..., 6]
    kd = jnp.max(d, axis=-1)
    ks = jnp.max(s, axis=-1)
    cd = jnp.where(kd[..., None] > 0, d / jnp.where(kd > 0, kd, 1.0)[..., None], 1.0)
    cs = jnp.where(ks[..., None] > 0, s / jnp.where(ks > 0, ks, 1.0)[..., None], 1.0)
    material = object.__new__(PhongMaterial)
    for name, value in (
        ("ka", jnp.asarray(ambient_ka, dtype=x.dtype)),
        ("kd", kd),
        ("ks", ks),
        ("exponent", exponent_from_unit(u)),
        ("diffuse_color", cd),
        ("specular_color", cs),
    ):
        object.__setattr__(material, name, value)
    object.__setattr__(material, "blinn", bool(blinn))
    return material


def vector_from_material(material: PhongMaterial) -> np.ndarray:
    """The physical vector (D, S, u) of a concrete Phong material (products clipped to [0, 1])."""
    kd = np.broadcast_to(np.asarray(material.kd, dtype=np.float64), (3,))
    ks = np.broadcast_to(np.asarray(material.ks, dtype=np.float64), (3,))
    d = np.clip(kd * np.asarray(material.diffuse_color, dtype=np.float64), 0.0, 1.0)
    s = np.clip(ks * np.asarray(material.specular_color, dtype=np.float64), 0.0, 1.0)
    return np.concatenate([d, s, [unit_from_exponent(float(material.exponent))]])


class PhongProblem(eqx.Module):
    """A Phong fit: geometry and target at the used pixels, the ambient coefficient, and
    the scale residuals are divided by (reference noise × √N, as in `strauss_fit.fitting.problem`)."""

    geometry: PhongGeometry
    target: Array
    residual_scale: Array
    ambient_ka: Array
    blinn: bool = eqx.field(static=True, default=False)
    layout: Layout = eqx.field(static=True, default=PHONG_LAYOUT)

    def physical(self, theta: Array) -> Array:
        return self.layout.to_physical(theta)

    def render_physical(self, x: Array) -> Array:
        """Model radiance (N, 3) for the physical vector ``x``."""
        return shade_geometry(self.geometry, material_from_vector(x, self.ambient_ka, self.blinn))

    def residual_physical(self, x: Array) -> Array:
        return (self.render_physical(x) - self.target).ravel()

    def residual(self, theta: Array, _args: Any = None) -> Array:
        return self.residual_physical(self.physical(theta)) / self.residual_scale


def phong_problem(scene: Scene, index: np.ndarray, *, blinn: bool = False) -> PhongProblem:
    """A `PhongProblem` template (target zero) for the pixels ``index`` of ``scene``."""
    geometry = phong_geometry(scene, index)
    return PhongProblem(
        geometry=geometry,
        target=jnp.zeros((len(index), 3)),
        residual_scale=jnp.asarray(1.0),
        ambient_ka=jnp.asarray(0.0),
        blinn=blinn,
    )


def _solve_phong_starts(problem: Any, thetas: Array, rtol: float, atol: float, max_steps: int, batched: bool):
    """Levenberg–Marquardt (`strauss_fit.fitting.solvers.levenberg_marquardt`, the fits'
    own) from every row of ``thetas`` of one problem, each
    start to its own convergence: one after the other (``lax.map``) on a CPU, vectorised
    (``vmap``) when ``batched``. Returns θ (S, P), the normalised cost Σr² (S,), the step
    counts and whether each solve succeeded."""
    solver = levenberg_marquardt(rtol, atol, reject_ratio=STRICT_REJECT_RATIO)

    def one(theta0):
        solution = optx.least_squares(problem.residual, solver, theta0, max_steps=max_steps, throw=False)
        r = problem.residual(solution.value)
        return (
            solution.value,
            jnp.sum(r * r),
            solution.stats["num_steps"],
            solution.result == optx.RESULTS.successful,
        )

    return jax.vmap(one)(thetas) if batched else jax.lax.map(one, thetas)


#: `_solve_phong_starts` as a `Kernel`: the conversions run
#: it over many materials at once (`strauss_fit.engine.run_batched`).
solve_phong_starts = Kernel(_solve_phong_starts, "phong_solve_starts")


def laplace_deviations_from(
    jacobian: np.ndarray, rss: float, free: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Standard deviations and correlation matrix of the physical parameters from the
    Gauss–Newton (Laplace) approximation `\\Sigma = \\sigma^2 (J^\top J)^{-1}`,
    `\\sigma^2 = \\mathrm{RSS}/(N - P)` (`strauss_fit.stats.laplace`), as for a
    Strauss fit, from the Jacobian ``jacobian`` already computed; the entries not ``free``
    (held) are left out of the inverse (deviation 0, the others conditional on them)."""
    j = np.asarray(jacobian)
    n, p = j.shape
    info = laplace.information(j)
    if free is not None:
        info = info * np.outer(free, free)
    covariance = laplace.covariance(info, laplace.residual_variance(rss, n, p))
    return laplace.deviations(covariance), laplace.correlation(covariance)
