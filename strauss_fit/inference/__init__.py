"""Uncertainty beyond the fit: the posterior, emcee sampling and summaries (the Laplace
approximation and the noise are below the fit, in :mod:`strauss_fit.stats`).

- :mod:`~strauss_fit.inference.posterior`: likelihood, priors, the noise level, and a
  fit's problem rebuilt from its result;
- :mod:`~strauss_fit.inference.sampler`: emcee runs, chain files, diagnostics, and
  :func:`~strauss_fit.inference.sampler.sample`, the whole sampling workflow;
- :mod:`~strauss_fit.inference.summaries`: posterior summaries, the Laplace-versus-emcee
  comparison, degeneracy warnings in words.

Next in the flow: :mod:`strauss_fit.reporting`.
"""
