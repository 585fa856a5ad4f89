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
times more (36 ms against 7 ms per 64² target, measured). On an accelerator the items run
side by side (``jax.vmap``), each stopping at its own convergence (a finished item's state
is carried unchanged by the batched loop), which is where the batch fills the device.

While compiled work runs, Python runs too: the generators are split into *cohorts*
(:func:`cohort_devices`), and one cohort's decisions are taken while the others' compiled
calls run, JAX dispatching a call and returning at once (:class:`Pending`). On a CPU the
compiled calls go to CPU devices other than the first
(:func:`strauss_fit.runtime.use_cpu_cores`), since a device runs its work in order and
the small eager operations of the Python would otherwise wait behind a whole batch; with
cores to spare, cohorts run on several devices at once. Which cohort a generator belongs
to is fixed by its position, so that a run is repeatable.

A failure stays with its target: an exception raised inside one generator ends that
target only (its slot holds the exception), and a batched call that fails is retried item
by item, so that the item that broke it fails alone.
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Callable, Generator, Iterable
from dataclasses import dataclass
from typing import Any

import equinox as eqx
import jax
import numpy as np
from equinox.internal import Static

from .export_cache import ExportedKernel, kernel_identity
from .runtime import usable_cores

#: A fit (or any computation) written as steps: it yields :class:`Call` and receives results.
Steps = Generator["Call", Any, Any]


class Kernel:
    """A numeric function of array pytrees, run directly (``kernel(*args)``, jitted with
    equinox's filtered jit: arrays are traced, everything else is static) or over a batch
    of argument tuples of identical structure (:meth:`run_many`)."""

    def __init__(self, fn: Callable[..., Any], name: str | None = None):
        self.fn = fn
        self.name = name or getattr(fn, "__name__", "kernel")
        identity = kernel_identity(fn)  # None: not kept on disk (strauss_fit.export_cache)
        self._one = _DispatchingJit(fn, identity)
        self._many = _DispatchingJit(self._batched, identity and identity + "[many]")

    def __repr__(self) -> str:
        return f"Kernel({self.name})"

    def __call__(self, *args: Any) -> Any:
        return self._one(*args)

    def run_call(self, call: Call) -> Any:
        """``self(*call.args)``, reusing the call's partition of its arguments."""
        return self._one.call_parts(call.args, call.parts)

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
        return self.start_many(argument_lists, sequential)()

    def start_many(
        self, argument_lists: list[tuple], sequential: bool | None = None, parts: list[tuple] | None = None
    ) -> Pending:
        """:meth:`run_many` started: JAX dispatches the compiled call and returns at once
        (see :class:`Pending`). ``parts``: the argument tuples already partitioned
        (:attr:`Call.parts`)."""
        if sequential is None:
            sequential = jax.default_backend() == "cpu"
        if parts is None:
            parts = [eqx.partition(args, eqx.is_array) for args in argument_lists]
        static = parts[0][1]
        stacked = jax.tree.map(lambda *leaves: np.stack([np.asarray(x) for x in leaves]), *[p[0] for p in parts])
        running = self._many(stacked, static, bool(sequential))

        def results() -> list[Any]:
            out = jax.device_get(running)
            return [jax.tree.map(lambda leaf, i=i: leaf[i], out) for i in range(len(argument_lists))]

        return Pending(results, running)


class Pending:
    """Compiled work dispatched and maybe still running: :meth:`ready` says whether it has
    finished (without waiting); calling it waits and returns the results (a list, one per
    call)."""

    def __init__(self, results: Callable[[], list[Any]], running: Any = None):
        self._results = results
        self._running = running

    def ready(self) -> bool:
        return all(leaf.is_ready() for leaf in jax.tree.leaves(self._running) if isinstance(leaf, jax.Array))

    def __call__(self) -> list[Any]:
        return self._results()


class _DispatchingJit:
    """``jax.jit`` over the array leaves of the arguments, everything else static — as
    equinox's ``filter_jit``, but returning as soon as JAX has dispatched the call:
    ``filter_jit`` waits for every call to finish (to word its runtime errors), which
    would keep the Python of other targets from running meanwhile (:func:`run_batched`).
    A runtime error then surfaces when the result is read. Arguments whose static part
    cannot be hashed go through ``filter_jit``."""

    def __init__(self, fn: Callable[..., Any], identity: str | None = None):
        self._filtered = eqx.filter_jit(fn)
        # traced and lowered programs kept on disk (strauss_fit.export_cache), where enabled
        self._exported = ExportedKernel(fn, identity) if identity is not None else None

        def arrays_only(dynamic: Any, static: Any) -> Any:
            arrays, rest = eqx.partition(fn(*eqx.combine(dynamic, static)), eqx.is_array)
            return arrays, Static(rest)

        arrays_only.__name__ = getattr(fn, "__name__", "kernel")
        self._jitted = jax.jit(arrays_only, static_argnums=1)

    def __call__(self, *args: Any) -> Any:
        return self.call_parts(args, eqx.partition(args, eqx.is_array))

    def call_parts(self, args: tuple, parts: tuple[Any, Any]) -> Any:
        """The call on ``args`` already partitioned into ``parts`` (:attr:`Call.parts`)."""
        dynamic, static = parts
        try:
            hash(static)
        except TypeError:
            return self._filtered(*args)
        if self._exported is not None:
            result = self._exported.call(dynamic, static)
            if result is not None:
                return result
        arrays, rest = self._jitted(dynamic, static)
        return eqx.combine(arrays, rest.value)


@dataclass(frozen=True)
class Call:
    """A request for ``kernel(*args)``, yielded by a step generator."""

    kernel: Kernel
    args: tuple

    @functools.cached_property
    def parts(self) -> tuple[Any, Any]:
        """The arguments' array part and the rest (``eqx.partition``), split once: grouping
        and stacking both need them."""
        return eqx.partition(self.args, eqx.is_array)


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
    dynamic, static = call.parts
    leaves, treedef = jax.tree.flatten(dynamic)
    try:
        static_key = hash(static), static
    except TypeError:  # an unhashable static part cannot be grouped: run it alone
        return (call.kernel, id(call))
    return (call.kernel, static_key, treedef, tuple((x.shape, x.dtype.str) for x in leaves))


class _Failed:
    def __init__(self, error: BaseException):
        self.error = error


def run_batched(
    step_lists: Iterable[Steps],
    *,
    sequential: bool | None = None,
    on_done: Callable[[int, Any], None] | None = None,
    max_batch: int | None = None,
    cohorts: int | None = None,
    python_bound: bool = True,
) -> list[Any]:
    """Drive many step generators together (see the module docstring). Returns, in order,
    each generator's value, or the exception that ended it. ``on_done(index, value)`` is
    called as each finishes (value: the result or the exception). ``max_batch`` caps the
    items of one compiled call (memory). ``cohorts``: into how many groups the generators
    are split (default :func:`cohort_devices`, which ``python_bound`` informs); each
    advances while the others' compiled calls run."""
    generators = list(step_lists)
    results: list[Any] = [None] * len(generators)
    devices = cohort_devices(len(generators), cohorts, python_bound=python_bound)
    count = len(devices)
    # generator i belongs to cohort i % count: fixed by position, so that a run is repeatable
    pending: list[dict[int, Call]] = [{} for _ in range(count)]
    running: list[list[tuple[list[int], Pending]]] = [[] for _ in range(count)]

    def advance(index: int, value: Any) -> None:
        generator = generators[index]
        try:
            request = generator.throw(value.error) if isinstance(value, _Failed) else generator.send(value)
        except StopIteration as done:
            finish(index, done.value)
        except Exception as error:  # the target fails alone
            finish(index, error)
        else:
            pending[index % count][index] = request

    def finish(index: int, value: Any) -> None:
        results[index] = value
        if on_done is not None:
            on_done(index, value)

    def start(cohort: int) -> None:
        calls = pending[cohort]
        groups: dict[Any, list[int]] = {}
        for index, call in calls.items():
            groups.setdefault(batch_key(call), []).append(index)
        for members in groups.values():
            for chunk in _chunks(members, max_batch):
                running[cohort].append((chunk, _start_group([calls[i] for i in chunk], sequential, devices[cohort])))
        calls.clear()

    def collect(cohort: int) -> None:
        batches, running[cohort] = running[cohort], []
        for chunk, outputs in batches:
            for index, output in zip(chunk, outputs()):
                advance(index, output)
        start(cohort)

    for index in range(len(generators)):
        advance(index, None)
    for cohort in range(count):
        start(cohort)
    turn = 0
    while any(running):
        # the first cohort whose work is done, in turn; none yet: wait for the next in turn
        busy = [c for c in (*range(turn, count), *range(turn)) if running[c]]
        done = next((c for c in busy if all(outputs.ready() for _, outputs in running[c])), busy[0])
        collect(done)
        turn = (done + 1) % count
    return results


def cohort_devices(items: int, cohorts: int | None = None, *, python_bound: bool = True) -> list[Any]:
    """The device of each cohort of :func:`run_batched` (None: JAX's default device).

    Two cohorts at least, so that one cohort's Python (the fits' decisions, the noise
    estimate) runs while the other's compiled calls do: JAX dispatches a compiled call
    and returns at once. But a device runs its work in order, so a small eager JAX
    operation in that Python (``jnp.asarray``, ``.at[].set``) would wait for the batch
    running on the same device. On a CPU with several devices
    (:func:`strauss_fit.runtime.use_cpu_cores`: one per core, up to eight, and one more)
    the batches therefore run on the devices after the first, which is left to the eager
    operations, one cohort per device: as many devices as there are cores less the one
    the Python needs (``python_bound``, a fit's case), or as cores (a conversion's, almost
    all compiled work). Each device compiles its own programs (and holds them: memory
    mappings, :mod:`strauss_fit.runtime`), so a batch uses a device only from
    :data:`ITEMS_PER_DEVICE` items per device on; a smaller batch runs on the default
    device, as a single fit does, sharing its programs."""
    devices = jax.local_devices() if jax.default_backend() == "cpu" else []
    if cohorts is None:
        cohorts = 2
        cores = usable_cores() - 1 if python_bound else usable_cores()
        wanted = min(len(devices) - 1, max(cores, 1), items // ITEMS_PER_DEVICE)
        if wanted >= 1:
            compute = devices[1 : 1 + wanted]
            cohorts = max(cohorts, len(compute))
            return [compute[c % len(compute)] for c in range(cohorts)]
    return [None] * max(1, min(cohorts, items))


#: Items per CPU device from which :func:`run_batched` spreads a batch over one more device.
ITEMS_PER_DEVICE = 16


def _chunks(items: list[int], size: int | None) -> list[list[int]]:
    if not size or len(items) <= size:
        return [items]
    return [items[i : i + size] for i in range(0, len(items), size)]


def _power_of_two_parts(count: int) -> list[int]:
    """``count`` as a sum of distinct powers of two, largest first (37 → 32, 4, 1)."""
    return [1 << bit for bit in range(count.bit_length() - 1, -1, -1) if count >> bit & 1]


def _start_group(calls: list[Call], sequential: bool | None, device: Any = None) -> Pending:
    """Start the calls of one structure on ``device`` (None: the default): their results
    come from batched calls, or, for a single call or when a batch fails, from one call
    each (each failure then goes to its own target).

    Batches come in power-of-two sizes only, so that the programs compiled per kernel
    stay few (at most seven up to 64 items) however the targets split up as their fits
    diverge: sequentially (a CPU) a group of 37 runs as 32 + 4 + 1 items, side by side (an
    accelerator) it is padded to 64 with copies of its first item, whose results are
    dropped."""
    if sequential is None:
        sequential = jax.default_backend() == "cpu"
    placed = jax.default_device(device) if device is not None else contextlib.nullcontext()

    def one_by_one() -> list[Any]:
        outputs = []
        with placed:
            for call in calls:
                try:
                    outputs.append(call.kernel.run_call(call))
                except Exception as error:
                    outputs.append(_Failed(error))
        return outputs

    if len(calls) == 1:
        outputs = one_by_one()
        return Pending(lambda: outputs, outputs)
    try:
        with placed:
            if not sequential:
                size = 1 << (len(calls) - 1).bit_length()
                padded = calls + [calls[0]] * (size - len(calls))
                parts = [calls[0].kernel.start_many([c.args for c in padded], sequential, [c.parts for c in padded])]
            else:
                parts, first = [], 0
                for part in _power_of_two_parts(len(calls)):
                    chunk = calls[first : first + part]
                    if part == 1:
                        single = chunk[0].kernel.run_call(chunk[0])
                        parts.append(Pending(lambda single=single: [single], single))
                    else:
                        parts.append(
                            chunk[0].kernel.start_many([c.args for c in chunk], sequential, [c.parts for c in chunk])
                        )
                    first += part
    except Exception:  # one item broke the batch: find it by running them alone
        return Pending(one_by_one)

    def results() -> list[Any]:
        try:
            return [output for part in parts for output in part()][: len(calls)]
        except Exception:  # it broke while running
            return one_by_one()

    return Pending(results, [part._running for part in parts])
