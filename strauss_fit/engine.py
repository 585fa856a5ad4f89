r"""Running a fit's numeric work for one target, or batched across many.

A fit is mostly Python decisions (which parameters to free, which bounds to pin, whether
to refit) around a handful of compiled numeric *kernels* (a solve from some starts, a
Jacobian, a render). The fit is written once, as a generator of *steps*
(:func:`strauss_fit.fit.api.fit_steps`): wherever it needs numeric work it yields a
:class:`Call` — a :class:`Kernel` and its arguments — and receives the result.

- :func:`run` drives one such generator, calling each kernel directly: that is
  :func:`strauss_fit.fit` (one target).
- :func:`run_batched` drives many at once: it collects the pending calls of all of them,
  groups the calls of the same kernel whose arguments have the same structure (the same
  static settings, the same array shapes and dtypes — the targets of one scene and image
  size), stacks their arrays and runs each group as *one* compiled call over the batch,
  then hands every generator its own slice of the result. That is
  :func:`strauss_fit.fit_many`: the per-target Python decisions stay exactly those of a
  single fit, while the compiled work, its dispatch and its compilation are shared.

How a batch runs: on a CPU one item after the other inside the compiled program
(``jax.lax.map``): under ``vmap`` every iteration of a solver's loop would run every item's
branches and continue until the slowest item converged, which on two cores cost five
times more (36 ms against 7 ms per 64² target, measured); on an accelerator the items run
side by side (``jax.vmap``), each stopping at its own convergence (a finished item's state
is carried unchanged by the batched loop), which is where the batch fills the device.

A failure stays with its target: an exception raised inside one generator ends that
target only (its slot holds the exception), and a batched call that fails is retried item
by item, so that the item that broke it fails alone.
"""

from __future__ import annotations

from collections.abc import Callable, Generator, Iterable
from dataclasses import dataclass
from typing import Any

import equinox as eqx
import jax
import numpy as np

#: A fit (or any computation) written as steps: it yields :class:`Call` and receives results.
Steps = Generator["Call", Any, Any]


class Kernel:
    """A numeric function of array pytrees, run directly (``kernel(*args)``, jitted with
    equinox's filtered jit: arrays are traced, everything else is static) or over a batch
    of argument tuples of identical structure (:meth:`run_many`)."""

    def __init__(self, fn: Callable[..., Any], name: str | None = None):
        self.fn = fn
        self.name = name or getattr(fn, "__name__", "kernel")
        self._one = eqx.filter_jit(fn)
        self._many = eqx.filter_jit(self._batched)

    def __repr__(self) -> str:
        return f"Kernel({self.name})"

    def __call__(self, *args: Any) -> Any:
        return self._one(*args)

    def call(self, *args: Any) -> Call:
        """The request to run this kernel on ``args`` (what a step yields)."""
        return Call(self, args)

    def _batched(self, dynamic: Any, static: Any, sequential: bool) -> Any:
        def one(item):
            return self.fn(*eqx.combine(item, static))

        return jax.lax.map(one, dynamic) if sequential else jax.vmap(one)(dynamic)

    def run_many(self, argument_lists: list[tuple], sequential: bool | None = None) -> list[Any]:
        """The kernel on every argument tuple (all of one structure, see :func:`batch_key`),
        as one compiled call; results as NumPy pytrees, one per tuple."""
        if sequential is None:
            sequential = jax.default_backend() == "cpu"
        parts = [eqx.partition(args, eqx.is_array) for args in argument_lists]
        static = parts[0][1]
        stacked = jax.tree.map(lambda *leaves: np.stack([np.asarray(x) for x in leaves]), *[p[0] for p in parts])
        out = jax.device_get(self._many(stacked, static, bool(sequential)))
        return [jax.tree.map(lambda leaf, i=i: leaf[i], out) for i in range(len(argument_lists))]


@dataclass(frozen=True)
class Call:
    """A request for ``kernel(*args)``, yielded by a step generator."""

    kernel: Kernel
    args: tuple


def run(steps: Steps) -> Any:
    """Drive one step generator to its end, running every :class:`Call` directly, and
    return its value."""
    try:
        request = next(steps)
        while True:
            request = steps.send(request.kernel(*request.args))
    except StopIteration as done:
        return done.value


def batch_key(call: Call) -> Any:
    """What calls must share to run as one batch: the kernel, the static (non-array) part
    of the arguments and the shapes and dtypes of the array part."""
    dynamic, static = eqx.partition(call.args, eqx.is_array)
    leaves, treedef = jax.tree.flatten(dynamic)
    try:
        static_key = hash(static), static
    except TypeError:  # an unhashable static part cannot be grouped: run it alone
        return (call.kernel, id(call))
    return (call.kernel, static_key, treedef, tuple((np.shape(x), np.asarray(x).dtype.str) for x in leaves))


class _Failed:
    def __init__(self, error: BaseException):
        self.error = error


def run_batched(
    step_lists: Iterable[Steps],
    *,
    sequential: bool | None = None,
    on_done: Callable[[int, Any], None] | None = None,
    max_batch: int | None = None,
) -> list[Any]:
    """Drive many step generators together (see the module docstring). Returns, in order,
    each generator's value, or the exception that ended it. ``on_done(index, value)`` is
    called as each finishes (value: the result or the exception). ``max_batch`` caps the
    items of one compiled call (memory)."""
    generators = list(step_lists)
    results: list[Any] = [None] * len(generators)
    pending: dict[int, Call] = {}

    def advance(index: int, value: Any) -> None:
        generator = generators[index]
        try:
            request = generator.throw(value.error) if isinstance(value, _Failed) else generator.send(value)
        except StopIteration as done:
            finish(index, done.value)
        except Exception as error:  # the target fails alone
            finish(index, error)
        else:
            pending[index] = request

    def finish(index: int, value: Any) -> None:
        results[index] = value
        if on_done is not None:
            on_done(index, value)

    for index in range(len(generators)):
        advance(index, None)
    while pending:
        groups: dict[Any, list[int]] = {}
        for index, call in pending.items():
            groups.setdefault(batch_key(call), []).append(index)
        current = dict(pending)
        pending.clear()
        for members in groups.values():
            for chunk in _chunks(members, max_batch):
                outputs = _run_group([current[i] for i in chunk], sequential)
                for index, output in zip(chunk, outputs):
                    advance(index, output)
    return results


def _chunks(items: list[int], size: int | None) -> list[list[int]]:
    if not size or len(items) <= size:
        return [items]
    return [items[i : i + size] for i in range(0, len(items), size)]


def _power_of_two_parts(count: int) -> list[int]:
    """``count`` as a sum of distinct powers of two, largest first (37 → 32, 4, 1)."""
    return [1 << bit for bit in range(count.bit_length() - 1, -1, -1) if count >> bit & 1]


def _run_group(calls: list[Call], sequential: bool | None) -> list[Any]:
    """The results of calls of one structure: batched calls, or, for a single call or
    when a batch fails, one call each (each failure then goes to its own target).

    Batches come in power-of-two sizes only, so that the programs compiled per kernel
    stay few (at most seven up to 64 items) however the targets split up as their fits
    diverge: sequentially (a CPU) a group of 37 runs as 32 + 4 + 1 items, side by side (an
    accelerator) it is padded to 64 with copies of its first item, whose results are
    dropped."""
    if sequential is None:
        sequential = jax.default_backend() == "cpu"
    if len(calls) > 1:
        try:
            if not sequential:
                size = 1 << (len(calls) - 1).bit_length()
                padded = [c.args for c in calls] + [calls[0].args] * (size - len(calls))
                return calls[0].kernel.run_many(padded, sequential)[: len(calls)]
            outputs, start = [], 0
            for part in _power_of_two_parts(len(calls)):
                chunk = calls[start : start + part]
                if part == 1:
                    outputs.append(chunk[0].kernel(*chunk[0].args))
                else:
                    outputs.extend(chunk[0].kernel.run_many([c.args for c in chunk], sequential))
                start += part
            return outputs
        except Exception:  # one item broke the batch: find it by running them alone
            pass
    outputs = []
    for call in calls:
        try:
            outputs.append(call.kernel(*call.args))
        except Exception as error:
            outputs.append(_Failed(error))
    return outputs
