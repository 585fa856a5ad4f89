"""Reports: self-contained HTML pages and Markdown with PNG figures.

- `document`: the one HTML/Markdown document builder;
- `figures`: the one figure helper (matplotlib Agg → PNG);
- `fit_report`: the uncertainty report of a fit and its chain;
- `capture_report`: the report of a capture's fit (per-light grid);
- `study_report`: the study's report and its conclusions.
"""
