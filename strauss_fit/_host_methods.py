"""Methods of equinox modules that run on the host only, read without equinox's wrapper.

equinox makes every method read from a module instance a ``BoundMethod`` — itself a module,
so that ``jax.jit(module.method)`` treats the instance as a pytree argument. Building one
runs a module's whole ``__init__`` machinery: about 0.2 ms, and a warm 256² fit read 42 such
methods (``Problem.real``, ``Material.to_dict``, ``Lights.present``…): 8.6 ms of its
140 ms (measured 2026-12-04). `host_method` marks a method that is never handed to a JAX
transformation as a function: reading it from an instance gives a ``functools.partial``
of the function and the instance (not a ``types.MethodType``, which is what equinox wraps).
Methods that compiled code calls or that are passed to ``jax.jit``, ``jax.jacfwd`` or a
solver (``Problem.residual``, the renders) stay plain methods.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, Generic, TypeVar

_Function = TypeVar("_Function", bound=Callable[..., Any])


class host_method(Generic[_Function]):  # noqa: N801 - used as a decorator, as ``property`` is
    """Decorator: the method, read from an instance, as a plain partial (see the module)."""

    def __init__(self, function: _Function):
        self.function = function
        functools.update_wrapper(self, function)

    def __get__(self, instance: Any, owner: type | None = None) -> Any:
        if instance is None:
            return self.function
        return functools.partial(self.function, instance)
