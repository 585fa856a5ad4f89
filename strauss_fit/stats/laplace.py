r"""The Laplace (Gauss–Newton) approximation: JᵀJ → covariance → deviations and correlations.

The one home of that computation, for every part of the library that needs it: the fit's
uncertainties (`problem_laplace`), the sampler's starting spread and the report
(`laplace_covariance`), the Phong fit, the study's Fisher information and the
identifiability analysis; the curvature the sampler's posterior has
(`posterior_covariance`).

At a least-squares optimum `\hat\theta` of residuals `r(\theta)` with Jacobian
J (with respect to the *physical* parameters), the Fisher information of Gaussian noise
of standard deviation σ is `\mathcal I = J^\top J/\sigma^2` and the Laplace
covariance its inverse, `\Sigma = \sigma^2 (J^\top J)^{-1}` — exact for a linear
model with a flat prior and an optimum away from the bounds. σ² is given, or estimated as
`\mathrm{RSS}/(N - P)` (`residual_variance`). The inverse is a pseudo-inverse
(`covariance`, eigenvalues below ``rcond`` times the largest dropped), or, with a
``ridge``, the inverse of `\mathcal I + \epsilon I`, which shows an exact degeneracy
as an enormous deviation instead of dropping it. Deviations are
`\sqrt{\max(\Sigma_{ii}, 0)}` and correlations
`\Sigma_{ij}/(s_i s_j)` (`deviations`, `correlation`).

Problems are duck-typed: anything with ``residual_physical(x)`` (a Strauss
`strauss_fit.fitting.problem.Problem`, a Phong
`strauss_fit.convert.phong_fit.PhongProblem`).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..engine import Kernel, Steps, run
from ..numerics import value_and_jacobian_columns
from ..precision import uses_float64

#: Eigenvalues of JᵀJ below this fraction of the largest are dropped by the pseudo-inverse.
PINV_RCOND = 1e-14


def _jacobian(problem: Any, x: Array) -> Array:
    return jax.jacfwd(problem.residual_physical)(x)


#: The Jacobian as a `Kernel` (for steps; see `jacobian`).
jacobian_kernel = Kernel(_jacobian, "jacobian")


@uses_float64
def jacobian(problem: Any, x: Array) -> Array:
    """d(residuals)/d(physical parameters) at ``x``, (N, P): ``jax.jacfwd`` of
    ``problem.residual_physical``, compiled once per problem structure."""
    return jacobian_kernel(problem, x)


def information(jac: np.ndarray) -> np.ndarray:
    """JᵀJ of a Jacobian (N, P)."""
    return jac.T @ jac


def residual_variance(rss: float, count: int, parameters: int) -> float:
    """σ̂² = RSS/(N − P) (N residuals, P parameters; at least one degree of freedom)."""
    return rss / max(count - parameters, 1)


def covariance(
    information: np.ndarray, variance: float = 1.0, *, rcond: float = PINV_RCOND, ridge: float | None = None
) -> np.ndarray:
    """Σ = variance × (JᵀJ)⁺ (Hermitian pseudo-inverse with ``rcond``), or with ``ridge``
    ε the plain inverse variance × (JᵀJ + ε I)⁻¹."""
    if ridge is not None:
        return variance * np.linalg.inv(information + ridge * np.eye(len(information)))
    return variance * np.linalg.pinv(information, rcond=rcond, hermitian=True)


def deviations(cov: np.ndarray) -> np.ndarray:
    """Standard deviations, sqrt(max(diag Σ, 0))."""
    return np.sqrt(np.maximum(np.diag(cov), 0.0))


def correlation(cov: np.ndarray, *, fallback: np.ndarray | None = None, floor: float | None = None) -> np.ndarray:
    """Correlation matrix Σᵢⱼ/(sᵢ sⱼ). Where sᵢ sⱼ = 0 the entry is taken from
    ``fallback`` (default 0); with ``floor``, the denominator is max(sᵢ sⱼ, floor)
    everywhere instead."""
    sd = deviations(cov)
    norm = np.outer(sd, sd)
    if floor is not None:
        return cov / np.maximum(norm, floor)
    out = np.zeros_like(cov) if fallback is None else np.array(fallback, dtype=float)
    return np.divide(cov, norm, out=out, where=norm > 0)


@uses_float64
def problem_laplace(
    problem: Any, x: np.ndarray, rss: float, sigma: float | None = None, info: np.ndarray | None = None
) -> tuple[dict[str, Any], dict[str, Any], np.ndarray | None]:
    """`problem_laplace_steps`, run directly."""
    return run(problem_laplace_steps(problem, x, rss, sigma, info))


def problem_laplace_steps(
    problem: Any, x: np.ndarray, rss: float, sigma: float | None = None, info: np.ndarray | None = None
) -> Steps:
    r"""The Laplace deviations and correlations of a fit problem at its optimum ``x``.

    `\Sigma = \sigma^2 (J^\top J)^{+}` with σ² given or RSS/(N − P). Entries the
    problem pins at a bound get deviation 0 (their rows and columns of JᵀJ are zeroed).
    ``info``: JᵀJ of the physical residuals at ``x`` if already computed (the polish
    does). Returns the deviations by parameter name (a list for colour), the correlation
    ``{"labels", "matrix"}`` (rounded to 6 digits) and Σ; empty and None for an empty
    layout."""
    layout = problem.layout
    if layout.size == 0:
        return {}, {}, None
    if info is None:
        info = information(np.asarray((yield jacobian_kernel.call(problem, np.asarray(x, dtype=np.float64)))))
    free = ~np.asarray(problem.pinned)
    info = np.asarray(info) * np.outer(free, free)
    n, p = _value_count(problem), layout.size
    variance = sigma**2 if sigma else residual_variance(rss, n, p)
    cov = covariance(info, variance)
    uncertainty, corr = by_parameter(layout, cov)
    return uncertainty, corr, cov


def _value_count(problem: Any) -> int:
    """The number of real residual values of a problem (a padded fit problem says; any
    other counts its target)."""
    counter = getattr(problem, "value_count", None)
    return int(counter()) if counter is not None else int(np.asarray(problem.target).size)


def by_parameter(layout: Any, cov: np.ndarray) -> tuple[dict[str, Any], dict[str, Any]]:
    """A covariance in a layout's order as the fit result writes it: deviations by
    parameter name (a list for colour) and the correlation ``{"labels", "matrix"}``
    (rounded to 6 digits)."""
    sd = deviations(cov)
    uncertainty: dict[str, Any] = {}
    for name, size, offset in zip(layout.names, layout.sizes, layout.offsets):
        values = sd[offset : offset + size]
        uncertainty[name] = values.tolist() if size > 1 else float(values[0])
    return uncertainty, {"labels": layout.labels(), "matrix": np.round(correlation(cov), 6).tolist()}


# --- under misspecification: the noise sandwich ------------------------------------------


def _value_derivatives(problem: Any, model: Array) -> tuple[Array, Array, Array, Array, Array]:
    """Each residual gᵢ = φᵢ(mᵢ, yᵢ) of ``problem.objective_of_model`` as a function of its
    own model value mᵢ and target value yᵢ (M,): g, ∂g/∂m, ∂g/∂y, ∂²g/∂m² and ∂²g/∂m∂y, each
    one forward-mode derivative along "every value + 1" (each gᵢ depends on its own mᵢ and
    yᵢ alone, so that direction gives every value's own derivative at once)."""
    target = problem.target
    ones = jnp.ones_like(target)

    def of_model(m: Array, y: Array) -> tuple[Array, Array]:
        return jax.jvp(lambda u: problem.objective_of_model(u, y), (m,), (ones,))

    (values, slope_m), (_, curvature_m) = jax.jvp(lambda m: of_model(m, target), (model,), (ones,))
    _, slope_y = jax.jvp(lambda y: problem.objective_of_model(model, y), (target,), (ones,))
    _, cross_my = jax.jvp(lambda y: of_model(model, y)[1], (target,), (ones,))
    return values, slope_m, slope_y, curvature_m, cross_my


def _opaque_entries(problem: Any) -> dict[str, range] | None:
    """The layout's entries by name where the renderer traces no transmission, else None."""
    layout = getattr(problem, "layout", None)
    plan = getattr(problem, "plan", None)
    if layout is None or plan is None or plan.transmit:
        return None
    spans = zip(layout.names, layout.sizes, layout.offsets)
    return {name: range(offset, offset + size) for name, size, offset in spans}


def zero_pairs(problem: Any) -> set[tuple[int, int]]:
    r"""The entry pairs (a ≤ b) of ``problem``'s layout where
    `\partial^2 m/\partial x_a \partial x_b = 0` at every pixel, whatever the values:
    where the renderer traces no transmission, each channel of the image is affine in that
    channel of the colour and in the metalness, and bilinear in the two
    (`strauss_fit.fitting.search`: the diffuse term, the specular tint
    `1 + m(1 - F)(C_c - 1)`, the ambient term and the reflected background), times free
    light intensities or an exposure if any. So the colour's pairs among themselves and the
    metalness with itself are 0: 7 of the 15 pairs of a (C, s, m) fit. With transmission C
    enters once per passage (a polynomial), and nothing is skipped. The tests compare the
    skipped pairs with computed ones (``tests/fit/test_single_fit_kernels.py``)."""
    entries = _opaque_entries(problem)
    if entries is None:
        return set()
    colour = list(entries.get("color", ()))
    pairs = {(a, b) for a in colour for b in colour if a <= b}
    pairs.update((a, a) for a in entries.get("metalness", ()))
    return pairs


def _hessian_passes(problem: Any, size: int) -> list[tuple[tuple[int, ...], int, tuple[tuple[int, int], ...]]]:
    """The second-derivative passes of `_weighted_model_hessian`: (entries summed into the
    first direction, the second direction's entry, the pairs it gives — one per channel when
    the first direction is the whole colour, else one).

    Each channel of the image depends on its own channel of the colour only, so along the
    colour's three entries at once the second derivative of a channel-c value in x_b is its
    derivative in C_c and x_b: one pass gives the three pairs (C_r, b), (C_g, b), (C_b, b),
    summed per channel. Used where no transmission is traced (as `zero_pairs`): 8 passes of
    a (C, s, m) fit become 4."""
    skipped = zero_pairs(problem)
    pairs = [(a, b) for a in range(size) for b in range(a, size) if (a, b) not in skipped]
    entries = _opaque_entries(problem)
    colour = tuple(entries.get("color", ())) if entries is not None else ()
    passes: list[tuple[tuple[int, ...], int, tuple[tuple[int, int], ...]]] = []
    grouped: dict[int, list[tuple[int, int]]] = {}
    for a, b in pairs:
        if len(colour) == 3 and (a in colour) != (b in colour):
            grouped.setdefault(b if a in colour else a, []).append((a, b))
        else:
            passes.append(((a,), b, ((a, b),)))
    for other, found in grouped.items():
        if len(found) == 3:
            passes.append((colour, other, tuple(found)))  # found is in channel order
        else:
            passes.extend(((a,), b, ((a, b),)) for a, b in found)
    return passes


def _weighted_model_hessian(problem: Any, x: Array, weights: Array) -> Array:
    r"""`\sum_i w_i \nabla^2 m_i(x)` (P, P) for the model values m (M,) of
    ``problem.render_physical``: the second derivatives
    `\partial^2 m/\partial x_a \partial x_b` as forward-over-forward directional
    derivatives, one pass after the other (``lax.map``) — every pair (a ≤ b), less those
    that vanish and with a colour channel's pairs grouped, see the end. Why not ``jax.hessian``: the model's
    derivatives are a closed-form ``custom_jvp`` (`strauss_fit.rendering.strauss.direct_radiance`),
    and batching its second derivatives over the P × P pairs (``vmap``) cost 6-10 times the
    pairs one by one at 256² (measured: 170-300 ms against 31 ms for P = 5). Pairs whose
    second derivative vanishes at every pixel are not computed (`zero_pairs`), and a colour
    channel's pairs with another entry are taken for the three channels in one pass
    (`_hessian_passes`)."""
    size = x.shape[0]
    passes = _hessian_passes(problem, size)
    if not passes:
        return jnp.zeros((size, size), dtype=x.dtype)  # none, or every pair vanishes (the colour alone)
    first = np.zeros((len(passes), size))
    second = np.zeros((len(passes), size))
    for k, (summed, other, _) in enumerate(passes):
        first[k, list(summed)] = 1.0
        second[k, other] = 1.0

    def render(z: Array) -> Array:
        return problem.render_physical(z).ravel()

    def one_pass(directions: tuple[Array, Array]) -> Array:
        u, v = directions
        _, second_derivative = jax.jvp(lambda z: jax.jvp(render, (z,), (u,))[1], (x,), (v,))
        return jnp.sum((weights * second_derivative).reshape(-1, 3), axis=0)  # per channel

    by_channel = jax.lax.map(one_pass, (jnp.asarray(first, dtype=x.dtype), jnp.asarray(second, dtype=x.dtype)))
    values, rows, columns = [], [], []
    for k, (_, _, found) in enumerate(passes):
        for channel, (a, b) in enumerate(found):
            values.append(by_channel[k, channel] if len(found) == 3 else jnp.sum(by_channel[k]))
            rows.append(a)
            columns.append(b)
    upper = jnp.stack(values)
    hessian = jnp.zeros((size, size), dtype=x.dtype).at[np.array(rows), np.array(columns)].set(upper)
    return hessian.at[np.array(columns), np.array(rows)].set(upper)


def _objective_terms(problem: Any, x: Array) -> tuple[Array, Array, Array, Array, Array]:
    return _objective_terms_and_model_jacobian(problem, x)[:5]


def _objective_terms_and_model_jacobian(problem: Any, x: Array) -> tuple[Array, ...]:
    r"""J, H, D, g and ∂J/∂y of `objective_terms`, from the model's Jacobian F (M, P)
    and the value-by-value derivatives of the residuals (`_value_derivatives`):
    `J_i = g'_i F_i`, `\partial J_i/\partial y_i = \partial^2 g_i/\partial m_i\partial y_i\,F_i`
    and `H = \sum_i (g_i'^2 + g_i g''_i) F_i F_i^\top + \sum_i g_i g'_i \nabla^2 m_i`
    (`_weighted_model_hessian`), g′ and g″ the derivatives in mᵢ: the Hessian of ½Σg²
    by the chain rule, with the render differentiated once and twice instead of the whole
    residual (the render's batched second derivatives are what made ``jax.hessian`` slow)."""
    # the render and its Jacobian F (M, P) by columns, so that the many products below read
    # two buffers instead of each evaluating the render again (`value_and_jacobian_columns`)
    model, columns = value_and_jacobian_columns(lambda z: problem.render_physical(z).ravel(), x)
    model, model_jacobian = model.reshape(-1, 3), columns.T
    values, slope_m, slope_y, curvature_m, cross_my = _value_derivatives(problem, model)
    jacobian = slope_m[:, None] * model_jacobian
    gauss_newton_weight = slope_m * slope_m + values * curvature_m
    hessian = model_jacobian.T @ (gauss_newton_weight[:, None] * model_jacobian) + _weighted_model_hessian(
        problem, x, values * slope_m
    )
    return jacobian, hessian, slope_y, values, cross_my[:, None] * model_jacobian, model_jacobian


#: `objective_terms` as a `Kernel`.
objective_terms_kernel = Kernel(_objective_terms, "objective_terms")


@uses_float64
def objective_terms(problem: Any, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    r"""At physical ``x``, for the residuals g the solver minimises
    (``problem.objective_residual``, the loss applied): their Jacobian J (M, P), the
    Hessian H of ½Σg² (P, P: JᵀJ plus the curvature of each residual times its value),
    D = ∂gᵢ/∂yᵢ (M,), the slope of each residual in its own target value (each gᵢ depends on
    yᵢ alone), and the rows C (M, P) of the cross derivative of the cost's gradient,
    `C_i = \partial(g_i \nabla_\theta g_i)/\partial y_i = D_i J_i + g_i\,\partial J_i/\partial y_i`:
    how the value yᵢ's noise moves the optimum (`problem_sandwich_steps`).

    ``problem``: a fit problem (`strauss_fit.fitting.problem.Problem`) whose residuals
    are value by value functions of its model (``render_physical``) and target
    (``objective_of_model``)."""
    j, h, slope, values, jacobian_slope = (
        np.asarray(v) for v in objective_terms_kernel(problem, jnp.asarray(x, dtype=jnp.float64))
    )
    return j, h, slope, _cross_rows(j, slope, values, jacobian_slope)


def _sandwich_parts(problem: Any, x: Array, noise_sd: Array) -> dict[str, Array]:
    r"""What the noise sandwich and the Laplace errors need, reduced on the device to P × P
    matrices (`problem_sandwich_steps`): the bread H/c², the meat
    `C^\top \mathrm{diag}(\sigma^2) C/c^4` (C's rows divided by c² factor by factor,
    `_cross_rows`), the Gauss–Newton JᵀJ/c² of the objective, and JᵀJ of the physical
    residuals (model minus target, the padding weighted 0) — c the largest |D|, 1 when that
    is not a positive finite number. ``noise_sd`` (M,): every value's noise, 0 on the padding."""
    jacobian, hessian, slope, values, jacobian_slope, model_jacobian = _objective_terms_and_model_jacobian(problem, x)
    scale = jnp.max(jnp.abs(slope)) if slope.size else jnp.asarray(0.0, slope.dtype)
    scale = jnp.where(jnp.isfinite(scale) & (scale > 0), scale, 1.0)
    cross = (slope / scale)[:, None] * (jacobian / scale) + (values / scale)[:, None] * (jacobian_slope / scale)
    scaled_jacobian = jacobian / scale
    # the physical residuals' Jacobian: the model's, the padding's rows weighted 0 as there
    valid = problem.valid
    physical = model_jacobian if valid is None else jnp.repeat(valid, 3)[:, None] * model_jacobian
    return {
        "scale": scale,
        "bread": hessian / scale / scale,
        "meat": cross.T @ (cross * (noise_sd**2)[:, None]),
        "gauss_newton": scaled_jacobian.T @ scaled_jacobian,
        "information": physical.T @ physical,
    }


#: `_sandwich_parts` as a `Kernel`.
sandwich_parts_kernel = Kernel(_sandwich_parts, "sandwich_parts")


def _cross_rows(
    j: np.ndarray, slope: np.ndarray, values: np.ndarray, jacobian_slope: np.ndarray, scale: float = 1.0
) -> np.ndarray:
    """C = D J + g ∂J/∂y (see `objective_terms`), divided by ``scale``² — each factor by
    ``scale`` before the product, so that neither overflows when the residuals were divided
    by a tiny reference noise."""
    return (slope / scale)[:, None] * (j / scale) + (values / scale)[:, None] * (jacobian_slope / scale)


def _positive_part(matrix: np.ndarray) -> np.ndarray:
    """The symmetric matrix with its negative eigenvalues set to 0."""
    values, vectors = np.linalg.eigh((matrix + matrix.T) / 2)
    return (vectors * np.maximum(values, 0.0)) @ vectors.T


def sandwich(bread: np.ndarray, meat: np.ndarray, free: np.ndarray | None = None) -> np.ndarray:
    r"""`V = B^{+} M B^{+}` over the ``free`` entries (the others get 0 rows and
    columns), B's negative eigenvalues dropped first (a saddle of the cost along a
    direction the data do not pin gives no information, not a negative variance)."""
    size = len(bread)
    free = np.ones(size, dtype=bool) if free is None else np.asarray(free, dtype=bool)
    out = np.zeros((size, size))
    if free.any():
        inverse = covariance(_positive_part(bread[np.ix_(free, free)]))
        out[np.ix_(free, free)] = inverse @ meat[np.ix_(free, free)] @ inverse
    return out


@uses_float64
def problem_sandwich(
    problem: Any, x: np.ndarray, noise_sd: np.ndarray
) -> tuple[dict[str, Any], dict[str, Any], np.ndarray, dict[str, Any]]:
    """`problem_sandwich_steps`, run directly."""
    return run(problem_sandwich_steps(problem, x, noise_sd))


def problem_sandwich_steps(problem: Any, x: np.ndarray, noise_sd: np.ndarray) -> Steps:
    r"""The noise-sandwich covariance of a fit at its optimum ``x``: how far the fitted
    values would move if the image were taken again with fresh noise.

    For the estimator `\hat\theta = \arg\min L(\theta, y)`,
    `L = \tfrac12\sum g_i(\theta, y_i)^2`, at a fixed image with noise ε of standard
    deviations ``noise_sd`` (per residual value, (M,)), the optimum moves with the noise as
    `\hat\theta - \theta^* \approx -H^{-1} C^\top \varepsilon`, C the rows
    `\partial(g_i\nabla_\theta g_i)/\partial y_i = D_i J_i + g_i\,\partial J_i/\partial y_i`
    of the derivative of ∇L in the data, so

    ```text
    V = H^{-1}\,(C^\top \mathrm{diag}(\sigma^2)\,C)\,H^{-1},
    ```

    with J, H, D = ∂g/∂y and C from `objective_terms`. For the linear and perceptual
    losses ∂J/∂y = 0 and C = DJ. For Huber and Cauchy, whose residuals are
    `g = \operatorname{sign}(z)\sqrt{2\rho(z)}` of the noise-scaled residual z (so that
    ½Σg² = Σρ), `C_i \propto \psi'(z_i)\nabla_\theta z_i` with ψ = ρ′: a value beyond
    Huber's threshold moves the optimum by nothing (ψ is flat there), where DJ alone gave it
    the weight `(k^2/g_i^2)^2` and widened the ± (by 1.2–1.35 times on a Phong target,
    see docs/uncertainty.md). For Gaussian noise the per-value weight E[ψ′(z + ε)²] is at
    least Var ψ(z + ε) (the Gaussian Poincaré inequality, Var h(ε) ≤ E h′(ε)²): the robust
    ± errs on the wide side where the noise straddles the threshold (on the Phong target,
    1.1–1.16 times the exact sandwich's).

    θ* is the *pseudo-true* value: the value the fit converges to as its noise averages out
    (the mean over retakes at the same noise level), whether or not the model can reproduce
    the image. For the linear loss it is the best fit to the noise-free image. For a robust
    loss it minimises the *expected* loss E Σρ((f(θ) − g − ε)/σ): the noise smooths ρ where the misfit is near
    the threshold, so under a mismatch θ* is not the robust fit to the noise-free image
    (on a Phong target 1.5–2.5 deviations from it in s and m) — nor the least-squares one.

    When the model is right and the loss linear, H = JᵀJ/s² (s the residual scale),
    D = 1/s and V is the Laplace covariance σ²(JᵀJ)⁻¹ with the known σ. When it is wrong,
    the misfit's curvature enters H, and the misfit — the same in every retake — does not
    count as noise, as it does in RSS/(N − P): on targets the model cannot reproduce this
    covered the pseudo-true values at 92–97 % for a nominal 95 %, where the Laplace
    interval from RSS was 2.5–12 times too wide and residual-based (Huber–White, cluster)
    sandwiches 1.1–270 times (measured on Phong and Mitsuba targets, 300 noise draws
    each; see docs/uncertainty.md). Entries pinned at a bound get 0.

    Returns the deviations by name, the correlation, V, and the eigenvalues of
    (JᵀJ)⁻¹H on the free entries (1 when the model fits; far from 1: the misfit's curvature
    matters)."""
    parts = yield sandwich_parts_kernel.call(problem, np.asarray(x, dtype=np.float64), padded_noise(problem, noise_sd))
    return sandwich_from_parts(problem, parts)


def padded_noise(problem: Any, noise_sd: np.ndarray) -> np.ndarray:
    """``noise_sd`` (one per real residual value) as `_sandwich_parts` takes it: one
    per value of ``problem.target``, 0 on a padded pixel set's padding
    (`strauss_fit.fitting.problem.pixel_bucket`), whose slope is 0 too."""
    noise_sd = np.asarray(noise_sd, dtype=np.float64).ravel()
    return np.concatenate([noise_sd, np.zeros(int(np.asarray(problem.target).size) - noise_sd.size)])


def sandwich_from_parts(
    problem: Any, parts: dict[str, Any]
) -> tuple[dict[str, Any], dict[str, Any], np.ndarray, dict[str, Any]]:
    """`problem_sandwich_steps`'s result from `_sandwich_parts`' P × P matrices.

    V is the same with C divided by any c² and H by c²: with c the largest slope (1/the
    residual scale, for the linear loss) the products stay of the image's own magnitude
    whatever scale the residuals were divided by (a reference noise of 1e-100 made the meat
    overflow to NaN)."""
    bread, meat = np.asarray(parts["bread"]), np.asarray(parts["meat"])
    free = ~np.asarray(problem.pinned)
    cov = sandwich(bread, meat, free)
    uncertainty, corr = by_parameter(problem.layout, cov)
    gauss_newton = np.asarray(parts["gauss_newton"])[np.ix_(free, free)]
    curvature = np.linalg.eigvals(covariance(gauss_newton) @ bread[np.ix_(free, free)]) if free.any() else np.zeros(0)
    return uncertainty, corr, cov, {"curvature_eigenvalues": np.sort(np.real(curvature)).tolist()}


@uses_float64
def laplace_covariance(problem: Any, x_hat: np.ndarray, sigma: float) -> np.ndarray:
    """Σ = σ² (JᵀJ)⁺ at ``x_hat``, every entry included (entries the fit pinned at a bound
    too: the sampler needs a scale for them)."""
    j = np.asarray(jacobian(problem, jnp.asarray(x_hat, dtype=jnp.float64)))
    return covariance(information(j), sigma**2)


def _rss_hessian(problem: Any, x: Array) -> Array:
    def half_rss(z):
        r = problem.residual_physical(z)
        return 0.5 * jnp.sum(r * r)

    return jax.hessian(half_rss)(x)


#: `rss_hessian` as a `Kernel`.
rss_hessian_kernel = Kernel(_rss_hessian, "rss_hessian")


@uses_float64
def rss_hessian(problem: Any, x: np.ndarray) -> np.ndarray:
    """The Hessian of ½RSS (least squares, whatever loss the problem's fit used) at
    physical ``x``, (P, P): JᵀJ plus each residual's curvature times its value."""
    return np.asarray(rss_hessian_kernel(problem, jnp.asarray(x, dtype=jnp.float64)))


@uses_float64
def posterior_covariance(problem: Any, x_hat: np.ndarray, sigma: float, free: np.ndarray) -> np.ndarray:
    r"""The covariance the least-squares posterior has near its optimum ``x_hat``,
    `\sigma^2 H^{+}` with H the Hessian of ½RSS (`rss_hessian`), over the
    ``free`` entries with the others held (0 rows and columns) — as the noise sandwich of
    `problem_sandwich_steps` holds entries pinned at a bound, so that the two can be
    compared entry for entry (``sample --adjust temperature``).

    H rather than the Gauss–Newton JᵀJ because it is the curvature the chain sees: when the
    model cannot reproduce the target the misfit's curvature enters it, and σ²(JᵀJ)⁻¹ can
    then be wider than the chain in some direction. The block of the full σ²(JᵀJ)⁺ on the
    free entries would be wider still: it lets the held entries move."""
    free = np.asarray(free, dtype=bool)
    size = len(free)
    out = np.zeros((size, size))
    if free.any():
        h = rss_hessian(problem, x_hat)
        out[np.ix_(free, free)] = covariance(h[np.ix_(free, free)], sigma**2)
    return out
