"""Files: images, fit targets, material libraries, and safe writes.

- `files`: atomic writers that refuse to overwrite without ``force``,
  and JSON reading with one-line errors;
- `images`: reading and writing images (OpenImageIO; sRGB for LDR);
- `targets`: reference images to fit, masks, matching a scene's camera;
- `mtl`: Wavefront ``.mtl`` libraries;
- `material_tables`: material lists in and out of the conversions.
"""
