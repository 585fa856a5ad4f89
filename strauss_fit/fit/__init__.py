"""Least-squares recovery of the Strauss parameters from an image.

In the order a fit uses them:

- :mod:`~strauss_fit.fit.options`: :class:`~strauss_fit.fit.options.FitOptions` and the
  quality presets (shared with sampling and conversions);
- :mod:`~strauss_fit.fit.parameters`: which quantities are free, and the smooth transforms
  that keep them in range;
- :mod:`~strauss_fit.fit.problem`: the prepared scene at the usable pixels and the residual;
- :mod:`~strauss_fit.fit.guess`: the closed-form first guess;
- :mod:`~strauss_fit.fit.identifiability`: which parameters the image constrains, and why not;
- :mod:`~strauss_fit.fit.starts`: the starting points and the scan over n;
- :mod:`~strauss_fit.fit.solvers`: the optimistix solvers, the batched starts and the
  bound-aware polish;
- :mod:`~strauss_fit.fit.equivalence`: the perceptual equivalence ranges (refits with a
  parameter held);
- :mod:`~strauss_fit.fit.result`: :class:`~strauss_fit.fit.result.FitResult` and its JSON;
- :mod:`~strauss_fit.fit.api`: :func:`~strauss_fit.fit.api.fit`, which puts them together.

Note: ``strauss_fit.fit`` as an attribute of the package is the *function*
(``strauss_fit.fit(scene, target)``); import the modules with
``from strauss_fit.fit import options`` or ``from strauss_fit.fit.options import FitOptions``.

Next in the flow: :mod:`strauss_fit.inference` (uncertainty).
"""
