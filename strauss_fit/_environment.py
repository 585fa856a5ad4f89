"""How the package reads its environment settings (a leaf: no imports of its own), shared
by `strauss_fit.runtime` and `strauss_fit.export_cache`."""

from __future__ import annotations


def turned_off(setting: str | None) -> bool:
    """Whether an environment setting says ``off`` (or ``none``, ``0``, empty); unset is not."""
    return setting is not None and setting.strip().lower() in ("", "off", "none", "0")
