"""Write the bundled latitude-longitude environment ``environments/studio.exr``.

A synthetic studio: a blue-to-white sky, a warm ground, two bright soft boxes and vertical
stripes along the horizon, so that a mirror-like sphere shows recognisable reflections. Run
``python -m data_synth.make_environment`` to regenerate it (deterministic).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

HEIGHT, WIDTH = 64, 128
OUTPUT = Path(__file__).with_name("environments") / "studio.exr"


def studio() -> np.ndarray:
    """The environment as linear RGB, (HEIGHT, WIDTH, 3)."""
    polar = (np.arange(HEIGHT) + 0.5) / HEIGHT * np.pi  # 0 at +y (top)
    azimuth = ((np.arange(WIDTH) + 0.5) / WIDTH - 0.5) * 2 * np.pi  # 0 toward -z
    theta, phi = np.meshgrid(polar, azimuth, indexing="ij")
    up = np.cos(theta)
    sky = np.where(
        up[..., None] > 0,
        (1 - up[..., None]) * np.array([0.9, 0.95, 1.0]) + up[..., None] * np.array([0.2, 0.4, 0.9]),
        np.array([0.35, 0.25, 0.15]),
    )
    stripes = 0.5 + 0.5 * np.sign(np.sin(8 * phi))
    band = (np.abs(up) < 0.15)[..., None] * stripes[..., None] * np.array([0.3, 0.3, 0.3])
    boxes = np.zeros_like(sky)
    for centre_phi, centre_up, power in ((0.9, 0.5, 8.0), (-1.6, 0.3, 4.0)):
        inside = (np.abs(phi - centre_phi) < 0.3) & (np.abs(up - centre_up) < 0.15)
        boxes += inside[..., None] * power
    return sky + band + boxes


def main() -> None:
    from strauss_fit.io.images import write_image

    OUTPUT.parent.mkdir(parents=True, exist_ok=True)
    write_image(OUTPUT, studio(), force=True)
    print(f"wrote {OUTPUT}")


if __name__ == "__main__":
    main()
