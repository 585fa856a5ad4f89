r"""The BRDF of Ngan, Durand & Matusik's (2005) Cook–Torrance fits to the MERL materials, as the
BSDF benchmark *bbm* defines it, and its image under a strauss-fit scene.

Ngan et al. fitted every isotropic MERL material with a Lambertian term plus one specular
model; bbm (Pieter Peers, github.com/bsdfbenchmark/bbm) ships their published parameters
(``fits/ngan_cooktorrance.fit``) and the model they belong to. Each material is
``Aggregate(Lambertian(albedo = kd), NganCookTorrance(albedo = ks, eta = F0, roughness = m))``,
and its BRDF, read from bbm at commit ``9807fb38d7ab51802f3a0fe0f65cf763cb01a0f4`` (2023-09-01), is

```text
f_r(\omega_i, \omega_o) = \frac{k_d}{\pi}
    + k_s\,\frac{D(h)\,G(\omega_i, \omega_o, h)\,F(\omega_i, \omega_o, h)}{\pi\,\cos\theta_i\cos\theta_o}
```

for `\cos\theta_i, \cos\theta_o > 0` (0 otherwise; the Lambertian term also at 0), with

- ``include/bsdfmodel/ngan.h``: ``ngancooktorrance`` = ``scaledmodel<microfacet<beckmann<Isotropic>,
  vgroove, schlick, microfacet_n::Cook>, SpecularScale>`` — the specular albedo `k_s`
  multiplies the microfacet model, whose normalisation factor ``microfacet_n::Cook`` is π;
- ``include/bsdfmodel/microfacet.h``: ``D * G * F / NormalizationFactor / (cosθ_i cosθ_o)``,
  the half vector `h = \mathrm{normalise}(\omega_i + \omega_o)`, and the Fresnel term
  evaluated at the mean of `\omega_i\cdot h` and `\omega_o\cdot h` (equal; bbm
  averages them against round-off);
- ``include/ndf/beckmann.h`` (``Normalize = true``, the default that ``ngan.h`` uses):
  `D(h) = \exp(-\tan^2\theta_h / m^2) / (\pi\, m^2 \cos^4\theta_h)` for
  `\cos\theta_h > 0` — normalised so that `\int D\cos\theta_h\,d\omega_h = 1`;
- ``include/maskingshadowing/vgroove.h``: `G = \min(1,\ 2\cos\theta_h\cos\theta_i/(\omega_i\cdot h),\
  2\cos\theta_h\cos\theta_o/(\omega_o\cdot h))`, 0 unless both dot products with h are positive;
- ``include/bbm/fresnel_schlick.h``: `F = F_0 + (1 - F_0)(1 - \cos)^5`, whose parameter
  defaults to ``ior::reflectance``: the fits' ``eta`` *is* `F_0`, not an index of
  refraction;
- ``include/bsdfmodel/lambertian.h``: ``albedo / π``.

Radiance follows strauss-fit's convention (docs/study.md, "Normalisation"): a light of
intensity I delivers the irradiance π I cos θ_i, so it contributes
`L_o = \pi f_r \cos\theta_i\, I` — a white Lambertian `k_d = 1` shows
`I\cos\theta_i`, exactly as Phong's `k_d C_d = 1` and Strauss's C = 1, s = m = 0
do. The scene's ambient light A adds `A\,k_d` (the radiance of a Lambertian surface
under a uniform surround; the specular lobe's share of it is left out, as Phong's ambient
term leaves it out).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from ..precision import float64
from ..rendering.coverage import fully_covered
from ..scene.camera import intersect_unit_sphere, rays_through
from ..scene.lights import sample_lights
from ..scene.loading import Scene

#: The bbm commit the formulas were read from (``include/bsdfmodel/ngan.h`` and the files it uses).
BBM_COMMIT = "9807fb38d7ab51802f3a0fe0f65cf763cb01a0f4"
#: Sub-samples per pixel side of `render_material` (the image a camera records is the
#: mean over each pixel's footprint; a Beckmann lobe of m = 0.005 is 0.3° wide, a 48-pixel
#: sphere's pixel spans 2.4° of normal at its centre, so one sample per pixel is a lottery).
SUPERSAMPLE = 8


@dataclass(frozen=True)
class NganMaterial:
    """One material of Ngan's Cook–Torrance fits: ``kd`` (the Lambertian albedo, RGB), ``ks``
    (the specular albedo, RGB), ``f0`` (Schlick's reflectance at normal incidence; bbm's
    ``eta``) and ``roughness`` (Beckmann's m)."""

    name: str
    kd: tuple[float, float, float]
    ks: tuple[float, float, float]
    f0: float
    roughness: float

    def to_dict(self) -> dict[str, object]:
        return {
            "name": self.name,
            "kd": list(self.kd),
            "ks": list(self.ks),
            "f0": self.f0,
            "roughness": self.roughness,
        }


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.sum(a * b, axis=-1)


def beckmann(cos_h: np.ndarray, roughness: float) -> np.ndarray:
    """bbm's normalised isotropic Beckmann distribution D(h) at cos θ_h (0 for cos θ_h ≤ 0)."""
    cos_h = np.asarray(cos_h, dtype=np.float64)
    m2 = float(roughness) ** 2
    positive = cos_h > 0
    c2 = np.where(positive, cos_h**2, 1.0)
    tan2 = (1.0 - c2) / c2
    with np.errstate(under="ignore", divide="ignore", invalid="ignore"):  # m² underflowing to 0 gives NaN
        value = np.exp(-tan2 / m2) / (math.pi * m2 * c2 * c2)
    return np.where(positive, value, 0.0)


def vgroove(cos_h: np.ndarray, cos_i: np.ndarray, cos_o: np.ndarray, ih: np.ndarray, oh: np.ndarray) -> np.ndarray:
    """bbm's V-groove (Cook–Torrance) masking–shadowing G (0 unless ω_i·h, ω_o·h > 0)."""
    ok = (ih > 0) & (oh > 0)
    safe_ih, safe_oh = np.where(ok, ih, 1.0), np.where(ok, oh, 1.0)
    g = np.minimum(1.0, np.minimum(2 * cos_h * cos_i / safe_ih, 2 * cos_h * cos_o / safe_oh))
    return np.where(ok, g, 0.0)


def schlick(f0: float, cos: np.ndarray) -> np.ndarray:
    """Schlick's Fresnel approximation with reflectance ``f0`` at normal incidence."""
    return f0 + (1.0 - f0) * (1.0 - cos) ** 5


def brdf(material: NganMaterial, normal: np.ndarray, to_light: np.ndarray, to_eye: np.ndarray) -> np.ndarray:
    """f_r (..., 3) of ``material`` (module docstring) for unit vectors of broadcastable
    shapes (..., 3): the surface normal, the direction toward the light and toward the eye."""
    normal, to_light, to_eye = (np.asarray(v, dtype=np.float64) for v in (normal, to_light, to_eye))
    cos_i = _dot(normal, to_light)
    cos_o = _dot(normal, to_eye)
    half = to_light + to_eye
    length = np.sqrt(_dot(half, half))
    half = half / np.where(length > 0, length, 1.0)[..., None]
    cos_h = _dot(normal, half)
    ih, oh = _dot(to_light, half), _dot(to_eye, half)
    above = (cos_i > 0) & (cos_o > 0)
    safe = np.where(above, cos_i * cos_o, 1.0)
    lobe = (
        beckmann(cos_h, material.roughness)
        * vgroove(cos_h, cos_i, cos_o, ih, oh)
        * schlick(material.f0, 0.5 * (ih + oh))
        / (math.pi * safe)
    )
    specular = np.where(above, lobe, 0.0)[..., None] * np.asarray(material.ks)
    diffuse = np.where((cos_i >= 0) & (cos_o >= 0), 1.0 / math.pi, 0.0)[..., None] * np.asarray(material.kd)
    return diffuse + specular


def render_material(
    material: NganMaterial, scene: Scene, supersample: int = SUPERSAMPLE
) -> tuple[np.ndarray, np.ndarray]:
    """The image (H, W, 3) of ``material`` on the unit sphere of ``scene`` and the pixels it
    holds (H, W): those whose whole footprint shows the sphere
    (`fully_covered`), each the mean radiance over
    ``supersample`` × ``supersample`` points of its footprint; 0 elsewhere. Radiance per
    light π f_r cos θ_i I·colour, plus the ambient light times kd (module docstring)."""
    camera = scene.camera
    height, width = camera.height, camera.width
    count = int(supersample)
    offsets = (np.arange(count) + 0.5) / count
    with float64():
        covered = np.asarray(fully_covered(camera))
        rows, cols = np.nonzero(covered)
        # image-plane points of every sub-sample of the covered pixels, (P, S², 2)
        sx = (cols[:, None] + np.tile(offsets, count)[None, :]) / width * 2 - 1
        sy = 1 - (rows[:, None] + np.repeat(offsets, count)[None, :]) / height * 2
        rays = rays_through(camera, jnp.asarray(sx), jnp.asarray(sy), jnp.float64)
        hit = intersect_unit_sphere(rays)
        normal = np.asarray(hit.point)
        to_eye = -np.asarray(rays.direction)
        seen = sample_lights(scene.lights, jnp.asarray(normal))
        ambient = scene.lights.ambient
        ambient = 0.0 if ambient is None else float(np.asarray(ambient))
    radiance = np.zeros(normal.shape[:-1] + (3,))
    if seen is not None:
        to_light = np.asarray(seen.to_light)
        strength = np.asarray(seen.irradiance)[..., None] * np.asarray(seen.color)  # (K, 3) or (P, S², K, 3)
        for k in range(to_light.shape[-2]):
            direction = to_light[..., k, :]
            light = strength[..., k, :]
            cos_i = np.clip(_dot(normal, direction), 0.0, None)
            f = brdf(material, normal, direction, to_eye)
            radiance += math.pi * f * cos_i[..., None] * light
    radiance += ambient * np.asarray(material.kd)
    image = np.zeros((height, width, 3))
    image[rows, cols] = radiance.mean(axis=1)
    return image, covered
