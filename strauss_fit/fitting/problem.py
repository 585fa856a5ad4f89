r"""A fit's problem: the prepared scene at the usable pixels, the target, and the residual.

The fit minimises `\tfrac12\sum_p \lVert I_\text{model}(p;\theta) - I_\text{target}(p)\rVert^2`
over the usable sphere pixels p (linear RGB), with θ the unconstrained parameters of
`strauss_fit.fitting.parameters`.

Speed: everything that does not depend on the material (pixel geometry, the angular terms
F, G and j of every light, backgrounds seen along mirror directions) is computed once
(`strauss_fit.rendering.strauss.prepare`, with every light at unit intensity) and
restricted to the usable pixels (`build_problem`); the solver then evaluates only
the material-dependent part, with the intensities applied (`scaled`). On a large
image the starts run on an evenly strided subsample (`coarse_problem`).

Compiled once for many images: a fit's pixel set is padded (``pad=True``, what
`strauss_fit.fit` does) to one of a few bucketed sizes (`pixel_bucket`, at
most about 19 % more pixels), the padding weighted 0 (`Problem.valid`). Targets of one
scene whose usable pixels differ in number — clipped highlights in 8-bit images, masks,
silhouettes — then share the compiled solvers instead of compiling them for every count;
the padding changes no residual, cost, Jacobian row or statistic
(`Problem.value_count` and `Problem.real` give the real ones).

The jitted helpers here (`costs`, `render_at`, `to_physical`, ...) are
internal API shared by the fit's modules, the conversions and the study: compiled once per
problem structure, called inside `strauss_fit.precision.float64`.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from .._host_methods import host_method
from ..engine import Kernel, Steps, run
from ..errors import StraussFitError
from ..io.targets import Target
from ..models.material import Material
from ..numerics import ones_like
from ..precision import uses_float64
from ..rendering.coverage import fully_covered, pixel_coverage, silhouette_blend
from ..rendering.strauss import Prepared, RenderPlan, first_pixels, prepare, shade_prepared, take_pixels
from ..scene.lights import Lights
from ..scene.loading import Scene
from .losses import FOLDED_LOSSES as FOLDED_LOSSES  # re-exported: other modules import the names from here
from .losses import LEAST_SQUARES, LOSS_REGISTRY, loss_named
from .losses import LOSSES as LOSSES
from .losses import ROBUST_LOSSES as ROBUST_LOSSES
from .parameters import Layout, intensity_vector, lights_with, material_with

if TYPE_CHECKING:
    from .options import FitOptions

#: Above twice this many usable pixels, the starts run on an evenly strided subsample of
#: about this size and only the best start is continued on every pixel
#: (`strauss_fit.fitting.solvers.solve`).
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
    #: How residuals enter the cost (`LOSSES`); "linear" is plain least squares. In
    #: a kernel (`kernel_form`) one of `FOLDED_LOSSES` is `LOSS_BY_CODE`.
    loss: str = eqx.field(static=True, default="linear")
    #: Per value (N, 3): the reference noise over each value's own noise level, for the
    #: robust losses (which act on noise-scaled residuals); None = the reference noise.
    weights: Array | None = None
    #: The perceptual loss's offset ε and slope normalisation (see `loss_residual`).
    loss_offset: Array | None = None
    loss_norm: Array | None = None
    #: The global exposure (one scale on all rendered radiance) when it is held; None = 1.
    exposure: Array | None = None
    #: A padded pixel set (`pixel_bucket`): (N,) 1 for the real pixels, which come
    #: first, 0 for the padding; None = every pixel is real.
    valid: Array | None = None
    #: The number of real pixels when padded (a 0-d array, so that it stays dynamic under
    #: ``jit`` and every count shares one compilation); None = every pixel is real.
    count: Array | None = None
    #: In a kernel form (`kernel_form`): which of `FOLDED_LOSSES` (its index, a
    #: 0-d array, dynamic); None otherwise.
    loss_code: Array | None = None

    @host_method
    def kernel_form(self) -> Problem:
        """This problem as a compiled kernel takes it (`strauss_fit.engine` asks every
        argument for it): the same residuals, with the loss as data rather than structure
        when it is one of `FOLDED_LOSSES` — ``loss`` `LOSS_BY_CODE`, the loss's
        index in ``loss_code`` and ``weights`` always an array (ones for the linear loss,
        whose residuals do not read them). Why: a static loss is part of the program, so
        each loss compiled every solver, Jacobian and render of a problem anew (a
        mismatched batch, linear then Huber, compiled 17 programs where a consistent one
        compiled 11: 13 s of a 46 s cold batch); as data, least squares, Huber and Cauchy
        share one program per problem shape, whose residuals are those of each loss's own
        (`loss_residual` runs the branch of the one ``loss_code`` names) up to the
        compiler's rounding in another program (each residual to 1e-15 relative,
        ``tests/test_registries.py``): with the select of 2026-12-03 fits moved by at most
        8e-16 in their parameters, with the same steps, verdicts and losses (16 fits); with
        the switch of 2026-12-04 the README's fit prints the same table and the reviewed
        fits' ± moved by about 1e-12 relative."""
        if self.loss not in FOLDED_LOSSES:
            return self
        weights = self.weights if self.weights is not None else _ones(np.shape(self.target))
        changes = dict(loss=LOSS_BY_CODE, loss_code=_LOSS_CODES[self.loss], weights=weights)
        fields = getattr(self, "__dict__", None)
        if fields is None:  # not a plain instance (equinox's layout changed): the slow way
            return dataclasses.replace(self, **changes)
        # A copy with three fields changed, as equinox's own unflattening builds a module:
        # dataclasses.replace would run the module's __init__ again (0.2-0.9 ms, once per
        # kernel call, against 20 µs), for values that are valid by construction.
        form = object.__new__(type(self))
        form.__dict__.update(fields, **changes)
        return form

    @host_method
    def value_count(self) -> int:
        """The number of real residual values (3 per real pixel), on the host."""
        return int(self.target.size if self.count is None else 3 * int(self.count))

    @host_method
    def real(self, per_pixel: Any) -> np.ndarray:
        """A per-pixel host array (N, ...) of this problem without its padding."""
        array = np.asarray(per_pixel)
        return array if self.count is None else array[: int(self.count)]

    @host_method
    def unpadded(self) -> Problem:
        """This problem on its real pixels only (itself when not padded): for code that
        evaluates one target at a time, such as the sampler, where padding buys nothing."""
        if self.count is None:
            return self
        count = int(self.count)
        return dataclasses.replace(
            self,
            prepared=first_pixels(self.prepared, count),
            target=np.asarray(self.target)[:count],
            weights=None if self.weights is None else np.asarray(self.weights)[:count],
            valid=None,
            count=None,
        )

    def _masked(self, per_pixel: Array) -> Array:
        return per_pixel if self.valid is None else per_pixel * self.valid[:, None]

    def physical(self, theta: Array) -> Array:
        """Physical values of θ, with pinned entries (at a bound, see
        `strauss_fit.fitting.solvers.polish`) replaced."""
        return jnp.where(self.pinned, self.pinned_values, self.layout.to_physical(theta))

    @host_method
    def pin(self, mask: np.ndarray, values: np.ndarray) -> Problem:
        # NumPy, as build_problem's: jnp.asarray would dispatch a device copy for each,
        # which on a busy device waits behind the compiled work (a conversion ran ~4 per
        # material); a kernel takes them as arrays all the same
        return dataclasses.replace(
            self, pinned=np.asarray(mask, dtype=bool), pinned_values=np.asarray(values, dtype=np.float64)
        )

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
        return self._masked(self.render_physical(x) - self.target).ravel()

    def objective_residual(self, x: Array) -> Array:
        """The residuals the solver minimises the squares of, at physical ``x``: the
        `loss` applied to model minus target, divided by ``residual_scale`` (the
        reference noise times sqrt(N)), so that tolerances do not depend on image size or
        brightness. For the linear loss, `residual_physical` / ``residual_scale``."""
        return self.objective_of_model(self.render_physical(x), self.target)

    def objective_of_model(self, model: Array, target: Array) -> Array:
        """The residuals of `objective_residual` as a function of the model radiance
        ``model`` (N, 3) and the ``target`` (N, 3), flattened (N·3,). Each residual depends on
        its own model value and target value alone (the loss, the padding's weight and the
        scale act value by value), which lets the noise sandwich take their derivatives
        value by value (`strauss_fit.stats.laplace.objective_terms`)."""
        if self.loss == LEAST_SQUARES:
            return self._masked(model - target).ravel() / self.residual_scale
        return self._masked(loss_residual(self, model, target)).ravel() / self.residual_scale

    def residual(self, theta: Array, _args: Any = None) -> Array:
        """`objective_residual` at the unconstrained θ (what optimistix calls)."""
        return self.objective_residual(self.physical(theta))


#: The global exposure's parameter name: one scale on all rendered radiance (every light
#: and the background together), the usual unknown of a photograph or a foreign render.
EXPOSURE = "exposure"

# The losses themselves (their names, which are robust, which fold into the kernel) are plain
# data in `strauss_fit.fitting.losses`, whose LOSSES, ROBUST_LOSSES and FOLDED_LOSSES are
# imported above and stay importable from here; how each loss computes is LOSS_RESIDUALS below.

#: A kernel form's ``loss``: one of `FOLDED_LOSSES`, the one ``loss_code`` names
#: ("linear, huber or cauchy, by loss_code"). A static field, so part of the compiled
#: program's key: one string for every folded loss.
LOSS_BY_CODE = f"{', '.join(FOLDED_LOSSES[:-1])} or {FOLDED_LOSSES[-1]}, by loss_code"
#: Each folded loss's code, one array each (the same object for every problem: a batch of
#: them passes it once, see `strauss_fit.engine._stack_items`).
_LOSS_CODES = {name: np.asarray(LOSS_REGISTRY[name].code, dtype=np.int32) for name in FOLDED_LOSSES}


@functools.lru_cache(maxsize=16)
def _ones(shape: tuple[int, ...]) -> np.ndarray:
    """Read-only ones of ``shape``, one array per shape (a linear problem's kernel form's
    weights: the same object for every problem of that shape)."""
    ones = np.ones(shape)
    ones.flags.writeable = False
    return ones


#: Huber's and Cauchy's tuning constants on the noise-scaled residual z (95 % efficiency
#: at Gaussian noise).
HUBER_K = 1.345
CAUCHY_C = 2.385
#: Below this |z| the Cauchy transform is replaced by its limit z (its square root has an
#: infinite slope at 0 that the chain rule would multiply by 0).
_CAUCHY_SMALL = 1e-6


def loss_residual(problem: Problem, model: Array, target: Array | None = None) -> Array:
    r"""Loss-transformed residuals (N, 3), in units of the reference noise σ_ref, whose
    squares sum to the cost (times ``residual_scale``², as for the linear loss).

    - ``linear``: model minus target.
    - ``perceptual``: `(f(I) - f(T))/f'(L)` with `f(x) = \sqrt[3]{x + ε}`,
      the cube root of CIELAB's lightness, so that differences in dark regions count as
      the eye sees them rather than by their linear size; ε = ``loss_offset`` (a
      thousandth of the target's 98th percentile L, which keeps the slope finite at 0)
      and f'(L) = ``loss_norm``, so that a bright pixel's residual is about its linear one.
    - ``huber`` / ``cauchy``: on the noise-scaled residual `z = (I - T)/σ` (σ each
      value's own noise: ``weights`` = σ_ref/σ), the value `ψ(z)σ_{ref}` with
      `ψ(z)^2/2 = ρ(z)`: Huber's ρ (quadratic up to |z| = 1.345, then linear) or
      Cauchy's `ρ = (c^2/2)\log(1 + (z/c)^2)`, c = 2.385. The few values the model
      cannot reproduce (a highlight's core, an edge) then weigh less than their squares,
      while values within the noise weigh as in least squares.

    A kernel form's problem (`Problem.kernel_form`) computes the values of the loss its
    ``loss_code`` names (`_folded_residual`). ``target``: the values
    compared with (default the problem's own).
    """
    target = problem.target if target is None else target
    if problem.loss == LOSS_BY_CODE:
        return _folded_residual(problem, model, target)
    return LOSS_RESIDUALS[problem.loss](problem, model, target)


def _least_squares_residual(problem: Problem, model: Array, target: Array) -> Array:
    """The linear loss's residual: model minus target."""
    return model - target


def _perceptual_residual(problem: Problem, model: Array, target: Array) -> Array:
    """The perceptual loss's residual: cube roots' difference over f'(L) (`loss_residual`)."""
    offset, norm = problem.loss_offset, problem.loss_norm
    return (jnp.cbrt(model + offset) - jnp.cbrt(target + offset)) / norm


def _noise_scaled(problem: Problem, difference: Array) -> tuple[Array, Array]:
    """The noise-scaled residual z = (I − T)/σ of a robust loss and σ_ref, the unit its ψ(z)
    is returned in (`loss_residual`)."""
    weights = 1.0 if problem.weights is None else problem.weights
    values = problem.target.size if problem.count is None else 3 * problem.count
    reference = problem.residual_scale / jnp.sqrt(values)  # σ_ref
    return difference * weights / reference, reference


def _robust_residual(psi: Callable[[Array], Array]) -> Callable[[Problem, Array, Array], Array]:
    """A robust loss's residual function: ψ of the noise-scaled residual, times σ_ref."""

    def residual(problem: Problem, model: Array, target: Array) -> Array:
        z, reference = _noise_scaled(problem, model - target)
        return psi(z) * reference

    return residual


def _folded_residual(problem: Problem, model: Array, target: Array) -> Array:
    """A kernel form's residual (`LOSS_BY_CODE`): the residual of the loss ``loss_code``
    names, computed by that loss's own residual function (`LOSS_RESIDUALS`) alone, as one
    branch of a ``lax.switch``. The folded losses are least squares and robust ones
    (``tests/test_registries.py`` holds it).

    Why a switch rather than every candidate and a select: a select computes and, in the
    Jacobian, differentiates every loss's ψ on every value — a least-squares residual and
    its Jacobian cost 3-5 times the render's at 256² (1.6 and 6.3 ms against 0.56 and
    1.2 ms). A switch whose index is one number for the whole call runs one branch; where
    the index differs between the items of a batch (``vmap`` over problems of several
    losses) JAX turns it into that select again."""
    branches = [functools.partial(LOSS_RESIDUALS[name], problem, model, target) for name in FOLDED_LOSSES]
    code = problem.loss_code
    index = sum(jnp.where(code == LOSS_REGISTRY[name].code, i, 0) for i, name in enumerate(FOLDED_LOSSES))
    return jax.lax.switch(index, branches)


def _huber_psi(z: Array) -> Array:
    """Huber's ψ(z) with ψ²/2 = ρ (see `loss_residual`)."""
    large = jnp.abs(z) > HUBER_K
    safe = jnp.where(large, jnp.abs(z), HUBER_K)
    return jnp.where(large, jnp.sign(z) * jnp.sqrt(2 * HUBER_K * safe - HUBER_K**2), z)


def _cauchy_psi(z: Array) -> Array:
    """Cauchy's ψ(z) with ψ²/2 = ρ (see `loss_residual`)."""
    small = jnp.abs(z) < _CAUCHY_SMALL
    safe = jnp.where(small, 1.0, z)
    return jnp.where(small, z, jnp.sign(safe) * CAUCHY_C * jnp.sqrt(jnp.log1p((safe / CAUCHY_C) ** 2)))


#: The robust losses' ψ on the noise-scaled residual z (ψ²/2 = ρ), by name.
ROBUST_PSI: dict[str, Callable[[Array], Array]] = {"huber": _huber_psi, "cauchy": _cauchy_psi}

#: How each loss of `strauss_fit.fitting.losses.LOSS_REGISTRY` transforms the residuals,
#: keyed by the same names (``tests/test_registries.py`` checks that the two agree): a
#: function of the problem, the model radiance and the target, (N, 3) each, returning the
#: residuals in units of the reference noise (`loss_residual`).
LOSS_RESIDUALS: dict[str, Callable[[Problem, Array, Array], Array]] = {
    LEAST_SQUARES: _least_squares_residual,
    "perceptual": _perceptual_residual,
    **{name: _robust_residual(psi) for name, psi in ROBUST_PSI.items()},
}


def _perceptual_fields(pixels: np.ndarray) -> dict[str, np.ndarray]:
    """The perceptual loss's `Problem` fields for a target's usable ``pixels``: its
    offset ε and slope normalisation f'(L) (`loss_residual`)."""
    level = max(float(np.percentile(pixels, 98)), 1e-12)
    offset = PERCEPTUAL_OFFSET * level
    return {"loss_offset": np.asarray(offset), "loss_norm": np.asarray((level + offset) ** (-2.0 / 3.0) / 3.0)}


def scaled(prepared: Prepared, lights: Lights) -> Prepared:
    """A unit-intensity `Prepared` with the lights'
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
    ones = {k: ones_like(v) for k, v in scene.lights.intensities().items()}
    return eqx.tree_at(lambda s: s.lights, scene, scene.lights.with_intensities(ones))


# Compiled once per structure (run eagerly, these would dispatch dozens of small XLA
# programs); `Kernel` also runs them over a batch of targets.
def _prepare_float64(scene: Scene, plan: RenderPlan, mode: str, table_size: int) -> Prepared:
    return prepare(scene, plan, mode, table_size, jnp.float64)


#: `strauss_fit.rendering.strauss.prepare` in float64.
prepare_float64 = Kernel(_prepare_float64, "prepare")
#: `strauss_fit.rendering.strauss.take_pixels`.
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
    """`Problem.physical` in NumPy (no JAX dispatch): the physical values of θ with the
    pinned entries replaced."""
    return np.where(
        np.asarray(problem.pinned), np.asarray(problem.pinned_values), problem.layout.to_physical_numpy(theta)
    )


def geometry_key(scene: Scene, plan: RenderPlan, options: FitOptions) -> tuple:
    """What a prepared scene depends on, as a hashable key: the camera, the background,
    the lights and depth (values, not object identity: every fit builds its own scene
    object), the render plan and the evaluator — so that the targets of one scene share
    one preparation (`build_problem_steps`)."""
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
    pad: bool = False,
) -> tuple[Problem, Prepared, np.ndarray]:
    """The `Problem` for the free ``names``, the full prepared image and the
    flat indices of the pixels used (`build_problem_steps`, run directly)."""
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
            pad=pad,
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
    pad: bool = False,
) -> Steps:
    """`build_problem` as steps (`strauss_fit.engine`).

    Of ``options`` only ``mode``, ``table_size`` and ``edge_pixels`` matter. ``cache`` (a
    dict) keeps the prepared scene per `geometry_key` — preparing depends only on the
    camera, the background, where the lights are and the plan, not on the material or the
    lights' intensities, so every problem of a fit, and every target of a scene in
    `strauss_fit.fit_many`, shares it — and the target's pixels per render plan.
    ``loss`` (`LOSSES`), ``noise_sigma`` (the noise level of every value of the
    image, (H, W, 3), for the robust losses) and ``exposure`` (a held global exposure
    other than 1) shape the residual. ``pad``: the pixel set padded to its
    `pixel_bucket` (see the module docstring); the returned indices are the real ones."""
    cache = {} if cache is None else cache
    if options.edge_pixels == "auto":  # a fit resolves it once, first; here for direct callers
        edge_pixels, _ = yield from resolve_edge_pixels_steps(
            scene, target, plan, options, cache, 1.0 if exposure is None else float(exposure)
        )
        options = dataclasses.replace(options, edge_pixels=edge_pixels)
    prepared_full = yield from prepared_full_steps(scene, plan, options, cache)
    geometry = geometry_key(scene, plan, options)
    key = ("pixels", id(target), geometry, options.edge_pixels)
    if key in cache:
        _, index, pixels = cache[key]
    else:
        covered_key = ("fully covered", geometry)
        if options.edge_pixels == "exclude" and covered_key not in cache:
            cache[covered_key] = fully_covered(scene.camera)  # once per scene
        used = used_pixels(scene, target, np.asarray(prepared_full.hit), options.edge_pixels, cache.get(covered_key))
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
        cache[key] = target, index, pixels  # the target is kept: its id stays its own
    extra: dict[str, Any] = {}
    rows = padded_rows(index.size) if pad else np.arange(index.size)
    if (*key, pad) not in cache:  # the prepared pixels and the target's, in the rows the problem takes
        target_rows = pixels[rows]
        target_rows.flags.writeable = False  # shared by every problem of this pixel set
        cache[(*key, pad)] = (yield take_pixels_jit.call(prepared_full, index[rows])), target_rows
    prepared, target_rows = cache[(*key, pad)]
    if pad:
        extra["valid"] = valid_rows(index.size, rows.size)
        extra["count"] = np.asarray(index.size)
    if loss != LEAST_SQUARES:
        spec = loss_named(loss)  # an unknown name is a one-line error listing the losses
        extra["loss"] = loss
        if spec.name in LOSS_FIELDS:  # fields of the target's pixels (the perceptual offset)
            extra.update(LOSS_FIELDS[spec.name](pixels))
        elif spec.robust and noise_sigma is not None:
            sigma = np.asarray(noise_sigma, dtype=np.float64).reshape(-1, 3)[index[rows]]
            extra["weights"] = reference_noise / np.maximum(sigma, 1e-300)
    if exposure is not None and float(exposure) != 1.0:
        extra["exposure"] = np.asarray(float(exposure))
    layout = Layout(tuple(names))
    problem = Problem(
        prepared=prepared,
        target=target_rows,
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


def prepared_full_steps(scene: Scene, plan: RenderPlan, options: FitOptions, cache: dict) -> Steps:
    """The scene prepared at every pixel (lights at unit intensity), once per
    `geometry_key` in ``cache``."""
    geometry = geometry_key(scene, plan, options)
    if geometry not in cache:
        cache[geometry] = yield prepare_float64.call(
            unit_intensity_scene(scene), plan, options.mode, options.table_size
        )
    return cache[geometry]


def resolve_edge_pixels_steps(
    scene: Scene, target: Target, plan: RenderPlan, options: FitOptions, cache: dict, exposure: float = 1.0
) -> Steps:
    """``options.edge_pixels`` as a fit uses it — ``"include"`` or ``"exclude"`` — and a
    note saying why when it was ``"auto"`` (`strauss_fit.rendering.coverage.silhouette_blend`:
    included for a point-sampled silhouette; excluded for a blended one or when it cannot
    be told)."""
    if options.edge_pixels != "auto":
        return options.edge_pixels, None
    prepared_full = yield from prepared_full_steps(scene, plan, options, cache)
    height, width = target.pixels.shape[:2]
    hit = np.asarray(prepared_full.hit).reshape(height, width)
    background = np.asarray(prepared_full.miss_radiance, dtype=np.float64).reshape(height, width, 3) * exposure
    coverage = pixel_coverage(scene.camera)  # a property of the camera: kept per camera
    blended, why = silhouette_blend(target.pixels, target.usable, hit, coverage, background)
    if blended is False:
        return "include", f"edge pixels used: {why}"
    return "exclude", f"edge pixels (partly covered by the sphere) left out: {why}"


def used_pixels(
    scene: Scene, target: Target, hit: np.ndarray, edge_pixels: str = "exclude", covered: np.ndarray | None = None
) -> np.ndarray:
    """(H, W) bool: the pixels a fit uses — on the sphere (``hit``: the ray through the
    centre hits it), usable in ``target`` (not masked out or clipped) and, with
    ``edge_pixels="exclude"``, wholly covered by the sphere
    (`strauss_fit.rendering.coverage.fully_covered`; ``covered``, when already known)."""
    used = np.asarray(hit) & target.usable
    if edge_pixels == "exclude":
        used &= fully_covered(scene.camera) if covered is None else covered
    return used


#: The perceptual loss's offset ε as a fraction of the target's 98th percentile: small
#: enough not to flatten dark regions (CIELAB's own linear toe is at 0.9 % of white), large
#: enough that the cube root's slope stays finite at black.
PERCEPTUAL_OFFSET = 1e-3
#: The losses whose residuals need fields computed from the target's usable pixels
#: (`build_problem_steps`): a function of those pixels (M, 3) giving the fields.
LOSS_FIELDS: dict[str, Callable[[np.ndarray], dict[str, np.ndarray]]] = {"perceptual": _perceptual_fields}


def coarse_problem(problem: Problem, prepared_full: Prepared, index: np.ndarray) -> Problem | None:
    """`coarse_problem_steps`, run directly."""
    return run(coarse_problem_steps(problem, prepared_full, index))


def coarse_problem_steps(problem: Problem, prepared_full: Prepared, index: np.ndarray) -> Steps:
    """``problem`` restricted to every k-th of its pixels (k = N // `COARSE_PIXELS`),
    or None when it is small enough. The residual scale shrinks with the pixel count, so
    costs (χ² per value at the reference noise) stay comparable."""
    stride = index.size // COARSE_PIXELS
    if stride < 2:
        return None
    subset = np.arange(0, index.size, stride)
    real = subset.size
    extra: dict[str, Any] = {}
    if problem.count is not None:  # padded as the problem is
        subset = subset[padded_rows(real)]
        extra = dict(valid=valid_rows(real, subset.size), count=np.asarray(real))
    prepared = yield take_pixels_jit.call(prepared_full, index[subset])
    # the problem's first index.size rows are its real pixels, in the order of index
    return dataclasses.replace(
        problem,
        prepared=prepared,
        target=np.asarray(problem.target)[subset],
        residual_scale=problem.residual_scale * np.sqrt(real / index.size),
        weights=None if problem.weights is None else np.asarray(problem.weights)[subset],
        **extra,
    )


#: The smallest padded pixel set (`pixel_bucket`).
_SMALLEST_BUCKET = 64


def pixel_bucket(count: int) -> int:
    """The padded size of a set of ``count`` pixels: the smallest of 64·2^(k/4), k = 0, 1,
    ..., rounded up to a multiple of 8, that holds them — four sizes per doubling, so the
    padding is at most 19 % (a little more below a thousand pixels, from the rounding) and a
    scene's images share a handful of compiled shapes."""
    size, k = _SMALLEST_BUCKET, 0
    while size < count:
        k += 1
        size = int(np.ceil(_SMALLEST_BUCKET * 2 ** (k / 4) / 8) * 8)
    return size


def padded_rows(count: int) -> np.ndarray:
    """Row indices of a padded set of ``count`` rows: 0 … count−1, then row 0 repeated up
    to `pixel_bucket` (a real pixel, so that the padding renders finite values; its
    weight is 0)."""
    rows = np.arange(pixel_bucket(count))
    rows[count:] = 0
    return rows


def valid_rows(count: int, size: int) -> np.ndarray:
    """(size,) weights: 1 for the first ``count`` rows (real), 0 for the padding."""
    return (np.arange(size) < count).astype(np.float64)
