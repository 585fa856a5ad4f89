"""Converting materials between Phong and Strauss by fitting sphere renders.

- :mod:`~strauss_fit.convert.converter`: the batch converter and the entry points
  :func:`~strauss_fit.convert.converter.phong_to_strauss`,
  :func:`~strauss_fit.convert.converter.strauss_to_phong` and
  :func:`~strauss_fit.convert.converter.convert_files`;
- :mod:`~strauss_fit.convert.phong_fit`: least squares of Phong's identifiable parameters
  and the vectorised chunk solver both directions use.
"""
