"""The intuitive-parameter study: does Strauss's parameterisation beat Phong's, in numbers?

- :mod:`~strauss_fit.study.study`: :func:`~strauss_fit.study.study.run_study` and its four
  parts (consistency, independence, uniformity, expressiveness).

Its report is :mod:`strauss_fit.reporting.study_report`.
"""
