"""Statistics a fit needs, below the fit in the layers (docs/development.md#layers):

- `laplace`: JᵀJ → covariance → deviations and correlations, the
  noise sandwich (the one home of those computations);
- `noise`: the target's noise, estimated from the image or read
  from its sidecar, and the noise model at a radiance.

They take arrays and problems, never fits: `strauss_fit.fitting` uses them, and
`strauss_fit.inference` (the posterior and sampling) sits above both. The perceptual
equivalence ranges refit with a parameter held, so they live in the fit
(`strauss_fit.fitting.equivalence`).

Next in the flow: `strauss_fit.rendering` is below; `strauss_fit.fitting` above.
"""
