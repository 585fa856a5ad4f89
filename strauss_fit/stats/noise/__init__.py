"""Noise level of a target image that does not come from the model's own residual.

NumPy + SciPy only (no JAX): it runs on the target image before any model exists.
Four sources of a per-channel noise level:

1. `estimate_noise` — the standard deviation of additive white noise, per channel,
   estimated from the image itself with a high-pass residual and a robust, iteratively
   clipped scale (the method is in its docstring). Returns a `NoiseEstimate` with
   the number of pixels used, a standard error, and checks that say whether the noise (and
   not the image content) sets the value.
2. `estimate_noise_model` — signal-dependent (Poisson–Gaussian) noise,
   Var[x] = a·x + b per channel (Foi et al. 2008 style), with a significance test of a.
3. `noise_from_sensor` — the per-pixel σ of the project's synthetic sensor
   (Var = E/gain + read_noise²).
4. `quantisation_sigma` — the per-pixel noise floor of 8-bit sRGB coding
   (bin width in linear units / √12), and `combine_with_quantisation`.

`mismatch_verdict` turns a fit's residual and a noise level into χ²/dof, its
expected spread and the decision. When the noise cannot be measured, `noise_bound`
still bounds it from above (the local mean square of a second-difference residual: the
noise plus the signal's own curvature), and `one_sided_verdict` tests a residual
against that bound: too large, or too structured, for any noise up to it.
`describe_noise` chooses a target's `NoiseModel`: given, from its sidecar, or
estimated.

Layout: one private module per estimator, all starting from the same input preparation
(``_inputs.prepare``: the image as float, the mask, the finiteness check, the erosion, the
kernel) and the same high-pass residual (``_highpass``) and robust scale (``_robust``):

- ``_additive``: `estimate_noise` (its constants in ``_calibration``);
- ``_level_line``: `estimate_noise_model`;
- ``_sensor``: `noise_from_sensor`; ``_quantisation``: the 8-bit floor;
- ``_bound``: `noise_bound`, `binned_laplacian_bound`;
- ``_verdicts``: `mismatch_verdict`, `one_sided_verdict`;
- ``_model``: `NoiseModel`, `check_noise_level`; ``_describe``:
  `describe_noise` and the sidecar.
"""

from ._additive import NoiseEstimate as NoiseEstimate
from ._additive import estimate_noise as estimate_noise
from ._bound import BOUND_CONFIDENCE as BOUND_CONFIDENCE
from ._bound import BOUND_FLOOR as BOUND_FLOOR
from ._bound import BOUND_WIDTH as BOUND_WIDTH
from ._bound import LAPLACIAN_BOUND_BINS as LAPLACIAN_BOUND_BINS
from ._bound import MEDIAN_CHI2_1 as MEDIAN_CHI2_1
from ._bound import NoiseBound as NoiseBound
from ._bound import binned_laplacian_bound as binned_laplacian_bound
from ._bound import noise_bound as noise_bound
from ._describe import ESTIMATED_KEPT as ESTIMATED_KEPT
from ._describe import MIN_PIXELS_SIGNAL_DEPENDENT as MIN_PIXELS_SIGNAL_DEPENDENT
from ._describe import STORAGE_PRECISION as STORAGE_PRECISION
from ._describe import describe_noise as describe_noise
from ._describe import read_sidecar as read_sidecar
from ._describe import sidecar_path as sidecar_path
from ._describe import storage_precision as storage_precision
from ._describe import unusable_sidecar as unusable_sidecar
from ._errors import NoiseEstimationError as NoiseEstimationError
from ._highpass import KERNELS as KERNELS
from ._highpass import kernel_kappa as kernel_kappa
from ._inputs import MIN_PIXELS as MIN_PIXELS
from ._level_line import FIXED_POINT as FIXED_POINT
from ._level_line import PoissonGaussian as PoissonGaussian
from ._level_line import estimate_noise_model as estimate_noise_model
from ._model import NOISE_RANGE as NOISE_RANGE
from ._model import NOISE_SOURCES as NOISE_SOURCES
from ._model import NoiseModel as NoiseModel
from ._model import check_noise_level as check_noise_level
from ._quantisation import combine_with_quantisation as combine_with_quantisation
from ._quantisation import quantisation_sigma as quantisation_sigma
from ._robust import MAD_CONSTANT as MAD_CONSTANT
from ._sensor import noise_from_sensor as noise_from_sensor
from ._verdicts import BOUND_CHI2 as BOUND_CHI2
from ._verdicts import BOUND_TILE as BOUND_TILE
from ._verdicts import STRUCTURE_POWER as STRUCTURE_POWER
from ._verdicts import STRUCTURE_Z as STRUCTURE_Z
from ._verdicts import OneSidedVerdict as OneSidedVerdict
from ._verdicts import Verdict as Verdict
from ._verdicts import mismatch_verdict as mismatch_verdict
from ._verdicts import one_sided_verdict as one_sided_verdict

# The API reference (mkdocstrings) renders the names of __all__ only: an imported name is
# private to it otherwise, even when re-exported as above.
__all__ = [
    "BOUND_CHI2",
    "BOUND_CONFIDENCE",
    "BOUND_FLOOR",
    "BOUND_TILE",
    "BOUND_WIDTH",
    "ESTIMATED_KEPT",
    "FIXED_POINT",
    "KERNELS",
    "LAPLACIAN_BOUND_BINS",
    "MAD_CONSTANT",
    "MEDIAN_CHI2_1",
    "MIN_PIXELS",
    "MIN_PIXELS_SIGNAL_DEPENDENT",
    "NOISE_RANGE",
    "NOISE_SOURCES",
    "STORAGE_PRECISION",
    "STRUCTURE_POWER",
    "STRUCTURE_Z",
    "NoiseBound",
    "NoiseEstimate",
    "NoiseEstimationError",
    "NoiseModel",
    "OneSidedVerdict",
    "PoissonGaussian",
    "Verdict",
    "binned_laplacian_bound",
    "check_noise_level",
    "combine_with_quantisation",
    "describe_noise",
    "estimate_noise",
    "estimate_noise_model",
    "kernel_kappa",
    "mismatch_verdict",
    "noise_bound",
    "noise_from_sensor",
    "one_sided_verdict",
    "quantisation_sigma",
    "read_sidecar",
    "unusable_sidecar",
    "sidecar_path",
    "storage_precision",
]
