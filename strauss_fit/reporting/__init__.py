"""Reports: self-contained HTML pages and Markdown with PNG figures.

- :mod:`~strauss_fit.reporting.document`: the one HTML/Markdown document builder;
- :mod:`~strauss_fit.reporting.figures`: the one figure helper (matplotlib Agg → PNG);
- :mod:`~strauss_fit.reporting.fit_report`: the uncertainty report of a fit and its chain;
- :mod:`~strauss_fit.reporting.capture_report`: the report of a capture's fit (per-light grid);
- :mod:`~strauss_fit.reporting.study_report`: the study's report and its conclusions.
"""
