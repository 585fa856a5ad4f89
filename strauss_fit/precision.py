"""Float64 without a global switch: the precision scope of strauss-fit.

JAX computes in float32 unless ``jax_enable_x64`` is on. strauss-fit needs float64 (fits
solve to relative tolerances far below float32's 1.2e-7, and the renderer's default
precision is float64), but importing it must not change other JAX code in the same
process. So ``import strauss_fit`` leaves ``jax_enable_x64`` as it was, and the library
switches float64 on only *inside* its own calls:

- every public entry point that creates or computes arrays (scene loading and
  `parse_scene`, constructing a
  `Material` or
  `PhongMaterial`, `render`,
  `render_phong`, `fit`, the
  posterior and the sampler, the conversions, the study, the reports) is decorated with
  `uses_float64`, which runs it inside `float64`;
- `float64` is a context manager (``jax.enable_x64(True)``) for your own code.

The rule for users. Arrays created inside a scope *stay* float64 afterwards, but JAX
operations run *outside* a scope canonicalise their inputs to float32 (``x + 1``,
``jnp.asarray(x, float)``, a jitted call). Results the library returns are therefore best
converted with ``np.asarray`` (exact), or further JAX work done inside ``with
strauss_fit.float64():``::

    import strauss_fit as sf

    scene = sf.load_scene("data_synth/scenes/two_lights.toml")
    image, mask = sf.render(scene)          # float64, whatever jax_enable_x64 says
    with sf.float64():
        brighter = image * 2                # float64 too
    darker = image / 2                      # float32: outside the scope

Pass Python numbers or NumPy arrays to the library rather than JAX arrays you created
outside a scope (those are already float32). Code that wants float64 everywhere, as the
benchmarks do, simply runs inside one ``with float64():`` block.

Scopes nest, and entering one costs about a microsecond. Compiled functions are cached
per precision, so a function used inside and outside a scope is compiled once for each.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

import jax

F = TypeVar("F", bound=Callable[..., Any])


@contextmanager
def float64() -> Iterator[None]:
    """Run the block with JAX's float64 support on (``jax.enable_x64(True)``), restoring
    the previous setting afterwards.

    Examples:
        >>> import jax.numpy as jnp
        >>> import strauss_fit as sf
        >>> with sf.float64():
        ...     print(jnp.ones(2).dtype)
        float64
    """
    with jax.enable_x64(True):
        yield


def uses_float64(function: F) -> F:
    """Decorator: run ``function`` inside `float64` (see the module docstring).

    Applied to every public entry point of the library that creates or computes arrays.
    """

    @functools.wraps(function)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with jax.enable_x64(True):
            return function(*args, **kwargs)

    return wrapper  # type: ignore[return-value]
