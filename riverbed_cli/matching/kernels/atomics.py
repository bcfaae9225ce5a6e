"""Atomic loads, stores and exchanges on elements of int64 arrays, for Numba kernels whose threads hand work to each
other (:func:`.sgm.sgm_aggregate_select`: a row goes to the disparity selection once both SGM passes have done it).

Plain Numba loads may be hoisted out of a waiting loop and plain stores reordered before the data they announce;
these are LLVM's atomic instructions (llvmlite), which neither the compiler nor the CPU reorders across: a
:func:`store_release` after writing a row, a :func:`load_acquire` before reading it.
"""

from numba import types
from numba.extending import intrinsic

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


@intrinsic
def exchange(typingctx, arr, index, value):
    """Atomically ``old = arr[index]; arr[index] = value`` (int64 array, sequentially consistent); returns ``old``:
    of several threads exchanging the same element, one reads what was there before."""
    _check(arr)
    sig = types.int64(arr, index, value)

    def codegen(context, builder, signature, args):
        arr_, index_, value_ = args
        value_ = context.cast(builder, value_, signature.args[2], types.int64)
        return builder.atomic_rmw("xchg", element_ptr(context, builder, signature.args[0], arr_, index_), value_,
                                  "seq_cst")

    return sig, codegen
