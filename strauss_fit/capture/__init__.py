"""Captures: many photographs of one sample sphere under several lights.

The flow: a capture is described (`read_capture`: a manifest, a DiLiGenT folder, or
image files with a lights file), its sphere found in the frame and its pixels read
(`load_samples`), and then fitted (`strauss_fit.fitting.capture_result.fit_capture`).
Lights can be estimated from photographs of a mirror ball (`estimate_lights`).
See docs/captures.md.
"""

from ._manifest import (
    CameraSpec,
    Capture,
    CaptureImage,
    CaptureLight,
    capture_from_images,
    capture_inputs,
    open_capture,
    read_capture,
    read_lights_file,
)
from ._mirror import LightEstimate, estimate_lights, lights_toml
from ._samples import CaptureSamples, load_samples
from ._sphere import Camera, Circle

__all__ = [
    "Camera",
    "CameraSpec",
    "Capture",
    "CaptureImage",
    "CaptureLight",
    "CaptureSamples",
    "Circle",
    "LightEstimate",
    "capture_from_images",
    "capture_inputs",
    "estimate_lights",
    "lights_toml",
    "load_samples",
    "open_capture",
    "read_capture",
    "read_lights_file",
]
