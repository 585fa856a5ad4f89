"""The intuitive-parameter study: does Strauss's parameterisation beat Phong's, in numbers?

- `study`: `run_study` and its four
  parts (consistency, independence, uniformity, expressiveness);
- `real`: the parts on real reflectance, run when given the data —
  5. the MERL materials as Ngan et al. (2005) fitted them, rendered with bbm's
  NganCookTorrance BRDF (`_bbm`) and fitted by Strauss and Phong;
  6. real photographs (held-out error and stability of every capture model);
- `real_report`: their verdicts and report sections, and
  `write_study_report`, which writes the whole report.

The report of the four parts is `strauss_fit.reporting.study_report`.
"""
