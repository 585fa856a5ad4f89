"""The losses a fit can minimise, as plain data: one registry (`LOSS_REGISTRY`) that
every place choosing or describing a loss reads, instead of lists of names spelled out
in each.

A `Loss` holds what the code branches on: whether the loss is robust (it scales
each residual by its value's own noise), whether it folds into the compiled kernel (and
its code there, see `strauss_fit.fitting.problem.Problem.kernel_form`), and a one-line
description for help texts. The numerical side — how each loss transforms the residuals —
is `strauss_fit.fitting.problem.LOSS_RESIDUALS`, keyed by the same names (a test checks
that the two agree).

Why two modules: this one imports the standard library only, so that the command line
builds its ``--loss`` choices and help without importing NumPy or JAX (``strauss-fit
--help`` stays fast); `strauss_fit.fitting.problem` needs JAX for the residuals.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import StraussFitError


@dataclass(frozen=True)
class Loss:
    """One loss a fit can minimise: what the code branches on, not how it computes."""

    #: The loss's name, as ``FitOptions.loss``, ``--loss`` and a result's ``solver.loss`` spell it.
    name: str
    #: One line for help texts: what the residual is.
    description: str
    #: Scales each residual by its value's own noise (``Problem.weights``): a function of the
    #: residual in noise units, whose fit needs the image's noise.
    robust: bool = False
    #: Its index among the losses that share one compiled program, the loss held as data
    #: (``Problem.loss_code``); None: the loss is part of the program's structure.
    code: int | None = None

    @property
    def folded(self) -> bool:
        """Whether problems of this loss share their compiled programs
        (`strauss_fit.fitting.problem.Problem.kernel_form`)."""
        return self.code is not None


#: Plain least squares on linear RGB: residuals as they are, the loss every statistic of a
#: fit assumes (the Laplace covariance, the sampler's likelihood).
LEAST_SQUARES = "linear"
#: ``FitOptions.loss``'s automatic choice: `LEAST_SQUARES`, then
#: `strauss_fit.fitting.options.MISMATCH_LOSS` when the model visibly cannot reproduce the target.
AUTO = "auto"

#: Every loss a fit can minimise, by name, in the order help texts list them. The codes of
#: the folded losses are their indices into `FOLDED_LOSSES` (0, 1, 2, ...).
LOSS_REGISTRY: dict[str, Loss] = {
    loss.name: loss
    for loss in (
        Loss(LEAST_SQUARES, "least squares on linear RGB", code=0),
        Loss(
            "perceptual",
            "least squares on the cube root of the values (CIELAB's lightness curve): dark regions count as the "
            "eye sees them",
        ),
        Loss(
            "huber",
            "Huber's robust loss of the residual in noise units, quadratic up to 1.345 and linear beyond",
            robust=True,
            code=1,
        ),
        Loss(
            "cauchy",
            "Cauchy's robust loss of the residual z in noise units, (c²/2) log(1 + (z/c)²) with c = 2.385",
            robust=True,
            code=2,
        ),
    )
}

#: The losses a fit can minimise (names of `LOSS_REGISTRY`).
LOSSES: tuple[str, ...] = tuple(LOSS_REGISTRY)
#: The losses that scale each residual by its value's own noise (``weights``).
ROBUST_LOSSES: tuple[str, ...] = tuple(name for name, loss in LOSS_REGISTRY.items() if loss.robust)
#: The losses whose problems share their compiled programs
#: (`strauss_fit.fitting.problem.Problem.kernel_form`), in the order of their codes.
FOLDED_LOSSES: tuple[str, ...] = tuple(
    sorted((name for name, loss in LOSS_REGISTRY.items() if loss.folded), key=lambda name: LOSS_REGISTRY[name].code)
)
#: What ``FitOptions.loss`` (and ``--loss``) accepts: `AUTO` and every loss.
LOSS_CHOICES: tuple[str, ...] = (AUTO, *LOSSES)


def loss_named(name: str) -> Loss:
    """The `Loss` called ``name``.

    Raises:
        StraussFitError: ``name`` is no loss of `LOSS_REGISTRY` (the message lists them).
    """
    try:
        return LOSS_REGISTRY[name]
    except (KeyError, TypeError):  # TypeError: an unhashable value, as unknown as any other
        raise StraussFitError(f"unknown loss {name!r}; expected one of {', '.join(LOSSES)}") from None
