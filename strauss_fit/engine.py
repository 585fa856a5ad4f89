r"""Running a fit's numeric work for one target, or batched across many.

A fit is mostly Python decisions (which parameters to free, which bounds to pin, whether
to refit) around a handful of compiled numeric *kernels* (a solve from some starts, a
Jacobian, a render). The fit is written once, as a generator of *steps*
(`strauss_fit.fitting.api.fit_steps`): wherever it needs numeric work it yields a
`Call` — a `Kernel` and its arguments — and receives the result.

- `run` drives one such generator, calling each kernel directly: that is
  `strauss_fit.fit` (one target).
- `run_batched` drives many at once: it collects the pending calls of all of them,
  groups the calls of the same kernel whose arguments have the same structure (the same
  static settings, the same array shapes and dtypes — the targets of one scene and image
  size) and runs each group, then hands every generator its own result. That is
  `strauss_fit.fit_many`: the per-target Python decisions stay exactly those of a
  single fit, while the compiled programs, and their compilation, are shared.

Compiled once, whatever the batch: a kernel's program depends on the structure of its
arguments only, never on how many targets a batch has or how they diverge. On a CPU every
call of a group runs alone, as the single-item program a single fit uses
(`SEQUENTIAL_BATCH`): a CPU runs a batch's items one after the other anyway, and
JAX dispatches each call without waiting. On an accelerator the group's items run side by
side (``jax.vmap``), each stopping at its own convergence (a finished item's state is
carried unchanged by the batched loop), in a batch padded to a power of four
(`batch_bucket`): a few programs per kernel, whatever the group's size. (Under
``vmap`` on a CPU every iteration of a solver's loop would run every item's branches until
the slowest item converged: five times slower on two cores, measured.) An argument may
fold what varies between calls into data (``kernel_form``, `split_arguments`): a
fit's problem holds its loss as data, so that least squares, Huber and Cauchy share their
programs. And all kernels run on one device (`compute_device`), a single fit's as a
batch's: a program belongs to its device, in memory and in the persistent compilation
cache.

While compiled work runs, Python runs too: the generators are split into *cohorts*
(`cohort_devices`), and one cohort's decisions are taken while the others' compiled
calls run, JAX dispatching a call and returning at once (`Pending`). On a CPU the
compiled calls go to CPU devices other than the first
(`strauss_fit.runtime.use_cpu_cores`), since a device runs its work in order and
the small eager operations of the Python would otherwise wait behind the kernels; with
cores to spare and many items, cohorts run on several devices at once. Which cohort a
generator belongs to is fixed by its position, so that a run is repeatable.

A failure stays with its target: an exception raised inside one generator ends that
target only (its slot holds the exception), and a batched call that fails is retried item
by item, so that the item that broke it fails alone (a single call's error reaches its own
generator when it reads the result).
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Callable, Generator, Iterable
from dataclasses import dataclass
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .export_cache import ExportedKernel, kernel_identity
from .runtime import usable_cores

#: A fit (or any computation) written as steps: it yields `Call` and receives results.
Steps = Generator["Call", Any, Any]


class _Static(eqx.Module):
    """The non-array part of a kernel's output, carried as static data: ``jax.jit`` returns
    only arrays, so the rest (``None`` partitions, Python numbers, strings) rides in the
    output's tree structure. Stored flat (its leaves and tree definition), so that it is
    hashable and compares by value. (equinox has the same idea as ``equinox.internal.Static``,
    a private API; this is the few lines it takes.)"""

    leaves: tuple = eqx.field(static=True)
    treedef: Any = eqx.field(static=True)

    @classmethod
    def of(cls, value: Any) -> _Static:
        leaves, treedef = jax.tree.flatten(value)
        return cls(tuple(leaves), treedef)

    @property
    def value(self) -> Any:
        return jax.tree.unflatten(self.treedef, self.leaves)


class Kernel:
    """A numeric function of array pytrees, run directly (``kernel(*args)``, jitted: arrays
    are traced, everything else is static) or over a batch of argument tuples of identical
    structure (`run_many`), on `compute_device` unless a device was chosen."""

    def __init__(self, fn: Callable[..., Any], name: str | None = None):
        self.fn = fn
        self.name = name or getattr(fn, "__name__", "kernel")
        identity = kernel_identity(fn)  # None: not kept on disk (strauss_fit.export_cache)
        self._one = _DispatchingJit(fn, identity)
        self._many = _DispatchingJit(self._batched, identity and identity + "[many]")

    def __repr__(self) -> str:
        return f"Kernel({self.name})"

    def __call__(self, *args: Any) -> Any:
        with on_compute_device():
            return self._one(*args)

    def run_call(self, call: Call) -> Any:
        """``self(*call.args)``, reusing the call's partition of its arguments."""
        with on_compute_device():
            return self._one.call_parts(call.args, call.parts)

    def call(self, *args: Any) -> Call:
        """The request to run this kernel on ``args`` (what a step yields)."""
        return Call(self, args)

    def _batched(self, stacked: list, shared: list, static: StaticPart, sequential: bool, count: Any) -> Any:
        def arguments(item: list) -> list:
            return [own if own is not None else common for own, common in zip(item, shared)]

        def one(item: list) -> Any:
            return self.fn(*static.rebuild(arguments(item)))

        if not sequential:
            return jax.vmap(one)(stacked)
        # One item after the other, the first ``count`` rows only: a batch padded to its
        # bucket (`batch_bucket`) spends nothing on the padding, and one program
        # serves every count up to the bucket's size. The results' shapes come from the
        # single-item program (``jax.jit``'s trace cache: usually traced already, by the
        # calls of one item, and reused by them otherwise), not from tracing ``fn`` again.
        size = next(x.shape[0] for x in stacked if x is not None)
        first = [None if x is None else jax.ShapeDtypeStruct(x.shape[1:], x.dtype) for x in stacked]
        shapes, rest = self._one.jitted.eval_shape(arguments(first), static)
        buffers = jax.tree.map(lambda leaf: jnp.zeros((size, *leaf.shape), leaf.dtype), shapes)

        def body(index: Any, buffers: Any) -> Any:
            item = [None if x is None else jax.lax.dynamic_index_in_dim(x, index, keepdims=False) for x in stacked]
            values, _ = eqx.partition(one(item), eqx.is_array)
            return jax.tree.map(lambda b, v: jax.lax.dynamic_update_index_in_dim(b, v, index, 0), buffers, values)

        # the non-array part of the results is the same for every item: returned once
        return eqx.combine(jax.lax.fori_loop(0, count, body, buffers), rest.value)

    def run_many(self, argument_lists: list[tuple], sequential: bool | None = None) -> list[Any]:
        """The kernel on every argument tuple (all of one structure, see `batch_key`),
        as one compiled call; results as NumPy pytrees, one per tuple."""
        return self.start_many(argument_lists, sequential)()

    def start_many(
        self,
        argument_lists: list[tuple],
        sequential: bool | None = None,
        parts: list[tuple] | None = None,
        size: int | None = None,
    ) -> Pending:
        """`run_many` started: JAX dispatches the compiled call and returns at once
        (see `Pending`). ``parts``: the argument tuples already partitioned
        (`Call.parts`). ``size``: the batch's compiled size, at least the number of
        tuples (default `batch_bucket`): the tuples are padded to it, so that every
        count up to it shares one program."""
        if sequential is None:
            sequential = jax.default_backend() == "cpu"
        if parts is None:
            parts = [split_arguments(args) for args in argument_lists]
        count = len(argument_lists)
        static = parts[0][1]
        with on_compute_device():
            if static is None:  # a static part that cannot be hashed: one call each
                outputs = [self._one.call_parts(args, part) for args, part in zip(argument_lists, parts)]
                return Pending(lambda: jax.device_get(outputs), outputs)
            size = batch_bucket(count) if size is None else max(size, count)
            # sequentially the padding is never run (see _batched): any values do; side by
            # side it is, so it holds copies of the first item (finite values, no spurious errors)
            stacked, shared = _stack_items([p[0] for p in parts], size, pad_with_first=not sequential)
            running = self._many(stacked, shared, static, bool(sequential), np.asarray(count, np.int32))

        def results() -> list[Any]:
            out = jax.device_get(running)
            return [jax.tree.map(lambda leaf, i=i: leaf[i] if _is_array(leaf) else leaf, out) for i in range(count)]

        return Pending(results, running)


def compute_device() -> Any:
    """The device kernels run on: on a CPU with several devices
    (`strauss_fit.runtime.use_cpu_cores`) the second, else None (JAX's default).

    Why not the first: a device runs its work in order, and the small eager operations of
    the Python around the kernels (``jnp.asarray``, ``.at[].set``) run on the first; they
    then never wait behind a kernel (see `cohort_devices`). Why one device for every
    kernel, a single fit's as a batch's: a compiled program belongs to its device, in memory
    and in the persistent compilation cache (whose key holds the device on a CPU). With
    single fits on the first device and batches on the second, a process (or a cache) that
    had seen one compiled everything again for the other."""
    if jax.default_backend() != "cpu":
        return None
    devices = jax.local_devices()
    return devices[1] if len(devices) > 1 else None


def on_compute_device() -> contextlib.AbstractContextManager:
    """The context in which a kernel call runs on `compute_device`, unless a device
    was chosen already (``jax.default_device``: a cohort's, or the caller's)."""
    if jax.config.jax_default_device is not None:
        return contextlib.nullcontext()
    device = compute_device()
    return jax.default_device(device) if device is not None else contextlib.nullcontext()


def _is_array(leaf: Any) -> bool:
    return isinstance(leaf, (np.ndarray, jax.Array))


#: The compiled sizes of a batched call (`batch_bucket`): powers of four, so that a
#: kernel has few programs whatever its batches' sizes, with at most 4x padding.
_BUCKET_BASE = 4
#: Calls per compiled call on a CPU (`_start_group`): 1, every call runs alone, as
#: the single-item program — a single fit's. Measured on 2 cores (2026-12-03, 40 targets
#: of 64², in one process, alternated): batches of up to 64 (padded to 4, 16 or 64, the
#: padding not run) compiled 31 programs cold where single calls compiled 18 (61 s against
#: 31 s for the batch), and were no faster warm (7.9 against 9.3 targets/s consistent,
#: 3.7 against 4.3 mismatched; conversions 15.4 against 15.3 materials/s): on a CPU the
#: items of a batch run one after the other anyway, and JAX dispatches single calls without
#: waiting. Above 1, groups run as batches of up to this many.
SEQUENTIAL_BATCH = 1


def batch_bucket(count: int) -> int:
    """The compiled size of a batch of ``count`` (≥ 2) items: the smallest power of four
    that holds them (4, 16, 64, 256, …). A batch is padded to it (`Kernel.start_many`),
    so that a kernel has a handful of batched programs, the same whatever sizes its batches
    come in. Sequentially (a CPU) the padding costs nothing but its rows' memory (it is not
    run); side by side (an accelerator) it costs idle lanes."""
    size = _BUCKET_BASE
    while size < count:
        size *= _BUCKET_BASE
    return size


def _stack_items(items: list[list], size: int | None = None, pad_with_first: bool = True) -> tuple[list, list]:
    """The array lists ``items`` (one per call, of one structure) as one batch of ``size``
    rows (default: as many as items): each array stacked along a new first axis, then
    padded with copies of the first item's (``pad_with_first``) or with zeros, except an
    array that is the same object in every item, which is passed once, unstacked (in
    ``shared``; None in ``stacked``, and the other way round). Why: the items of a
    conversion share their problem's prepared geometry (a megabyte per item at the default
    scene), which stacking would copy for every item and the batched program would slice
    again per item."""
    first, others = items[0], items[1:]
    size = len(items) if size is None else size
    stacked: list = []
    shared: list = []
    for i, array in enumerate(first):
        if all(other[i] is array for other in others):
            stacked.append(None)
            shared.append(array)
            continue
        rows = [np.asarray(item[i]) for item in items]
        if size == len(rows):
            block = np.stack(rows)
        else:
            block = np.zeros((size, *rows[0].shape), np.result_type(*rows))
            np.stack(rows, out=block[: len(rows)])
            if pad_with_first:
                block[len(rows) :] = rows[0]
        stacked.append(block)
        shared.append(None)
    return stacked, shared


class Pending:
    """Compiled work dispatched and maybe still running: `ready` says whether it has
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
    would keep the Python of other targets from running meanwhile (`run_batched`).
    A runtime error then surfaces when the result is read. The arguments are split once
    into their arrays and a `StaticPart` (`split_arguments`); arguments with
    a leaf that cannot be hashed go through ``filter_jit``."""

    def __init__(self, fn: Callable[..., Any], identity: str | None = None):
        self._filtered = eqx.filter_jit(fn)

        def on_arrays(arrays: list, static: StaticPart) -> Any:
            return fn(*static.rebuild(arrays))

        # traced and lowered programs kept on disk (strauss_fit.export_cache), where enabled
        self._exported = ExportedKernel(on_arrays, identity) if identity is not None else None

        def arrays_only(arrays: list, static: StaticPart) -> Any:
            out_arrays, rest = eqx.partition(on_arrays(arrays, static), eqx.is_array)
            return out_arrays, _Static.of(rest)

        arrays_only.__name__ = getattr(fn, "__name__", "kernel")
        #: ``(arrays, static) -> (output arrays, _Static(output rest))``, jitted.
        self.jitted = jax.jit(arrays_only, static_argnums=1)

    def __call__(self, *args: Any) -> Any:
        return self.call_parts(args, split_arguments(args))

    def call_parts(self, args: tuple, parts: tuple[list, StaticPart | None]) -> Any:
        """The call on ``args`` already split into ``parts`` (`Call.parts`)."""
        arrays, static = parts
        if static is None:
            return self._filtered(*args)
        if self._exported is not None:
            result = self._exported.call(arrays, static)
            if result is not None:
                return result
        out_arrays, rest = self.jitted(arrays, static)
        return eqx.combine(out_arrays, rest.value)


class _ArraySlot:
    """Where an array stands among a `StaticPart`'s leaves."""

    def __repr__(self) -> str:
        return "<array>"

    def __reduce__(self) -> str:
        return "ARRAY_SLOT"


#: The marker of an array's place in `StaticPart.leaves`.
ARRAY_SLOT = _ArraySlot()


class StaticPart:
    """The non-array part of a kernel call's arguments: their pytree structure and their
    leaves, each array replaced by `ARRAY_SLOT`. Hashed once, compared structurally.

    Why not ``eqx.partition``'s static pytree: hashing and comparing that walks every
    equinox module of the arguments in Python (a conversion's problem: ~50 µs a hash, and
    a call's static part is hashed and compared four times: its batch, the export cache,
    ``jax.jit``), and partitioning itself costs ~180 µs; one flatten costs ~20 µs and the
    structure's hash and comparison happen in C++."""

    __slots__ = ("treedef", "leaves", "_hash")

    def __init__(self, treedef: Any, leaves: tuple):
        self.treedef = treedef
        self.leaves = leaves
        self._hash = hash((treedef, leaves))  # TypeError: a leaf that cannot be hashed

    def __hash__(self) -> int:
        return self._hash

    def __eq__(self, other: object) -> bool:
        if self is other:
            return True
        return (
            isinstance(other, StaticPart)
            and self._hash == other._hash
            and self.treedef == other.treedef
            and self.leaves == other.leaves
        )

    def rebuild(self, arrays: list) -> Any:
        """The arguments, with ``arrays`` in the array slots (in order)."""
        supply = iter(arrays)
        return jax.tree.unflatten(self.treedef, [next(supply) if x is ARRAY_SLOT else x for x in self.leaves])

    def describe(self, plain: tuple[type, ...]) -> str | None:
        """A text that tells this static part from any other, or None when a leaf is not of
        a ``plain`` type (its ``repr`` might not tell two values apart) nor a
        `StaticPart` itself (a batched call's)."""
        texts = []
        for leaf in self.leaves:
            if leaf is ARRAY_SLOT or type(leaf) in plain:
                texts.append(repr(leaf))
            elif isinstance(leaf, StaticPart):
                inner = leaf.describe(plain)
                if inner is None:
                    return None
                texts.append(inner)
            else:
                return None
        return repr((str(self.treedef), texts))


def split_arguments(args: tuple) -> tuple[list, StaticPart | None]:
    """``args`` as their array leaves (in order) and their `StaticPart` (None when a
    leaf cannot be hashed), each argument with a ``kernel_form()`` method replaced by what
    it returns: the form a compiled program takes it in, which may hold as data what the
    object holds as structure, so that its variants share one program (a fit's problem
    and its loss: `strauss_fit.fitting.problem.Problem.kernel_form`)."""
    args = tuple(_kernel_form(argument) for argument in args)
    leaves, treedef = jax.tree.flatten(args)
    arrays = [x for x in leaves if isinstance(x, _ARRAY_TYPES)]
    try:
        static = StaticPart(treedef, tuple(ARRAY_SLOT if isinstance(x, _ARRAY_TYPES) else x for x in leaves))
    except TypeError:
        static = None
    return arrays, static


def _kernel_form(argument: Any) -> Any:
    form = None if isinstance(argument, type) else getattr(argument, "kernel_form", None)
    return form() if callable(form) else argument


#: What ``eqx.is_array`` counts as an array.
_ARRAY_TYPES = (jax.Array, np.ndarray, np.generic)


@dataclass(frozen=True)
class Call:
    """A request for ``kernel(*args)``, yielded by a step generator."""

    kernel: Kernel
    args: tuple

    @functools.cached_property
    def parts(self) -> tuple[list, StaticPart | None]:
        """The arguments' arrays and `StaticPart` (`split_arguments`), split
        once: grouping, stacking and the call all need them."""
        return split_arguments(self.args)


def run(steps: Steps) -> Any:
    """Drive one step generator to its end, running every `Call` directly, and
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
    arrays, static = call.parts
    if static is None:  # a static part that cannot be hashed cannot be grouped: run it alone
        return (call.kernel, id(call))
    return (call.kernel, static, tuple((np.shape(x), x.dtype.str) for x in arrays))


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
    are split (default `cohort_devices`, which ``python_bound`` informs); each
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
    """The device of each cohort of `run_batched` (None: JAX's default device).

    Two cohorts at least, so that one cohort's Python (the fits' decisions, the noise
    estimate) runs while the other's compiled calls do: JAX dispatches a compiled call
    and returns at once. But a device runs its work in order, so a small eager JAX
    operation in that Python (``jnp.asarray``, ``.at[].set``) would wait for the batch
    running on the same device. On a CPU with several devices
    (`strauss_fit.runtime.use_cpu_cores`: one per core, up to eight, and one more)
    the batches therefore run on the devices after the first, which is left to the eager
    operations, one cohort per device: as many devices as there are cores less the one
    the Python needs (``python_bound``, a fit's case), or as cores (a conversion's, almost
    all compiled work). A batch runs on the first of them whatever its size, and on one
    more per `ITEMS_PER_DEVICE` items. Why not the default device for a small batch
    (which would share a single fit's programs): a compiled program belongs to its device,
    in memory and in the persistent compilation cache (whose key holds the device on a
    CPU), so a batch that moved between devices with its size would compile everything
    again — a run of 13 targets after one of 40 compiled 29 programs in 65 s, against none.
    Each further device compiles its own programs (and holds them: memory mappings,
    `strauss_fit.runtime`), hence only for large batches."""
    devices = jax.local_devices() if jax.default_backend() == "cpu" else []
    if cohorts is None:
        cohorts = 2
        cores = usable_cores() - 1 if python_bound else usable_cores()
        wanted = min(len(devices) - 1, max(cores, 1), max(1, items // ITEMS_PER_DEVICE))
        if wanted >= 1:
            compute = devices[1 : 1 + wanted]
            cohorts = max(min(cohorts, items), len(compute))
            return [compute[c % len(compute)] for c in range(cohorts)]
    return [None] * max(1, min(cohorts, items))


#: Items per CPU device from which `run_batched` spreads a batch over one more device.
ITEMS_PER_DEVICE = 16


def _chunks(items: list[int], size: int | None) -> list[list[int]]:
    if not size or len(items) <= size:
        return [items]
    return [items[i : i + size] for i in range(0, len(items), size)]


def _start_group(calls: list[Call], sequential: bool | None, device: Any = None) -> Pending:
    """Start the calls of one structure on ``device`` (None: the default): their results
    come from batched calls, or, for a single call or when a batch fails, from one call
    each (each failure then goes to its own target).

    The programs compiled per kernel are few and the same however the targets split up as
    their fits diverge: on a CPU (``sequential``) every call runs alone, as the
    single-item program (`SEQUENTIAL_BATCH`), all of them dispatched before any is
    waited for; on an accelerator the group runs side by side as one batch padded to its
    `batch_bucket` (4, 16, 64, … items) with copies of its first item, whose results
    are dropped."""
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

    step = SEQUENTIAL_BATCH if sequential else len(calls)
    if len(calls) == 1 or step <= 1:
        outputs = one_by_one()
        return Pending(lambda: outputs, outputs)
    try:
        with placed:
            parts = []
            for first in range(0, len(calls), step):
                chunk = calls[first : first + step]
                if len(chunk) == 1:
                    single = chunk[0].kernel.run_call(chunk[0])
                    parts.append(Pending(lambda single=single: [single], single))
                else:
                    kernel = chunk[0].kernel
                    parts.append(kernel.start_many([c.args for c in chunk], sequential, [c.parts for c in chunk]))
    except Exception:  # one item broke the batch: find it by running them alone
        return Pending(one_by_one)

    def results() -> list[Any]:
        try:
            return [output for part in parts for output in part()]
        except Exception:  # it broke while running
            return one_by_one()

    return Pending(results, [part._running for part in parts])
