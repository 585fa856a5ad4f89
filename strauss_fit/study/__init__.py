"""The intuitive-parameter study: does Strauss's parameterisation beat Phong's, in numbers?

- :mod:`~strauss_fit.study.study`: :func:`~strauss_fit.study.study.run_study` and its four
  parts (consistency, independence, uniformity, expressiveness);
- :mod:`~strauss_fit.study.real`: the parts on real reflectance, run when given the data —
  5. the MERL materials as Ngan et al. (2005) fitted them, rendered with bbm's
  NganCookTorrance BRDF (:mod:`~strauss_fit.study._bbm`) and fitted by Strauss and Phong;
  6. real photographs (held-out error and stability of every capture model);
- :mod:`~strauss_fit.study.real_report`: their verdicts and report sections, and
  :func:`~strauss_fit.study.real_report.write_study_report`, which writes the whole report.

The report of the four parts is :mod:`strauss_fit.reporting.study_report`.
"""
