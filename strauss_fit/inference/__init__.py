"""Uncertainty beyond the fit: the posterior, emcee sampling and summaries (the Laplace
approximation and the noise are below the fit, in `strauss_fit.stats`).

- `posterior`: likelihood, priors, the noise level, and a
  fit's problem rebuilt from its result;
- `sampler`: emcee runs, chain files, diagnostics, and
  `sample`, the whole sampling workflow;
- `summaries`: posterior summaries, the Laplace-versus-emcee
  comparison, degeneracy warnings in words.

Next in the flow: `strauss_fit.reporting`.
"""
