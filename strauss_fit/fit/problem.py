r"""A fit's problem: the prepared scene at the usable pixels, the target, and the residual.

The fit minimises :math:`\tfrac12\sum_p \lVert I_\text{model}(p;\theta) - I_\text{target}(p)\rVert^2`
over the usable sphere pixels p (linear RGB), with θ the unconstrained parameters of
:mod:`strauss_fit.fit.parameters`.

Speed: everything that does not depend on the material (pixel geometry, the angular terms
F, G and j of every light, backgrounds seen along mirror directions) is computed once
(:func:`strauss_fit.render.strauss.prepare`, with every light at unit intensity) and
restricted to the usable pixels (:func:`build_problem`); the solver then evaluates only
the material-dependent part, with the intensities applied (:func:`scaled`). On a large
image the starts run on an evenly strided subsample (:func:`coarse_problem`).

The jitted helpers here (:func:`costs`, :func:`render_at`, :func:`to_physical`, ...) are
internal API shared by the fit's modules, the conversions and the study: compiled once per
problem structure, called inside :func:`strauss_fit.precision.float64`.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..engine import Kernel, Steps, run
from ..errors import StraussFitError
from ..io.targets import Target
from ..models.material import Material
from ..precision import uses_float64
from ..render.coverage import fully_covered
from ..render.strauss import Prepared, RenderPlan, prepare, shade_prepared, take_pixels
from ..scene.lights import Lights
from ..scene.loading import Scene
from .parameters import Layout, intensity_vector, lights_with, material_with

if TYPE_CHECKING:
    from .options import FitOptions

#: Above twice this many usable pixels, the starts run on an evenly strided subsample of
#: about this size and only the best start is continued on every pixel
#: (:func:`strauss_fit.fit.solvers.solve`).
COARSE_PIXELS = 8192


class Problem(eqx.Module):
    """A fit's data: prepared (material-independent) terms at the usable pixels, the
    target there, the scene, the material and lights that held parameters come from."""

    prepared: Prepared
    target: Array
    scene: Scene
    material: Material
    lights: Lights
    pinned: Array
    pinned_values: Array
    residual_scale: Array
    layout: Layout = eqx.field(static=True)
    plan: RenderPlan = eqx.field(static=True)
    #: How residuals enter the cost (:data:`LOSSES`); "linear" is plain least squares.
    loss: str = eqx.field(static=True, default="linear")
    #: Per value (N, 3): the reference noise over each value's own noise level, for the
    #: robust losses (which act on noise-scaled residuals); None = the reference noise.
    weights: Array | None = None
    #: The perceptual loss's offset ε and slope normalisation (see :func:`loss_residual`).
    loss_offset: Array | None = None
    loss_norm: Array | None = None
    #: The global exposure (one scale on all rendered radiance) when it is held; None = 1.
    exposure: Array | None = None

    def physical(self, theta: Array) -> Array:
        """Physical values of θ, with pinned entries (at a bound, see
        :func:`strauss_fit.fit.solvers.polish`) replaced."""
        return jnp.where(self.pinned, self.pinned_values, self.layout.to_physical(theta))

    def pin(self, mask: np.ndarray, values: np.ndarray) -> Problem:
        return dataclasses.replace(self, pinned=jnp.asarray(mask), pinned_values=jnp.asarray(values))

    def render_physical(self, x: Array) -> Array:
        """Model radiance (N, 3) at the usable pixels for physical parameters ``x``."""
        values = self.layout.split(x)
        material = material_with(self.material, values)
        prepared = scaled(self.prepared, lights_with(self.lights, values))
        radiance = shade_prepared(material, prepared, self.scene, self.plan)
        exposure = values.get(EXPOSURE, self.exposure)
        return radiance if exposure is None else radiance * exposure

    def residual_physical(self, x: Array) -> Array:
        """Model minus target at the usable pixels, flattened (N·3,): what χ² is made of."""
        return (self.render_physical(x) - self.target).ravel()

    def objective_residual(self, x: Array) -> Array:
        """The residuals the solver minimises the squares of, at physical ``x``: the
        :attr:`loss` applied to model minus target, divided by ``residual_scale`` (the
        reference noise times sqrt(N)), so that tolerances do not depend on image size or
        brightness. For the linear loss, :meth:`residual_physical` / ``residual_scale``."""
        if self.loss == "linear":
            return self.residual_physical(x) / self.residual_scale
        return loss_residual(self, self.render_physical(x)).ravel() / self.residual_scale

    def residual(self, theta: Array, _args: Any = None) -> Array:
        """:meth:`objective_residual` at the unconstrained θ (what optimistix calls)."""
        return self.objective_residual(self.physical(theta))


#: The global exposure's parameter name: one scale on all rendered radiance (every light
#: and the background together), the usual unknown of a photograph or a foreign render.
EXPOSURE = "exposure"

#: The losses a fit can minimise (:func:`loss_residual`).
LOSSES = ("linear", "perceptual", "huber", "cauchy")
#: Huber's and Cauchy's tuning constants on the noise-scaled residual z (95 % efficiency
#: at Gaussian noise).
HUBER_K = 1.345
CAUCHY_C = 2.385
#: Below this |z| the Cauchy transform is replaced by its limit z (its square root has an
#: infinite slope at 0 that the chain rule would multiply by 0).
_CAUCHY_SMALL = 1e-6


def loss_residual(problem: Problem, model: Array) -> Array:
    r"""Loss-transformed residuals (N, 3), in units of the reference noise σ_ref, whose
    squares sum to the cost (times ``residual_scale``², as for the linear loss).

    - ``perceptual``: :math:`(f(I) - f(T))/f'(L)` with :math:`f(x) = \sqrt[3]{x + ε}`,
      the cube root of CIELAB's lightness, so that differences in dark regions count as
      the eye sees them rather than by their linear size; ε = ``loss_offset`` (a
      thousandth of the target's 98th percentile L, which keeps the slope finite at 0)
      and f'(L) = ``loss_norm``, so that a bright pixel's residual is about its linear one.
    - ``huber`` / ``cauchy``: on the noise-scaled residual :math:`z = (I - T)/σ` (σ each
      value's own noise: ``weights`` = σ_ref/σ), the value :math:`ψ(z)σ_{ref}` with
      :math:`ψ(z)^2/2 = ρ(z)`: Huber's ρ (quadratic up to |z| = 1.345, then linear) or
      Cauchy's :math:`ρ = (c^2/2)\log(1 + (z/c)^2)`, c = 2.385. The few values the model
      cannot reproduce (a highlight's core, an edge) then weigh less than their squares,
      while values within the noise weigh as in least squares.
    """
    difference = model - problem.target
    if problem.loss == "perceptual":
        offset, norm = problem.loss_offset, problem.loss_norm
        return (jnp.cbrt(model + offset) - jnp.cbrt(problem.target + offset)) / norm
    weights = 1.0 if problem.weights is None else problem.weights
    reference = problem.residual_scale / jnp.sqrt(problem.target.size)  # σ_ref
    z = difference * weights / reference
    if problem.loss == "huber":
        large = jnp.abs(z) > HUBER_K
        safe = jnp.where(large, jnp.abs(z), HUBER_K)
        psi = jnp.where(large, jnp.sign(z) * jnp.sqrt(2 * HUBER_K * safe - HUBER_K**2), z)
    else:  # cauchy
        small = jnp.abs(z) < _CAUCHY_SMALL
        safe = jnp.where(small, 1.0, z)
        psi = jnp.where(small, z, jnp.sign(safe) * CAUCHY_C * jnp.sqrt(jnp.log1p((safe / CAUCHY_C) ** 2)))
    return psi * reference


def scaled(prepared: Prepared, lights: Lights) -> Prepared:
    """A unit-intensity :class:`~strauss_fit.render.strauss.Prepared` with the lights'
    intensities applied."""
    changes = {}
    if prepared.irradiance is not None:
        changes["irradiance"] = prepared.irradiance * intensity_vector(lights)
    if lights.ambient is not None:
        changes["ambient"] = lights.ambient
    return dataclasses.replace(prepared, **changes)


def unit_intensity_scene(scene: Scene) -> Scene:
    """The scene with every light's intensity 1, so that prepared irradiance holds only
    the geometric attenuation and intensities can be applied (or fitted) later."""
    ones = {k: jnp.ones_like(v) for k, v in scene.lights.intensities().items()}
    return eqx.tree_at(lambda s: s.lights, scene, scene.lights.with_intensities(ones))


# Compiled once per structure (run eagerly, these would dispatch dozens of small XLA
# programs); :class:`~strauss_fit.engine.Kernel` also runs them over a batch of targets.
def _prepare_float64(scene: Scene, plan: RenderPlan, mode: str, table_size: int) -> Prepared:
    return prepare(scene, plan, mode, table_size, jnp.float64)


#: :func:`strauss_fit.render.strauss.prepare` in float64.
prepare_float64 = Kernel(_prepare_float64, "prepare")
#: :func:`strauss_fit.render.strauss.take_pixels`.
take_pixels_jit = Kernel(take_pixels, "take_pixels")


def _shade_full(material: Material, prepared: Prepared, lights: Lights, scene: Scene, plan: RenderPlan) -> Array:
    return shade_prepared(material, scaled(prepared, lights), scene, plan)


#: The whole image of a unit-intensity prepared scene for a material and lights.
shade_full = Kernel(_shade_full, "shade_full")


def _to_physical(layout: Layout, theta: Array) -> Array:
    return layout.to_physical(theta)


#: ``layout.to_physical``.
to_physical = Kernel(_to_physical, "to_physical")


def _render_at(problem: Any, x: Array) -> Array:
    return problem.render_physical(x)


#: A problem's model radiance (N, 3) at physical parameters ``x`` (any problem with
#: ``render_physical``, a Phong one too).
render_at = Kernel(_render_at, "render_at")


def _costs(problem: Problem, xs: Array) -> Array:
    return jax.vmap(lambda x: jnp.sum(problem.objective_residual(x) ** 2))(xs)


#: The normalised cost Σ(r/scale)² at each row of physical points ``xs`` (K, P).
costs = Kernel(_costs, "costs")


def physical_values(problem: Problem, theta: np.ndarray) -> np.ndarray:
    """:meth:`Problem.physical` in NumPy (no JAX dispatch): the physical values of θ with the
    pinned entries replaced."""
    return np.where(
        np.asarray(problem.pinned), np.asarray(problem.pinned_values), problem.layout.to_physical_numpy(theta)
    )


def geometry_key(scene: Scene, plan: RenderPlan, options: FitOptions) -> tuple:
    """What a prepared scene depends on, as a hashable key: the camera, the background,
    the lights and depth (values, not object identity: every fit builds its own scene
    object), the render plan and the evaluator — so that the targets of one scene share
    one preparation (:func:`build_problem_steps`)."""
    leaves, treedef = jax.tree.flatten((scene.camera, scene.background, scene.lights, scene.depth))
    return (
        "geometry",
        str(treedef),
        tuple(np.asarray(leaf).tobytes() + str(np.asarray(leaf).dtype).encode() for leaf in leaves),
        plan,
        options.mode,
        options.table_size,
    )


@uses_float64
def build_problem(
    scene: Scene,
    target: Target,
    names: list[str],
    material: Material,
    plan: RenderPlan,
    options: FitOptions,
    reference_noise: float = 1.0,
    cache: dict | None = None,
    *,
    loss: str = "linear",
    noise_sigma: np.ndarray | None = None,
    exposure: float | None = None,
) -> tuple[Problem, Prepared, np.ndarray]:
    """The :class:`Problem` for the free ``names``, the full prepared image and the
    flat indices of the pixels used (:func:`build_problem_steps`, run directly)."""
    return run(
        build_problem_steps(
            scene,
            target,
            names,
            material,
            plan,
            options,
            reference_noise,
            cache,
            loss=loss,
            noise_sigma=noise_sigma,
            exposure=exposure,
        )
    )


def build_problem_steps(
    scene: Scene,
    target: Target,
    names: list[str],
    material: Material,
    plan: RenderPlan,
    options: FitOptions,
    reference_noise: float = 1.0,
    cache: dict | None = None,
    *,
    loss: str = "linear",
    noise_sigma: np.ndarray | None = None,
    exposure: float | None = None,
) -> Steps:
    """:func:`build_problem` as steps (:mod:`strauss_fit.engine`).

    Of ``options`` only ``mode``, ``table_size`` and ``edge_pixels`` matter. ``cache`` (a
    dict) keeps the prepared scene per :func:`geometry_key` — preparing depends only on the
    camera, the background, where the lights are and the plan, not on the material or the
    lights' intensities, so every problem of a fit, and every target of a scene in
    :func:`strauss_fit.fit_many`, shares it — and the target's pixels per render plan.
    ``loss`` (:data:`LOSSES`), ``noise_sigma`` (the noise level of every value of the
    image, (H, W, 3), for the robust losses) and ``exposure`` (a held global exposure
    other than 1) shape the residual."""
    cache = {} if cache is None else cache
    geometry = geometry_key(scene, plan, options)
    if geometry not in cache:
        cache[geometry] = yield prepare_float64.call(
            unit_intensity_scene(scene), plan, options.mode, options.table_size
        )
    prepared_full = cache[geometry]
    key = ("pixels", id(target), geometry, options.edge_pixels)
    if key in cache:
        _, index, prepared, pixels = cache[key]
    else:
        used = used_pixels(scene, target, np.asarray(prepared_full.hit), options.edge_pixels)
        if not used.any():
            raise StraussFitError(
                f"target {target.path} has no usable sphere pixels (all masked, clipped or outside the sphere"
                + (", or on the silhouette" if options.edge_pixels == "exclude" else "")
                + ")"
            )
        index = np.flatnonzero(used.ravel())
        pixels = np.asarray(target.pixels, dtype=np.float64).reshape(-1, 3)[index]
        if float(np.max(pixels)) <= 0:
            raise StraussFitError(f"target {target.path} is black on every usable sphere pixel: nothing to fit")
        prepared = yield take_pixels_jit.call(prepared_full, index)
        cache[key] = target, index, prepared, pixels  # the target is kept: its id stays its own
    extra: dict[str, Any] = {}
    if loss != "linear":
        if loss not in LOSSES:
            raise StraussFitError(f"unknown loss {loss!r}; expected one of {', '.join(LOSSES)}")
        extra["loss"] = loss
        if loss == "perceptual":
            level = max(float(np.percentile(pixels, 98)), 1e-12)
            offset = PERCEPTUAL_OFFSET * level
            extra["loss_offset"] = np.asarray(offset)
            extra["loss_norm"] = np.asarray((level + offset) ** (-2.0 / 3.0) / 3.0)
        elif noise_sigma is not None:
            sigma = np.asarray(noise_sigma, dtype=np.float64).reshape(-1, 3)[index]
            extra["weights"] = reference_noise / np.maximum(sigma, 1e-300)
    if exposure is not None and float(exposure) != 1.0:
        extra["exposure"] = np.asarray(float(exposure))
    layout = Layout(tuple(names))
    problem = Problem(
        prepared=prepared,
        target=pixels,
        scene=scene,
        material=material.astype(jnp.float64),
        lights=scene.lights,
        pinned=np.zeros(layout.size, dtype=bool),
        pinned_values=np.zeros(layout.size),
        residual_scale=np.asarray(reference_noise * np.sqrt(pixels.size)),
        layout=layout,
        plan=plan,
        **extra,
    )
    return problem, prepared_full, index


def used_pixels(scene: Scene, target: Target, hit: np.ndarray, edge_pixels: str = "exclude") -> np.ndarray:
    """(H, W) bool: the pixels a fit uses — on the sphere (``hit``: the ray through the
    centre hits it), usable in ``target`` (not masked out or clipped) and, with
    ``edge_pixels="exclude"``, wholly covered by the sphere
    (:func:`strauss_fit.render.coverage.fully_covered`)."""
    used = np.asarray(hit) & target.usable
    if edge_pixels == "exclude":
        used &= fully_covered(scene.camera)
    return used


#: The perceptual loss's offset ε as a fraction of the target's 98th percentile: small
#: enough not to flatten dark regions (CIELAB's own linear toe is at 0.9 % of white), large
#: enough that the cube root's slope stays finite at black.
PERCEPTUAL_OFFSET = 1e-3


def coarse_problem(problem: Problem, prepared_full: Prepared, index: np.ndarray) -> Problem | None:
    """:func:`coarse_problem_steps`, run directly."""
    return run(coarse_problem_steps(problem, prepared_full, index))


def coarse_problem_steps(problem: Problem, prepared_full: Prepared, index: np.ndarray) -> Steps:
    """``problem`` restricted to every k-th of its pixels (k = N // :data:`COARSE_PIXELS`),
    or None when it is small enough. The residual scale shrinks with the pixel count, so
    costs (χ² per value at the reference noise) stay comparable."""
    stride = index.size // COARSE_PIXELS
    if stride < 2:
        return None
    subset = np.arange(0, index.size, stride)
    prepared = yield take_pixels_jit.call(prepared_full, index[subset])
    return dataclasses.replace(
        problem,
        prepared=prepared,
        target=problem.target[subset],
        residual_scale=problem.residual_scale * np.sqrt(subset.size / index.size),
        weights=None if problem.weights is None else problem.weights[subset],
    )
