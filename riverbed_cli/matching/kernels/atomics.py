"""Atomic loads, stores, exchanges and additions on elements of int64 arrays, for Numba kernels whose threads hand
work to each other (:func:`.sgm.sgm_aggregate_select`: a row goes to the disparity selection once both SGM passes have
done it; :func:`.sgm_pass.sgm_rows`: the threads of a pass take rows from a counter and wait for the rows before).

Plain Numba loads may be hoisted out of a waiting loop and plain stores reordered before the data they announce;
these are LLVM's atomic instructions (llvmlite), which neither the compiler nor the CPU reorders across: a
:func:`store_release` after writing a row, a :func:`load_acquire` before reading it.
"""

import sys

from numba import types
from numba.extending import intrinsic

from ...runtime.kernel import kernel
from .vector_ir import element_ptr


def _check(arr):
    if not (isinstance(arr, types.Array) and arr.dtype == types.int64):
        raise TypeError("atomics work on int64 arrays")


@intrinsic
def load_acquire(typingctx, arr, index):
    """``arr[index]`` (int64 array), an acquire load: what the storing thread wrote before its release store of
    this value is visible after it."""
    _check(arr)
    sig = types.int64(arr, index)

    def codegen(context, builder, signature, args):
        return builder.load_atomic(element_ptr(context, builder, signature.args[0], *args), "acquire", 8)

    return sig, codegen


@intrinsic
def store_release(typingctx, arr, index, value):
    """``arr[index] = value`` (int64 array), a release store: everything this thread wrote before is visible to a
    thread whose acquire load reads the value."""
    _check(arr)
    sig = types.void(arr, index, value)

    def codegen(context, builder, signature, args):
        arr_, index_, value_ = args
        value_ = context.cast(builder, value_, signature.args[2], types.int64)
        builder.store_atomic(value_, element_ptr(context, builder, signature.args[0], arr_, index_), "release", 8)
        return context.get_dummy_value()

    return sig, codegen


def _read_modify_write(operation, arr, index, value):
    # the signature and code of an atomic read-modify-write of arr[index] with value (LLVM's atomicrmw, sequentially
    # consistent), which returns what was there before
    _check(arr)
    sig = types.int64(arr, index, value)

    def codegen(context, builder, signature, args):
        arr_, index_, value_ = args
        value_ = context.cast(builder, value_, signature.args[2], types.int64)
        return builder.atomic_rmw(operation, element_ptr(context, builder, signature.args[0], arr_, index_), value_,
                                  "seq_cst")

    return sig, codegen


@intrinsic
def exchange(typingctx, arr, index, value):
    """Atomically ``old = arr[index]; arr[index] = value`` (int64 array, sequentially consistent); returns ``old``:
    of several threads exchanging the same element, one reads what was there before."""
    return _read_modify_write("xchg", arr, index, value)


@intrinsic
def fetch_add(typingctx, arr, index, value):
    """Atomically ``old = arr[index]; arr[index] += value`` (int64 array, sequentially consistent); returns ``old``:
    threads taking rows from one counter each get a different row."""
    return _read_modify_write("add", arr, index, value)


if sys.platform == "win32":
    @kernel
    def yield_cpu():
        """(No yield on Windows: a waiting thread spins on.)"""
        return 0
else:
    #: ``sched_yield()``: a thread that has waited a while gives its core to another (more threads than cores: the
    #: one it waits for may be queued behind it)
    yield_cpu = types.ExternalFunction("sched_yield", types.intc())
