"""Least-squares recovery of the Strauss parameters from an image.

In the order a fit uses them:

- `options`: `FitOptions` and the
  quality presets (shared with sampling and conversions);
- `parameters`: which quantities are free, and the smooth transforms
  that keep them in range;
- `problem`: the prepared scene at the usable pixels and the residual;
- `guess`: the closed-form first guess;
- `identifiability`: which parameters the image constrains, and why not;
- `starts`: the starting points and the scan over n;
- `solvers`: the optimistix solvers, the batched starts and the
  bound-aware polish;
- `equivalence`: the perceptual equivalence ranges (refits with a
  parameter held);
- `result`: `FitResult` and its JSON;
- `api`: `fit`, which puts them together.

The package is ``fitting`` and the function ``strauss_fit.fit`` (``fit(scene, target)``):
distinct names, so that importing a module of the package never hides the function.

Next in the flow: `strauss_fit.inference` (uncertainty).
"""
