"""Converting materials between Phong and Strauss by fitting sphere renders.

- :mod:`~strauss_fit.convert.converter`: the batch converter and the entry points
  :func:`~strauss_fit.convert.converter.phong_to_strauss`,
  :func:`~strauss_fit.convert.converter.strauss_to_phong` and
  :func:`~strauss_fit.convert.converter.convert_files`;
- :mod:`~strauss_fit.convert.phong_fit`: least squares of Phong's identifiable parameters
  and the vectorised chunk solver both directions use.

Behind the converter, private modules: the steps of each direction (``_to_strauss``:
Phong → Strauss, ``_to_phong``: Strauss → Phong), the closed-form guesses they start from
(``_guesses``), the Strauss problems of the conversion scene (``_problems``), the batch
driver (``_batches``) and what the results share (``_shared``). Their public names are
imported from :mod:`~strauss_fit.convert.converter`.
"""
