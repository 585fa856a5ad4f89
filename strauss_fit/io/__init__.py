"""Files: images, fit targets, material libraries, and safe writes.

- :mod:`~strauss_fit.io.files`: atomic writers that refuse to overwrite without ``force``,
  and JSON reading with one-line errors;
- :mod:`~strauss_fit.io.images`: reading and writing images (OpenImageIO; sRGB for LDR);
- :mod:`~strauss_fit.io.targets`: reference images to fit, masks, matching a scene's camera;
- :mod:`~strauss_fit.io.mtl`: Wavefront ``.mtl`` libraries;
- :mod:`~strauss_fit.io.material_tables`: material lists in and out of the conversions.
"""
