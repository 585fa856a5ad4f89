"""Least-squares recovery of the Strauss parameters from an image.

In the order a fit uses them:

- :mod:`~strauss_fit.fitting.options`: :class:`~strauss_fit.fitting.options.FitOptions` and the
  quality presets (shared with sampling and conversions);
- :mod:`~strauss_fit.fitting.parameters`: which quantities are free, and the smooth transforms
  that keep them in range;
- :mod:`~strauss_fit.fitting.problem`: the prepared scene at the usable pixels and the residual;
- :mod:`~strauss_fit.fitting.guess`: the closed-form first guess;
- :mod:`~strauss_fit.fitting.identifiability`: which parameters the image constrains, and why not;
- :mod:`~strauss_fit.fitting.starts`: the starting points and the scan over n;
- :mod:`~strauss_fit.fitting.solvers`: the optimistix solvers, the batched starts and the
  bound-aware polish;
- :mod:`~strauss_fit.fitting.equivalence`: the perceptual equivalence ranges (refits with a
  parameter held);
- :mod:`~strauss_fit.fitting.result`: :class:`~strauss_fit.fitting.result.FitResult` and its JSON;
- :mod:`~strauss_fit.fitting.api`: :func:`~strauss_fit.fitting.api.fit`, which puts them together.

The package is ``fitting`` and the function ``strauss_fit.fit`` (``fit(scene, target)``):
distinct names, so that importing a module of the package never hides the function.

Next in the flow: :mod:`strauss_fit.inference` (uncertainty).
"""
