r"""Rendering the sphere with the Strauss model: local lighting plus the global model.

Rendering runs in two stages so that a fit can do the first once per scene:

1. `prepare` traces the primary rays and computes everything that does not depend
   on the material: hit mask, normals, view vectors, the angular terms of every light
   (`strauss_fit.models.strauss.angular_terms`), the background seen by missed rays and, when
   reflection is traced, the background seen along the mirror direction.
2. `shade_prepared` adds the material: the local model at every hit and, where the
   `RenderPlan` asks for it, the global model.

`render` composes them.

Global model (recursive ray tracing, Strauss's "global illumination model"). At a hit seen
from outside, with `\gamma` the angle of view:

- the *reflected* ray, along `R_V = 2N(N\cdot V) - V`, is weighted by the specular
  reflectivity for light arriving from the mirror direction, `r_j` with α = γ
  (cos β = 1), and coloured by `C_s` (light colour white). The sphere is convex, so it
  sees the background;
- the *transmitted* ray is weighted by `z = t(1 - r_s)/(1 - r_n)` (nothing where
  t = 0), bent by Snell's law with `n_{12} = 1/n`,
  `T = [n_{12}(N\cdot V) - \cos\alpha_2] N - n_{12} V`, and tinted by the colour C
  (a coloured-glass filter: without the tint a fully transparent material would show no
  colour at all and C could not be recovered from it). The tint applies once per passage
  through the body, at entry.

Inside the sphere a ray meets the surface again at its exit point, where the same
weights apply with the inward normal: the refracted part (`n_{12} = n`) leaves and
sees the background; the reflected part (weight `r_j`, colour `C_s`) stays
inside. Beyond the critical angle, `\sin\alpha > 1/n`, there is no refracted ray
(total internal reflection): the share z that would have left is reflected too. Direct
light is evaluated only at the hit seen from outside (lamps seen through the glass,
i.e. caustics, are not modelled).

``depth`` counts surface interactions, the first hit included: ``depth = 1`` is the local
model alone. A ray still inside the sphere after the last allowed interaction is given the
background radiance along its direction, as if the sphere ended there; nothing is dropped
silently.

Bounded work (`effective_depth`). Each interaction inside the sphere multiplies what
a ray still carries by the reflected weight `r_j C_s`, and inside a sphere every
interaction of a ray that entered by refraction happens at the same angle, below the
critical angle `\arcsin(1/n)`, where `r_j` is small (at most 0.077 for the
bundled glass, t = 0.9, s = 0.9, n = 1.5). So the light a path can still bring after k
interactions falls geometrically, and `render` traces only as deep as it can change
the image by more than a tolerance (by default the unit roundoff of the result's dtype,
relative to the background's brightest radiance): the compiled program is smaller (at
``depth = 64`` a glass sphere compiled for about 70 s and 2.5 GB, 128 × 128 pixels).

Only what the scene needs is computed (`plan_render`): no light term for a kind of
light the scene lacks, no reflected ray when the background is black, and no transmitted
ray for an opaque material. An opaque material over a black background costs exactly the
local model.
"""

from __future__ import annotations

import dataclasses
import functools
import weakref
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.custom_derivatives import SymbolicZero

from ..models.material import Material
from ..models.strauss import (
    DEFAULT_TABLE_SIZE,
    K_J,
    MODES,
    AngularTerms,
    Mode,
    ShadeWeights,
    _fresnel,  # F and G on NumPy arrays: the bound of effective_depth
    _shadow,
    angular_terms,
    combine_rgb,
    diffuse_reflectivity,
    fresnel,
    normalised_angle,
    shadow,
    specular_base,
    specular_color,
    specular_peak,
    weight_slopes,
    weights_of,
)
from ..numerics import dot, is_traced, safe_divide, safe_normalize, safe_sqrt
from ..precision import uses_float64
from ..scene.background import Background, background_radiance
from ..scene.camera import Rays, intersect_unit_sphere, primary_rays
from ..scene.lights import sample_lights
from ..scene.loading import Scene, background_peak, check_radiance_range


class RenderPlan(NamedTuple):
    """Which parts of the global model are traced (decided before compiling)."""

    reflect: bool
    transmit: bool


def _is_zero(x: Any) -> bool:
    """True only for a concrete array that is all zeros (traced values may be non-zero)."""
    if isinstance(x, jax.core.Tracer):
        return False
    return not np.any(np.asarray(x))


def plan_render(scene: Scene, material: Material | None = None, *, transparent: bool | None = None) -> RenderPlan:
    """Decide what the global model must trace for this scene and material.

    Reflection is traced when ``scene.depth > 1`` and the background is not black.
    Transmission is traced when ``scene.depth > 1`` and the material may be transparent:
    ``transparent`` if given (fits pass whether t is free), else whether ``material``'s
    transparency is non-zero (a traced value counts as possibly non-zero).
    """
    if scene.depth <= 1:
        return RenderPlan(False, False)
    background = scene.background
    black = background.kind == "color" and _is_zero(background.color)
    if transparent is None:
        transparent = material is None or not _is_zero(material.transparency)
    return RenderPlan(reflect=not black, transmit=bool(transparent))


class Prepared(eqx.Module):
    """The material-independent part of a rendering (see `prepare`)."""

    hit: Array
    point: Array
    normal: Array
    to_eye: Array
    direction: Array
    miss_radiance: Array
    direct: AngularTerms | None
    irradiance: Array | None
    light_color: Array | None
    ambient: Array | None
    mirror_j: Array | None
    mirror_fresnel: Array | None
    reflected_radiance: Array | None


def _mirror_terms(cos_view: Array) -> tuple[Array, Array]:
    """j and F for the mirror direction (α = γ), from cos γ."""
    x = normalised_angle(cos_view)
    f = fresnel(x)
    g = shadow(x)
    return f * g * g, f


def prepare(
    scene: Scene, plan: RenderPlan, mode: Mode = "exact", table_size: int = DEFAULT_TABLE_SIZE, dtype: Any = None
) -> Prepared:
    """Trace primary rays and compute every material-independent quantity."""
    if mode not in MODES:
        raise ValueError(f"unknown mode {mode!r}; expected one of {', '.join(MODES)}")
    dtype = dtype or jnp.result_type(float)
    rays = primary_rays(scene.camera, dtype)
    hits = intersect_unit_sphere(rays)
    normal = hits.point
    to_eye = -rays.direction
    miss_radiance = background_radiance(scene.background, rays)
    samples = sample_lights(scene.lights, hits.point)
    direct = irradiance = light_color = None
    if samples is not None:
        direct = angular_terms(normal[..., None, :], samples.to_light, to_eye[..., None, :], mode, table_size)
        irradiance = jnp.broadcast_to(samples.irradiance, direct.lit.shape)  # per pixel, for take_pixels
        light_color = samples.color
    mirror_j = mirror_fresnel = reflected = None
    if plan.reflect or plan.transmit:
        cos_view = jnp.clip(dot(normal, to_eye), 0.0, 1.0)
        mirror_j, mirror_fresnel = _mirror_terms(cos_view)
    if plan.reflect:
        mirror = 2 * dot(normal, to_eye)[..., None] * normal - to_eye
        reflected = background_radiance(scene.background, Rays(hits.point, mirror))
    return Prepared(
        hit=hits.hit,
        point=hits.point,
        normal=normal,
        to_eye=to_eye,
        direction=rays.direction,
        miss_radiance=miss_radiance,
        direct=direct,
        irradiance=irradiance,
        light_color=light_color,
        ambient=scene.lights.ambient,
        mirror_j=mirror_j,
        mirror_fresnel=mirror_fresnel,
        reflected_radiance=reflected,
    )


_PER_PIXEL_FIELDS = (
    "hit",
    "point",
    "normal",
    "to_eye",
    "direction",
    "miss_radiance",
    "irradiance",
    "mirror_j",
    "mirror_fresnel",
    "reflected_radiance",
)


def take_pixels(prepared: Prepared, index: Any) -> Prepared:
    """The `Prepared` terms of the pixels at flat ``index`` (leading axes (H, W)
    become one axis of ``len(index)``), e.g. the usable pixels of a fit."""
    index = jnp.asarray(index)

    def take(x):
        return None if x is None else x.reshape((-1,) + x.shape[2:])[index]

    replacements = {name: take(getattr(prepared, name)) for name in _PER_PIXEL_FIELDS}
    if prepared.direct is not None:
        replacements["direct"] = AngularTerms(*(take(f) for f in prepared.direct))
    return dataclasses.replace(prepared, **replacements)


def first_pixels(prepared: Prepared, count: int) -> Prepared:
    """The `Prepared` terms of the first ``count`` pixels of a prepared set of pixels
    (one pixel axis, as `take_pixels` returns): a padded set without its padding."""

    def first(x):
        return None if x is None else x[:count]

    replacements = {name: first(getattr(prepared, name)) for name in _PER_PIXEL_FIELDS}
    if prepared.direct is not None:
        replacements["direct"] = AngularTerms(*(first(f) for f in prepared.direct))
    return dataclasses.replace(prepared, **replacements)


def local_radiance(material: Material, prepared: Prepared) -> Array:
    """The local model at every pixel: ambient plus every light, (H, W, 3).

    The lights' part (`direct_radiance`) has its derivatives in closed form: it is
    linear in C and in the irradiance, and s, m, t enter only through three scalar weights
    per pixel and light (`strauss_fit.models.strauss.weight_slopes`). A fit's
    Jacobian then costs about two renders instead of one forward-mode pass per parameter."""
    radiance = jnp.zeros(prepared.normal.shape, dtype=prepared.normal.dtype)
    if prepared.direct is not None:
        radiance = direct_radiance(
            material.color,
            material.smoothness,
            material.metalness,
            material.transparency,
            prepared.irradiance,
            prepared.direct,
            prepared.light_color,
        )
    if prepared.ambient is not None:
        radiance = radiance + prepared.ambient * diffuse_reflectivity(material) * material.color
    return radiance


def _sum_lights(weights: ShadeWeights, irradiance: Array, color: Array, light_color: Array) -> Array:
    r"""`\sum_k E_k [d_k (C \circ C_{L,k}) + r_{s,k} C_{L,k} + w_k (C - C_{L,k})]`, (..., 3)."""
    weights = ShadeWeights(*(w * irradiance for w in weights))  # scalars (..., K)
    # K is static and small: adding the lights one by one avoids materialising
    # (..., K, 3) arrays and a reduction over K
    total = combine_rgb(ShadeWeights(*(w[..., 0] for w in weights)), color, light_color[0])
    for k in range(1, light_color.shape[0]):
        total = total + combine_rgb(ShadeWeights(*(w[..., k] for w in weights)), color, light_color[k])
    return total


def _direct_radiance(color, s, m, t, irradiance, terms, light_color):
    return _sum_lights(weights_of(s, m, t, terms), irradiance, color, light_color)


@jax.custom_jvp
def direct_radiance(
    color: Array, s: Array, m: Array, t: Array, irradiance: Array, terms: AngularTerms, light_color: Array
) -> Array:
    r"""The lights' part of the local model, (..., 3), from the angular ``terms`` of K
    lights (fields (..., K)), their ``irradiance`` (..., K) and colours (K, 3).

    Differentiated in closed form (a ``jax.custom_jvp``): with
    `R = \sum_k E_k [d_k\,C \circ C_{L,k} + r_{s,k} C_{L,k} + w_k (C - C_{L,k})]`,

    ```text
    \dot R = \dot C \circ \sum_k E_k (d_k C_{L,k} + w_k)
    + \sum_{\theta \in \{s, m, t\}} \dot\theta\,\partial_\theta R
    + \sum_k \dot E_k [d_k\,C \circ C_{L,k} + r_{s,k} C_{L,k} + w_k (C - C_{L,k})],
    ```

    `\partial_\theta R` from `strauss_fit.models.strauss.weight_slopes`. Only
    the terms whose tangent is not zero are formed, so that a linearised fit keeps four
    (N, 3) arrays and its Jacobian is a few multiply-adds per parameter. Tangents of the
    geometry or of the lights' colours (never a fit's) go through plain forward-mode
    differentiation."""
    return _direct_radiance(color, s, m, t, irradiance, terms, light_color)


def _is_symbolic_zero(tangent: Any) -> bool:
    return all(isinstance(leaf, SymbolicZero) for leaf in jax.tree.leaves(tangent, is_leaf=_is_zero_leaf))


def _is_zero_leaf(x: Any) -> bool:
    return isinstance(x, SymbolicZero)


def _instantiate(tangent: Any) -> Any:
    def one(leaf):
        if not isinstance(leaf, SymbolicZero):
            return leaf
        aval = leaf.aval
        return (
            np.zeros(aval.shape, aval.dtype) if aval.dtype == jax.dtypes.float0 else jnp.zeros(aval.shape, aval.dtype)
        )

    return jax.tree.map(one, tangent, is_leaf=_is_zero_leaf)


def _direct_radiance_jvp(primals, tangents):
    color, s, m, t, irradiance, terms, light_color = primals
    d_color, d_s, d_m, d_t, d_irradiance, d_terms, d_light = tangents
    if not (_is_symbolic_zero(d_terms) and _is_symbolic_zero(d_light)):
        return jax.jvp(_direct_radiance, primals, _instantiate(tangents))
    weights, slopes = weight_slopes(s, m, t, terms)
    radiance = _sum_lights(weights, irradiance, color, light_color)
    tangent = jnp.zeros_like(radiance)
    if not _is_symbolic_zero(d_color):
        # dR/dC = sum_k E_k (d_k C_Lk + w_k), per channel
        diffuse, tint = weights.diffuse * irradiance, weights.tint * irradiance
        slope = sum(diffuse[..., k, None] * light_color[k] + tint[..., k, None] for k in range(light_color.shape[0]))
        tangent = tangent + slope * d_color
    for slope, d_value in zip(slopes, (d_s, d_m, d_t)):
        if not _is_symbolic_zero(d_value):
            tangent = tangent + _sum_lights(slope, irradiance, color, light_color) * d_value[..., None]
    if not _is_symbolic_zero(d_irradiance):
        tangent = tangent + _sum_lights(weights, d_irradiance, color, light_color)
    return radiance, tangent


direct_radiance.defjvp(_direct_radiance_jvp, symbolic_zeros=True)


def transmission_weight(material: Material, r_s: Array) -> Array:
    """`z = t (1 - r_s)/(1 - r_n)`, and 0 where t = 0 (no division there)."""
    t = material.transparency
    return jnp.where(t > 0, safe_divide(t * (1 - r_s), 1 - specular_base(material)), 0.0)


def refract(direction: Array, normal: Array, relative_ior: Array) -> tuple[Array, Array]:
    r"""Snell refraction of a ray travelling along ``direction`` through a surface whose
    unit ``normal`` faces the incoming ray, with `n_{12} = n_1/n_2`.

    With L = −direction: `\cos\alpha_2 = \sqrt{1 - n_{12}^2 (1 - (N\cdot L)^2)}` and
    `T = [n_{12} (N\cdot L) - \cos\alpha_2] N - n_{12} L`. Returns ``(T, total)``
    where ``total`` marks total internal reflection (the radicand is negative; T is then 0).
    """
    to_source = -direction
    cos_in = dot(normal, to_source)
    radicand = 1 - relative_ior**2 * (1 - cos_in**2)
    total = radicand < 0
    cos_out = safe_sqrt(radicand)
    t = (relative_ior * cos_in - cos_out)[..., None] * normal - relative_ior[..., None] * to_source
    return jnp.where(total[..., None], 0.0, t), total


def interior_radiance(
    material: Material, background: Background, origin: Array, direction: Array, interactions: int
) -> Array:
    """Radiance carried back along a ray travelling inside the sphere, allowing
    ``interactions`` more surface interactions (the exit point included).

    Internal API (the global model's inner loop, used by `shade_prepared`; public
    for tests)."""
    shape = direction.shape
    gathered = jnp.zeros(shape, dtype=direction.dtype)
    throughput = jnp.ones(shape, dtype=direction.dtype)
    white = jnp.ones(3, dtype=direction.dtype)
    relative_ior = jnp.broadcast_to(material.ior, shape[:-1]).astype(direction.dtype)
    for _ in range(interactions):
        exit_point = intersect_unit_sphere(Rays(origin, direction), from_inside=True).point
        inward = -exit_point
        cos_in = jnp.clip(dot(inward, -direction), 0.0, 1.0)
        j, f = _mirror_terms(cos_in)
        r_mirror = specular_peak(material, j)
        z = transmission_weight(material, r_mirror)
        refracted, total = refract(direction, inward, relative_ior)
        outside = background_radiance(background, Rays(exit_point, safe_normalize(refracted)))
        gathered = gathered + throughput * jnp.where(total, 0.0, z)[..., None] * outside
        reflect_weight = r_mirror + jnp.where(total, z, 0.0)
        throughput = throughput * reflect_weight[..., None] * specular_color(material, f, white)
        direction = direction - 2 * dot(direction, inward)[..., None] * inward
        origin = exit_point
    # Whatever is still inside after the last interaction sees the background directly.
    return gathered + throughput * background_radiance(background, Rays(origin, direction))


#: The depths `effective_depth` rounds up to, so that materials of similar
#: transparency share one compiled program (a dataset of many materials compiles a few).
DEPTH_STEPS = (2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64)

#: The ``depth_tolerance`` of ``strauss-fit render``: float32's unit roundoff, the precision
#: of the image files it writes (8-bit files are coarser).
OUTPUT_TOLERANCE = 2.0**-24

#: Estimated compile time (s) from which ``strauss-fit render`` warns (`depth_messages`).
SLOW_COMPILE_S = 10.0

# Sub-intervals of [0, x_c] over which the mirror j is bounded (the bound is tight to
# about 1/_J_INTERVALS of its value).
_J_INTERVALS = 512


def unit_roundoff(dtype: Any) -> float:
    """Half the machine epsilon of a floating-point ``dtype``: 2^-24 for float32, 2^-53 for
    float64 (the largest relative rounding error of one operation)."""
    return float(np.finfo(np.dtype(dtype)).eps) / 2


@functools.lru_cache(maxsize=256)
def _angle_intervals(x_c: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Over each of the sub-intervals [a, b] of [0, x_c]: an upper bound of j = F G²,
    F(b) G(a)², and F at both ends (see `interior_reflectance_bound`)."""
    steps = np.linspace(0.0, x_c, _J_INTERVALS + 1)
    f, g = _fresnel(steps), _shadow(steps)
    return f[1:] * g[:-1] ** 2, f[:-1], f[1:]


def interior_reflectance_bound(material: Material) -> np.ndarray:
    r"""An upper bound of the reflected weight `r_j\,C_s` per interaction inside the
    sphere, per channel (shape (..., 3) for a material with batch axes (...)); concrete
    material values only.

    A ray refracted into a sphere meets its surface at the same angle at every
    interaction, and below the critical angle `\alpha_c = \arcsin(1/n)` (the
    refracted angle from outside, `\sin\alpha_2 = \sin\gamma / n`), so its normalised
    angle is at most `x_c = 2\alpha_c/\pi` (1 for n = 1) and there is no total
    internal reflection. The interval [0, x_c] (plus a margin of 10⁻³ for rounding) is cut
    into 512 pieces [a, b]. F grows and G falls on [0, 1], so on a piece
    `j = F G^2 \le F(b)\,G(a)^2`, and `r_j = \min\{1, r_n + j (r_n + k_j)\}`
    grows with j; `C_s = 1 + m (1 - F)(C - 1)` is linear in F, so at most its larger
    value at F(a) and F(b). The bound is the largest product of the two over the pieces
    (within a few per cent of the true largest weight)."""
    return _reflectance_bound(*_material_values(material))


def _material_values(material: Material) -> tuple[np.ndarray, ...]:
    """t, s, m, C, n as float64 NumPy arrays (a tracer raises TracerArrayConversionError)."""
    fields = (material.transparency, material.smoothness, material.metalness, material.color, material.ior)
    return tuple(np.asarray(v, dtype=np.float64) for v in fields)


def _reflectance_bound(t, s, m, color, ior) -> np.ndarray:
    """`interior_reflectance_bound` from the material's values (batch axes allowed)."""
    batch = np.broadcast_shapes(t.shape, s.shape, m.shape, color.shape[:-1], ior.shape)
    t, s, m, ior = (np.broadcast_to(v, batch) for v in (t, s, m, ior))
    color = np.broadcast_to(color, batch + (3,))
    bound = np.empty(batch + (3,))
    for index in np.ndindex(*batch):
        x_c = min(2.0 / np.pi * float(np.arcsin(1.0 / max(float(ior[index]), 1.0))) + 1e-3, 1.0)
        j_upper, f_lower, f_upper = _angle_intervals(x_c)
        r_n = (1 - t[index]) * s[index] ** 3
        r_upper = np.minimum(1.0, r_n + j_upper * (r_n + K_J))  # (pieces,)
        tint = m[index] * (color[index] - 1)  # C_s = 1 + (1 - F) tint
        c_s = np.maximum(1 + (1 - f_lower)[:, None] * tint, 1 + (1 - f_upper)[:, None] * tint)  # (pieces, 3)
        bound[index] = np.max(r_upper[:, None] * c_s, axis=0)
    return bound


def effective_depth(scene: Scene, material: Material | None = None, *, tolerance: float) -> int:
    r"""The depth beyond which the global model cannot change any pixel by more than
    ``tolerance`` times the background's brightest radiance
    (`background_peak`): at most ``scene.depth``, rounded
    up to one of `DEPTH_STEPS`.

    Only transmitted light recurses (the reflected ray from outside sees the background at
    once), so an opaque material, or a black background, needs ``min(depth, 2)``. Otherwise,
    with `\rho` from `interior_reflectance_bound`: a path has weight at most
    `z\,C \le t\,C` at entry and keeps at most the factor `\rho` per
    interaction, and what depth D and any deeper depth give differ by at most what the
    ray still carries after D − 1 interactions times the background's radiance, since the
    weights that leave (z) and stay (`r_j`) add up to at most 1. So depth D is exact
    to `\max_c t\,C_c\,\rho_c^{D-1} \le` ``tolerance`` (in exact arithmetic; the
    rendering's own rounding comes on top, as at any depth).

    Pure: concrete values only. A traced material or background (inside ``jax.grad`` or a
    fit), or ``tolerance <= 0``, gives ``scene.depth``.
    """
    material = scene.material if material is None else material
    if scene.depth <= 2:
        return scene.depth
    return _effective_depth(scene.depth, material, background_peak(scene.background), tolerance)


def _effective_depth(depth: int, material: Material, peak: float | None, tolerance: float) -> int:
    """`effective_depth` with the background's peak radiance given."""
    if depth <= 2 or peak is None:
        return depth
    try:
        values = _material_values(material)
    except jax.errors.TracerArrayConversionError:
        return depth
    if all(v.ndim == 0 for v in values[:3] + values[4:]) and values[3].shape == (3,):  # one material: cached
        return _depth_for(
            depth, peak == 0, float(tolerance), *(float(v) for v in values[:3]), tuple(values[3]), float(values[4])
        )
    return _depth_from(depth, peak == 0, tolerance, *values)


@functools.lru_cache(maxsize=1024)
def _depth_for(depth, black, tolerance, t, s, m, color, ior) -> int:
    return _depth_from(depth, black, tolerance, *(np.asarray(v, dtype=np.float64) for v in (t, s, m, color, ior)))


def _depth_from(depth: int, black: bool, tolerance: float, t, s, m, color, ior) -> int:
    if not np.any(t > 0) or black:
        return 2  # nothing is transmitted, or nothing to see through the sphere
    if not tolerance > 0:
        return depth
    rho = _reflectance_bound(t, s, m, color, ior)
    bound = np.maximum(t, 0.0)[..., None] * np.abs(color)
    for candidate in range(2, depth):
        bound = bound * rho  # the bound at depth `candidate`: t C rho^(candidate - 1)
        if np.all(bound <= tolerance):
            return min(next(step for step in DEPTH_STEPS if step >= candidate), depth)
    return depth


def estimated_compile_cost(depth: int) -> tuple[float, float]:
    """Rough seconds and GB of memory of a ``strauss-fit render`` of a transparent material
    at ``depth``, almost all of it compiling: the interior interactions are unrolled, so the
    program grows with depth and its compile time faster. Fitted to
    ``glass_checkerboard.toml`` (float64, one x86 core; the image size hardly matters):
    5.0 s and 0.47 GB at depth 4, 6.8 s at 8, 9.6 s and 0.56 GB at 16, 70 s and 2.5 GB
    at 64."""
    return 4.0 + depth * depth / 64.0, 0.45 + depth * depth / 2000.0


def depth_messages(scene: Scene, material: Material | None = None, *, tolerance: float) -> list[str]:
    """One-line notes for a render of ``scene`` with ``depth_tolerance=tolerance``: that the
    depth is reduced (`effective_depth`), and a warning when what remains is slow to
    compile (`estimated_compile_cost` at least `SLOW_COMPILE_S`). Empty when
    nothing is traced beyond depth 2 (an opaque material, a black background)."""
    material = scene.material if material is None else material
    if scene.depth <= 2 or is_traced(material) or not plan_render(scene, material).transmit:
        return []
    if not background_peak(scene.background):
        return []
    depth = effective_depth(scene, material, tolerance=tolerance)
    messages = []
    if depth < scene.depth:
        messages.append(
            f"depth {scene.depth} reduced to {depth}: further interactions inside the sphere change no pixel by "
            f"more than {tolerance:.2g} × the background's brightest radiance"
        )
    seconds, gigabytes = estimated_compile_cost(depth)
    if seconds >= SLOW_COMPILE_S:
        t, s = (np.asarray(v, dtype=np.float64).max() for v in (material.transparency, material.smoothness))
        messages.append(
            f"warning: depth {depth} is needed (transparency {t:g}, smoothness {s:g}: light stays inside the "
            f"sphere for many interactions); rendering takes about {seconds:.0f} s and {gigabytes:.1f} GB "
            f"on one CPU core, mostly compiling; a smaller --depth is faster"
        )
    return messages


def shade_prepared(material: Material, prepared: Prepared, scene: Scene, plan: RenderPlan) -> Array:
    """Add the material to a `Prepared` rendering: the image, (H, W, 3)."""
    radiance = local_radiance(material, prepared)
    white = jnp.ones(3, dtype=radiance.dtype)
    if plan.reflect or plan.transmit:
        r_mirror = specular_peak(material, prepared.mirror_j)
    if plan.reflect:
        c_s = specular_color(material, prepared.mirror_fresnel, white)
        radiance = radiance + r_mirror[..., None] * c_s * prepared.reflected_radiance
    if plan.transmit:
        z = transmission_weight(material, r_mirror)
        relative_ior = jnp.broadcast_to(1.0 / material.ior, z.shape).astype(radiance.dtype)
        inside, _ = refract(prepared.direction, prepared.normal, relative_ior)  # never total from outside
        carried = interior_radiance(material, scene.background, prepared.point, safe_normalize(inside), scene.depth - 1)
        radiance = radiance + z[..., None] * material.color * carried
    return jnp.where(prepared.hit[..., None], radiance, prepared.miss_radiance)


# The last few (lights, background) pairs found in range, with the background's peak
# radiance: render() checks a scene once, not at every call (weak references: an entry
# never outlives its objects, which are immutable).
_CHECKED: list[tuple[weakref.ref, weakref.ref, float | None]] = []


def _checked_background_peak(scene: Scene) -> float | None:
    """`check_radiance_range` of ``scene`` and the peak
    radiance of its background, remembered for the last 8 (lights, background) pairs."""
    for lights, background, peak in _CHECKED:
        if lights() is scene.lights and background() is scene.background:
            return peak
    check_radiance_range(scene)
    peak = background_peak(scene.background)
    if not is_traced((scene.lights, scene.background)):
        _CHECKED.insert(0, (weakref.ref(scene.lights), weakref.ref(scene.background), peak))
        del _CHECKED[8:]
    return peak


@eqx.filter_jit
def render_jit(scene: Scene, material: Material, plan: RenderPlan, mode: str, table_size: int, dtype: Any):
    """The jitted core of `render` (all arguments resolved). Internal API, public for
    compile-time measurements (``render_jit.lower(...)``); call it inside
    `strauss_fit.precision.float64`."""
    scene = scene.astype(dtype)  # inside the jit: eager casts cost more than a small render
    material = material.astype(dtype)
    prepared = prepare(scene, plan, mode, table_size, dtype)
    return shade_prepared(material, prepared, scene, plan), prepared.hit


@uses_float64
def render(
    scene: Scene,
    material: Material | None = None,
    *,
    mode: Mode = "exact",
    table_size: int = DEFAULT_TABLE_SIZE,
    dtype: Any = None,
    plan: RenderPlan | None = None,
    depth_tolerance: float | None = None,
) -> tuple[Array, Array]:
    """Render the sphere: a linear RGB image (height, width, 3) and the sphere mask.

    ``material`` defaults to the scene file's. ``dtype`` (``jnp.float32`` or
    ``jnp.float64``; default float64) sets the precision of the whole computation.
    Differentiable in the material and in the light intensities (``scene.lights``).
    ``plan`` overrides `plan_render` (transmission is never traced for a material
    that is concretely opaque, t = 0, whatever the plan says). ``mode`` and ``table_size`` select the
    evaluator (see `strauss_fit.models.strauss.shade`).

    The global model is traced to `effective_depth` (at most ``scene.depth``): the
    interactions beyond it change no pixel by more than ``depth_tolerance`` times the
    background's brightest radiance. ``depth_tolerance`` defaults to the unit roundoff of
    ``dtype`` (2^-53 for float64, 2^-24 for float32); 0 traces the full ``scene.depth``.
    With a traced material or background (inside ``jax.grad``) the full depth is traced.

    A scene outside the renderer's range (a light or background brighter than
    `strauss_fit.scene.loading.MAX_RADIANCE`, see
    `strauss_fit.scene.loading.check_radiance_range`) raises a
    `RadianceRangeError` before any work.

    Examples:
        >>> import strauss_fit as sf
        >>> scene = sf.load_scene("data_synth/scenes/key_and_fill.toml")  # 40 x 40 pixels
        >>> image, mask = sf.render(scene, sf.Material(color=(0.8, 0.2, 0.1), smoothness=0.6))
        >>> image.shape, int(mask.sum())  # the sphere covers 1264 of the 1600 pixels
        ((40, 40, 3), 1264)
    """
    peak = _checked_background_peak(scene)
    material = scene.material if material is None else material
    dtype = jnp.dtype(dtype or jnp.float64)
    plan = plan or plan_render(scene, material)
    if plan.transmit and _is_zero(material.transparency):
        # a plan made without the material (plan_render(scene)) traces transmission in case
        # it is transparent; an opaque one transmits nothing: the same image at half the cost
        plan = plan._replace(transmit=False)
    if plan.transmit and scene.depth > 2:  # otherwise the depth changes nothing
        tolerance = unit_roundoff(dtype) if depth_tolerance is None else float(depth_tolerance)
        depth = _effective_depth(scene.depth, material, peak, tolerance)
        if depth != scene.depth:
            scene = dataclasses.replace(scene, depth=depth)
    return render_jit(scene, material, plan, mode, int(table_size), dtype)
