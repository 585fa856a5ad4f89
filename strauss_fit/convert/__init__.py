"""Converting materials between Phong and Strauss by fitting sphere renders.

- `converter`: the batch converter and the entry points
  `phong_to_strauss`,
  `strauss_to_phong` and
  `convert_files`;
- `phong_fit`: least squares of Phong's identifiable parameters
  and the vectorised chunk solver both directions use.

Behind the converter, private modules: the steps of each direction (``_to_strauss``:
Phong → Strauss, ``_to_phong``: Strauss → Phong), the closed-form guesses they start from
(``_guesses``), the Strauss problems of the conversion scene (``_problems``), the batch
driver (``_batches``) and what the results share (``_shared``). Their public names are
imported from `converter`.
"""
