r"""Posterior sampling with emcee's affine-invariant ensemble sampler.

Layout (as emcee's): the chain file's format and `ChainError` (``_format``), the
in-memory HDF5 backend (``_backends``), diagnostics (``_diagnostics``), the walkers'
starting points (``_walkers``), reading and writing chain files (``_chain``), running
emcee (``_run``: `run_sampler`) and the whole workflow (``_workflow``:
`sample`). Every public name is re-exported here; import from
``strauss_fit.inference.sampler``, not from the private modules.

What runs: `emcee.EnsembleSampler` with ``vectorize=True`` over the log-posterior
of `strauss_fit.inference.posterior` (one jitted, ``vmap``-ed JAX call per half-ensemble
update), walkers started around the least-squares optimum θ̂.

Start. Walkers are drawn from the Laplace (Gauss–Newton) Gaussian `N(\hat\theta,\Sigma)`
(each standard deviation kept between 1e-6 and 1/4 of its prior width, so degenerate
directions neither collapse nor explode) and folded back into the prior box by reflection
at its faces. Entries the fit pinned at a bound start just inside it, since the posterior
there is one-sided.

Stopping (checked every ``check_every`` steps). With `\hat\tau_i` emcee's estimate of
the integrated autocorrelation time of parameter i over the whole chain (Sokal's
windowing, c = 5), the run stops when the chain is at least ``min_tau_multiple`` (50)
times `\max_i\hat\tau_i` long *and* `\max_i\hat\tau_i` changed by less than
`TAU_STABILITY` since the previous check (short chains underestimate τ), or at
``max_steps`` (the whole chain's length, earlier runs included), or on Ctrl-C.

Diagnostics (`diagnose`): the burn-in discarded is `\lceil 2\max_i\hat\tau_i\rceil`
steps (at most half the chain); the effective sample size of parameter i is
`\mathrm{ESS}_i = W (S - b) / \hat\tau_i` (W walkers, S steps, b burn-in); the
acceptance fraction is per walker over the whole chain. The chain is *trustworthy* when
all of these hold (else the failed ones are listed):

1. S ≥ ``min_tau_multiple`` · max τ̂ (the τ estimate and everything after it are reliable);
2. the mean acceptance fraction lies in [0.1, 0.9] and no walker is below 0.02 (a stuck
   walker sits in a spurious mode or at a corner of the prior);
3. every parameter has ESS ≥ 100;
4. every stored log-probability is finite.

Storage: emcee's own HDF5 layout (group ``mcmc``: ``chain`` (S, W, P), ``log_prob`` (S, W),
``accepted`` (W,), the random state) — load it with
``emcee.backends.HDFBackend(path, read_only=True)`` or h5py — plus a group ``strauss_fit``
holding what is needed to resume and report (labels, prior, σ, the fit, the target's
digest, and the ``adjustment``: its method and reason, the fit's covariance V and the
centre θ̂, and for the affine one the matrix A with the steps and burn-in it was computed
from and the draws it drops; `strauss_fit.inference.adjustment`).

Adjustment (``adjust``). On a target the model cannot reproduce, the Gaussian
likelihood's posterior does not have the spread of the fitted values over fresh noise
(the fit's noise sandwich V). With ``"affine"`` (the default when the fit's uncertainty is
the sandwich and its verdict a mismatch) the chain is sampled as usual and A, with
A Σ_post Aᵀ = V, is computed from its draws after burn-in when sampling ends and stored;
`Chain.samples` returns the mapped draws θ̂ + A(θ − θ̂) (those outside the prior
dropped) and ``adjusted=False`` the raw ones. ``"temperature"`` samples with σ√T instead
(T ≥ 1: it only widens; `strauss_fit.inference.adjustment.temperature`).

Least squares only. The likelihood is Gaussian, so its optimum is the least-squares fit's
θ̂: a fit made with another loss (Huber, which ``fit --loss auto`` switches to on a visible
mismatch; Cauchy; perceptual) has its θ̂ elsewhere, and its noise sandwich is the spread of
*that* estimator. The walkers' start, the temperature and the affine map θ̂ + A(θ − θ̂)
(A Σ_post Aᵀ = V, V the fit's sandwich) all take θ̂ and V to be the chain's own optimum and
the spread of the estimator the chain describes; with a Huber fit the chain centres on the
least-squares optimum instead (many deviations away) and the map moves it to neither. So
`sample` refuses such a fit (`check_least_squares`), and the fit it makes
itself is least squares.

Writing the chain safely. HDF5 cannot survive a full disk: a failed write inside it can
crash the process (a segmentation fault in h5py's clean-up) and leave a file that no
longer opens. So HDF5 never writes to the disk here: the chain file is held in memory
(`BufferedHDFBackend`; h5py writes into a ``BytesIO``), and
`BufferedHDFBackend.persist` writes the whole file image to a temporary file, every
write and the ``fsync`` checked, and renames it over the chain
(`strauss_fit.io.files.Outputs`). A failed write (a full disk) removes the temporary
and leaves the chain on disk exactly as it was after the previous write; ``--resume`` reads
it once there is space again. The file is written at least every `FLUSH_SECONDS`
seconds — less often when one write costs more than a tenth of that time
(`PERSIST_SHARE`), as for long chains — at every check when that is due, and at the
end; Ctrl-C writes every step sampled so far before the interrupt propagates. Resuming
restores the last walkers, log-probabilities and the random state, so an
interrupted-and-resumed chain equals an uninterrupted one.

Reading a chain (`load_chain`) checks what it reads: metadata with every key a
report or a resume needs, as many rows as the iteration count says, finite samples; a
damaged file is a one-line `ChainError`.
"""

from ._backends import CHUNK_STEPS as CHUNK_STEPS
from ._backends import FLUSH_SECONDS as FLUSH_SECONDS
from ._backends import PERSIST_SHARE as PERSIST_SHARE
from ._backends import BufferedHDFBackend as BufferedHDFBackend
from ._chain import REQUIRED_METADATA as REQUIRED_METADATA
from ._chain import Chain as Chain
from ._chain import load_chain as load_chain
from ._chain import read_metadata as read_metadata
from ._chain import write_metadata as write_metadata
from ._diagnostics import ACCEPTANCE_RANGE as ACCEPTANCE_RANGE
from ._diagnostics import DEFAULT_MIN_TAU_MULTIPLE as DEFAULT_MIN_TAU_MULTIPLE
from ._diagnostics import MIN_ESS as MIN_ESS
from ._diagnostics import STUCK_WALKER as STUCK_WALKER
from ._diagnostics import Diagnostics as Diagnostics
from ._diagnostics import autocorrelation_times as autocorrelation_times
from ._diagnostics import burn_in as burn_in
from ._diagnostics import diagnose as diagnose
from ._format import CHAIN_GROUP as CHAIN_GROUP
from ._format import FORMAT as FORMAT
from ._format import FORMAT_VERSION as FORMAT_VERSION
from ._format import META_GROUP as META_GROUP
from ._format import ChainError as ChainError
from ._run import CHECK_EVERY as CHECK_EVERY
from ._run import TAU_STABILITY as TAU_STABILITY
from ._run import Progress as Progress
from ._run import SampleRun as SampleRun
from ._run import SampleSettings as SampleSettings
from ._run import deferred_interrupt as deferred_interrupt
from ._run import run_sampler as run_sampler
from ._walkers import default_walkers as default_walkers
from ._walkers import initial_walkers as initial_walkers
from ._workflow import SampleResult as SampleResult
from ._workflow import SamplingInterrupted as SamplingInterrupted
from ._workflow import check_least_squares as check_least_squares
from ._workflow import run_and_summarise as run_and_summarise
from ._workflow import sample as sample
from ._workflow import stored_steps as stored_steps

# griffe (mkdocstrings) documents an imported name only when it is listed here
__all__ = [
    "CHECK_EVERY",
    "TAU_STABILITY",
    "FLUSH_SECONDS",
    "PERSIST_SHARE",
    "CHUNK_STEPS",
    "DEFAULT_MIN_TAU_MULTIPLE",
    "MIN_ESS",
    "ACCEPTANCE_RANGE",
    "STUCK_WALKER",
    "CHAIN_GROUP",
    "META_GROUP",
    "FORMAT",
    "FORMAT_VERSION",
    "ChainError",
    "default_walkers",
    "BufferedHDFBackend",
    "Diagnostics",
    "autocorrelation_times",
    "burn_in",
    "diagnose",
    "initial_walkers",
    "REQUIRED_METADATA",
    "read_metadata",
    "write_metadata",
    "Chain",
    "load_chain",
    "SampleSettings",
    "Progress",
    "SampleRun",
    "deferred_interrupt",
    "run_sampler",
    "check_least_squares",
    "SampleResult",
    "SamplingInterrupted",
    "stored_steps",
    "sample",
    "run_and_summarise",
]
