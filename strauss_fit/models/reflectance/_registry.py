"""The registry of reflectance models by name (as colour-science's ``*_METHODS`` dictionaries)."""

from __future__ import annotations

from types import MappingProxyType

from ...errors import StraussFitError
from ._base import ReflectanceModel
from ._blinn_phong import BlinnPhong
from ._cook_torrance import CookTorrance
from ._lambert import Lambert
from ._phong import Phong
from ._strauss import Strauss

#: Every reflectance model by its name (read-only).
REFLECTANCE_MODELS: MappingProxyType[str, ReflectanceModel] = MappingProxyType(
    {model.name: model for model in (Strauss(), Lambert(), Phong(), BlinnPhong(), CookTorrance())}
)


def reflectance_model(name: str) -> ReflectanceModel:
    """The model called ``name`` (a key of `REFLECTANCE_MODELS`); an unknown name is a
    one-line `StraussFitError` listing the names."""
    try:
        return REFLECTANCE_MODELS[name]
    except (KeyError, TypeError):
        raise StraussFitError(
            f"unknown reflectance model {name!r}; expected one of {', '.join(REFLECTANCE_MODELS)}"
        ) from None
