"""The verdicts a fit draws from the noise: `mismatch_verdict` against a known noise
level (χ²/dof and its spread), `one_sided_verdict` against the bound of
`noise_bound` when the level is unknown (too large, or too structured, for any noise
up to it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ._bound import NoiseBound


@dataclass
class Verdict:
    """χ²/dof of a fit's residual against a known noise, with its expected spread."""

    chi2_dof: float
    dof: int
    expected_sd: float
    z: float
    consistent: bool
    per_channel: list = field(default_factory=list)


def mismatch_verdict(
    residual: np.ndarray,
    sigma: np.ndarray,
    usable: np.ndarray,
    n_params: int,
    *,
    sigma_rel_se: np.ndarray | float = 0.0,
    z_threshold: float = 3.0,
) -> Verdict:
    """χ²/dof = Σ (r/σ)² / (N − P) over the usable pixels and channels, against its expected
    spread: √(2/dof) from the noise alone, widened by the noise level's own uncertainty
    (a relative SE ε of σ is ≈ 2ε on σ², hence on χ²/dof; per-channel ε (C,) are taken as
    independent, each channel carrying 1/C of χ², a scalar ε as common to all channels).
    ``sigma``: (C,) or a per-pixel map (H, W, C). ``consistent`` when
    (χ²/dof − 1)/spread < ``z_threshold`` (one-sided: χ²/dof well below 1 means the noise
    level was over-estimated, which is reported by z but is not a model mismatch).
    ``per_channel``: the same per channel (chi2_dof, expected_sd, z)."""
    res = np.asarray(residual, np.float64)
    r = res[usable]
    s = np.broadcast_to(np.asarray(sigma, np.float64), res.shape)[usable]
    z2 = (r / s) ** 2
    if z2.ndim == 1:
        z2 = z2[:, None]
    n_rows, C = z2.shape
    dof = max(z2.size - n_params, 1)
    chi = float(z2.sum() / dof)
    eps = np.asarray(sigma_rel_se, np.float64)
    eps_c = np.broadcast_to(eps, (C,)) if eps.ndim else np.full(C, float(eps))
    sigma_part = 2 * float(eps) if eps.ndim == 0 else 2 * float(np.sqrt(np.sum(eps_c**2))) / C
    sd = math.sqrt(2.0 / dof + sigma_part**2)
    zval = (chi - 1.0) / sd
    per = []
    for c in range(C):
        dof_c = max(n_rows - n_params / C, 1.0)
        chi_c = float(z2[:, c].sum() / dof_c)
        sd_c = math.sqrt(2.0 / dof_c + (2 * float(eps_c[c])) ** 2)
        per.append({"chi2_dof": chi_c, "expected_sd": sd_c, "z": (chi_c - 1.0) / sd_c})
    return Verdict(chi, dof, sd, float(zval), bool(zval < z_threshold), per)


#: χ²/dof at the bound above which the residual is too large for any noise the image can
#: hold (the "magnitude" test): the residual's RMS is then over √10 ≈ 3.2 times the bound,
#: over the whole sphere or over one tile (below).
BOUND_CHI2 = 10.0
#: The magnitude test is also made on square tiles of this many pixels a side (a fixed
#: grid from the image's corner) that hold at least half a tile of used pixels: a misfit
#: confined to a small region (a refraction's centre, a highlight) is diluted in the
#: sphere's mean but not in its tile's.
BOUND_TILE = 8
#: The "structure" test: the residual's lag-1 autocovariance, in units of the bound's
#: variance, above this (its smooth part alone holds twice the largest noise variance)...
STRUCTURE_POWER = 2.0
#: ...and at least this many of its own standard errors above 0 (white noise: N(0, 1)).
STRUCTURE_Z = 8.0


@dataclass
class OneSidedVerdict:
    """The residual of a fit against the largest noise its target can hold
    (`one_sided_verdict`).

    ``chi2_dof``: Σ(r/σ_b)²/(N − P); ``per_channel``: the same per channel;
    ``worst_tile``: the tile with the largest mean (r/σ_b)² (``chi2_per_dof``, ``pixels``
    used in it, its top-left ``row`` and ``column``, its ``size``), None when no tile holds
    enough used pixels; ``lag1_correlation``: ρ₁ of the residual in bound units over
    neighbouring used pixels; ``structured_power``: their mean product C₁ (the power of the
    residual's smooth part, in units of the bound's variance); ``structure_z``: C₁ in its
    own standard errors; ``pairs``: how many neighbour pairs; ``too_large`` /
    ``too_structured``: which test fired. ``mismatch`` when either did."""

    chi2_dof: float
    per_channel: list[float]
    worst_tile: dict | None
    lag1_correlation: float
    structured_power: float
    structure_z: float
    pairs: int
    too_large: bool
    too_structured: bool

    @property
    def mismatch(self) -> bool:
        return self.too_large or self.too_structured


def one_sided_verdict(
    residual: np.ndarray,
    bound: NoiseBound,
    n_params: int,
    *,
    chi2_threshold: float = BOUND_CHI2,
    tile: int = BOUND_TILE,
    structure_power: float = STRUCTURE_POWER,
    structure_z: float = STRUCTURE_Z,
) -> OneSidedVerdict:
    r"""Is the residual ``residual`` (H, W, C; read at ``bound.used``) too large or too
    structured for any noise up to ``bound``? A one-sided test: it can say that the model
    does not reproduce the target, never that it does.

    With z_i = r_i/σ_b(i) (σ_b² = ``bound.variance``, each value's noise σ_i ≤ σ_b(i)):

    - **magnitude**: χ²_b = Σ z²/(N − P) ≤ χ²/dof at the true noise, whose expected value
      is 1 when the model is right. The test fires when χ²_b > ``chi2_threshold`` (10)
      over the used pixels, or when the mean z² over the used values of one ``tile`` ×
      ``tile`` square (a fixed grid; squares with fewer than tile²/2 used pixels are
      skipped) does. With white noise E[z²] ≲ 0.7 (the bound's confidence margin), and a
      tile's mean over at least 32 pixels exceeds 10 with a probability below 1e-45 even
      if the channels' noise were one (a χ² with 32 degrees of freedom beyond 320): the
      margin is for what the bound assumes, not for chance. Noise whose neighbours correlate by ρ leaks through the
      high-pass kernel at only g(ρ) = ((6 − 8ρ + 2ρ²)/6)² of its variance; a threshold of
      10 tolerates ρ up to about 0.6.
    - **structure**: over the pairs (i, j) of horizontally or vertically neighbouring used
      pixels, p_ij = (1/C) Σ_c z_ic z_jc. For noise independent between pixels
      E[p_ij] = 0, and the p_ij are uncorrelated (E[z_i z_j z_j z_k] = 0), so
      C₁ = mean p_ij has the standard error √(Σ p²)/n_pairs, whatever the noise's level
      or its correlation between channels, and t = Σ p/√(Σ p²) is about N(0, 1). A smooth
      residual m (the model's misfit) gives C₁ ≈ mean (m/σ_b)²: the power of its smooth
      part in units of the bound, whatever the noise. The test fires when
      C₁ > ``structure_power`` (2) **and** t > ``structure_z`` (8): the smooth part alone
      exceeds twice the largest noise variance, and is no accident (8 standard errors;
      a self-normalised sum of symmetric terms exceeds x with probability below
      exp(−x²/2) ≈ 1e-14). Noise whose neighbours correlate by ρ gives C₁ ≈ ρ/g(ρ) in
      bound units (0.36 at ρ = 0.2, 0.9 at 0.35, 2.9 at 0.5), so the test tolerates
      neighbour correlations up to about 0.45.

    ``lag1_correlation`` ρ₁ = Σ p / Σ (z_i² + z_j²)/2 (channel means) is reported, not
    tested: 0 for white noise, near 1 for a smooth residual."""
    res = np.asarray(residual, dtype=np.float64)
    if res.ndim == 2:
        res = res[..., None]
    used = bound.used
    C = res.shape[-1]
    z = np.where(used[..., None], res / np.sqrt(np.where(used[..., None], bound.variance, 1.0)), 0.0)
    values = z[used]
    n_used = values.shape[0]
    dof = max(values.size - n_params, 1)
    chi2 = float(np.sum(values**2) / dof)
    per_channel = [float(np.sum(values[:, c] ** 2) / max(n_used - n_params / C, 1.0)) for c in range(C)]
    worst_tile = _worst_tile(np.sum(z * z, axis=-1) / C, used, tile)
    products, squares = [], []
    for a, b, both in (
        (z[:, :-1], z[:, 1:], used[:, :-1] & used[:, 1:]),
        (z[:-1, :], z[1:, :], used[:-1, :] & used[1:, :]),
    ):
        products.append(np.mean(a * b, axis=-1)[both])
        squares.append(np.mean(a * a + b * b, axis=-1)[both] / 2.0)
    p, q = np.concatenate(products), np.concatenate(squares)
    pairs = int(p.size)
    total, spread, power = float(np.sum(p)), float(np.sqrt(np.sum(p * p))), float(np.sum(q))
    c1 = total / pairs if pairs else 0.0
    t = total / spread if spread > 0 else 0.0
    rho = total / power if power > 0 else 0.0
    return OneSidedVerdict(
        chi2_dof=chi2,
        per_channel=per_channel,
        worst_tile=worst_tile,
        lag1_correlation=rho,
        structured_power=c1,
        structure_z=t,
        pairs=pairs,
        too_large=bool(
            chi2 > chi2_threshold or (worst_tile is not None and worst_tile["chi2_per_dof"] > chi2_threshold)
        ),
        too_structured=bool(c1 > structure_power and t > structure_z),
    )


def _worst_tile(z2: np.ndarray, used: np.ndarray, tile: int) -> dict | None:
    """The ``tile`` × ``tile`` square of a fixed grid (from the image's corner) with the
    largest mean of ``z2`` (H, W: the mean over channels of z²) over its used pixels,
    among the squares with at least tile²/2 of them; None when there is none."""
    H, W = used.shape
    rows, cols = -(-H // tile), -(-W // tile)
    padded_z = np.zeros((rows * tile, cols * tile))
    padded_u = np.zeros((rows * tile, cols * tile))
    padded_z[:H, :W] = np.where(used, z2, 0.0)
    padded_u[:H, :W] = used
    sums = padded_z.reshape(rows, tile, cols, tile).sum(axis=(1, 3))
    counts = padded_u.reshape(rows, tile, cols, tile).sum(axis=(1, 3))
    enough = counts >= tile * tile / 2
    if not enough.any():
        return None
    means = np.where(enough, sums / np.maximum(counts, 1.0), -np.inf)
    row, col = np.unravel_index(int(np.argmax(means)), means.shape)
    return {
        "chi2_per_dof": float(means[row, col]),
        "pixels": int(counts[row, col]),
        "row": int(row * tile),
        "column": int(col * tile),
        "size": int(tile),
    }
