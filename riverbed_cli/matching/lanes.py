"""Fixed-width int16 vector steps for the SGM passes, written as LLVM vector code (Numba intrinsics).

Why not plain Numba loops: a tube is 5-30 disparities wide, and Numba's loop over them loses most of its time around
the arithmetic. Numba widens ``int16 + int16`` to int64 (8 lanes where 32 fit), every array view made per pixel
costs an atomic reference count, a loop of varying length ends in a scalar remainder and mispredicted branches, and
LLVM guards each vectorised loop with run-time aliasing checks. These intrinsics do one step on ``LANES``
disparities at once, as a handful of vector instructions with no branch: disparities past a tube's end are masked
to the sentinel. Measured on the tube volumes of the dev pairs (docs/tubes.md): one SGM pass 2x faster.

Conventions shared by all steps: arrays are 1-D, indices are element indices (int64), ``lanes`` is the number of
valid lanes (``<= 0``: none; ``>= LANES``: all), and every access touches ``LANES`` consecutive elements from the
index (+2 for the previous path costs), which the caller keeps inside the arrays. Path costs are int16; costs
(uint8 or uint16) are widened to int16. The vector type is generic: LLVM lowers it to whatever SIMD the CPU has.

Numba's cache keys a kernel on its own source file only: after editing this module, delete the cached kernels of the
modules that use it (``riverbed_cli/matching/__pycache__/{sgm,disparity}.*.nb[ic]``), or they keep the old steps.
"""

from llvmlite import ir
from numba import types
from numba.extending import intrinsic

LANES = 16  # 256 bits of int16: on the dev machine 16 lanes beat 32 (most tubes are under 16 wide)
SENTINEL = 16384  # above any path cost (sgm.check_sgm_bounds); SENTINEL + P1 still fits int16

_I16 = ir.IntType(16)
_I64 = ir.IntType(64)
_V16 = ir.VectorType(_I16, LANES)
_LANE_INDEX = ir.Constant(ir.VectorType(_I64, LANES), list(range(LANES)))


def _vector_ptr(context, builder, arrty, arr, index, elem=None):
    data = context.make_array(arrty)(context, builder, arr).data
    vty = ir.VectorType(elem or _I16, LANES)
    return builder.bitcast(builder.gep(data, [index]), vty.as_pointer())


def _load(context, builder, arrty, arr, index):
    """``LANES`` elements from ``arr[index]`` as int16 lanes (uint8 widened with zeros)."""
    elem = context.get_value_type(arrty.dtype)
    v = builder.load(_vector_ptr(context, builder, arrty, arr, index, elem), align=elem.width // 8)
    return builder.zext(v, _V16) if elem.width < 16 else v


def _store(context, builder, arrty, arr, index, value):
    builder.store(value, _vector_ptr(context, builder, arrty, arr, index), align=2)


def _splat(builder, value, vty=_V16):
    if value.type != vty.element:
        value = builder.trunc(value, vty.element) if value.type.width > vty.element.width else \
            builder.sext(value, vty.element)
    undef = ir.Constant(vty, ir.Undefined)
    one = builder.insert_element(undef, value, ir.Constant(ir.IntType(32), 0))
    return builder.shuffle_vector(one, undef, ir.Constant(ir.VectorType(ir.IntType(32), LANES), [0] * LANES))


def _smin(builder, a, b):
    return builder.select(builder.icmp_signed("<", a, b), a, b)


def _valid(builder, lanes):
    return builder.icmp_signed("<", _LANE_INDEX, _splat(builder, lanes, ir.VectorType(_I64, LANES)))


def _reduce_min(builder, v, signed=True):
    # a tree of halving shuffles: portable across LLVM versions (no reduction intrinsic needed)
    n = LANES
    while n > 1:
        n //= 2
        undef = ir.Constant(v.type, ir.Undefined)
        hi = builder.shuffle_vector(v, undef, ir.Constant(ir.VectorType(ir.IntType(32), LANES),
                                                           [i + n if i < n else i for i in range(LANES)]))
        v = builder.select(builder.icmp_signed("<", v, hi) if signed else builder.icmp_unsigned("<", v, hi), v, hi)
    return builder.extract_element(v, ir.Constant(ir.IntType(32), 0))


def _finish(context, builder, sig_args, v, mask, L, cur, acc, ai, keep):
    # lanes past the tube hold the sentinel (unreachable for the next pixel); the path cost joins the half-sum
    # (keep 0: the pixel's first direction starts it, so the half-sum needs no zeroing per pixel)
    v = builder.select(mask, v, ir.Constant(_V16, [SENTINEL] * LANES))
    _store(context, builder, sig_args[0], L, cur, v)
    accty = sig_args[1]
    kept = builder.and_(_load(context, builder, accty, acc, ai), _splat(builder, keep))
    _store(context, builder, accty, acc, ai, builder.add(kept, v))
    return _reduce_min(builder, v)


@intrinsic
def lanes_first(typingctx, L, acc, cur, cost, ci, ai, lanes, keep):
    """The first pixel of a path: its path costs are its costs.

    Lane ``d``: ``L[cur + d] = cost[ci + d]`` (the sentinel for ``d >= lanes``), ``acc[ai + d] = (acc[ai + d] &
    keep) +`` that (``keep`` int16 -1: adds to the half-sum, 0: starts it); returns the minimum over the lanes
    (int16).
    """
    sig = types.int16(L, acc, cur, cost, ci, ai, lanes, keep)

    def codegen(context, builder, signature, args):
        L_, acc_, cur_, cost_, ci_, ai_, lanes_, keep_ = args
        c = _load(context, builder, signature.args[3], cost_, ci_)
        return _finish(context, builder, signature.args, c, _valid(builder, lanes_), L_, cur_, acc_, ai_, keep_)

    return sig, codegen


@intrinsic
def lanes_step(typingctx, L, acc, cur, cost, ci, ai, lanes, prev, p1, jump, mp, keep):
    """One SGM step along a path on ``LANES`` disparities.

    Lane ``d``: with ``a, b, e = L[prev + d + 1], L[prev + d], L[prev + d + 2]`` (the previous pixel's path costs at
    the same disparity and its two neighbours), ``L[cur + d] = cost[ci + d] + min(a, min(b, e) + p1, jump) - mp``
    (``jump = mp + P2``, ``mp`` the previous pixel's minimum) for ``d < lanes``, the sentinel past them;
    ``acc[ai + d]`` as in :func:`lanes_first`. Returns the minimum over the lanes (int16).
    """
    sig = types.int16(L, acc, cur, cost, ci, ai, lanes, prev, p1, jump, mp, keep)

    def codegen(context, builder, signature, args):
        L_, acc_, cur_, cost_, ci_, ai_, lanes_, prev_, p1_, jump_, mp_, keep_ = args
        lt = signature.args[0]
        b = _load(context, builder, lt, L_, prev_)
        a = _load(context, builder, lt, L_, builder.add(prev_, ir.Constant(_I64, 1)))
        e = _load(context, builder, lt, L_, builder.add(prev_, ir.Constant(_I64, 2)))
        v = _smin(builder, a, builder.add(_smin(builder, b, e), _splat(builder, p1_)))
        v = _smin(builder, v, _splat(builder, jump_))
        c = _load(context, builder, signature.args[3], cost_, ci_)
        v = builder.sub(builder.add(c, v), _splat(builder, mp_))
        return _finish(context, builder, signature.args, v, _valid(builder, lanes_), L_, cur_, acc_, ai_, keep_)

    return sig, codegen


@intrinsic
def lanes_fill(typingctx, arr, index, value):
    """``arr[index:index + LANES] = value`` (an int16 array)."""
    sig = types.void(arr, index, value)

    def codegen(context, builder, signature, args):
        arr_, index_, value_ = args
        _store(context, builder, signature.args[0], arr_, index_, _splat(builder, value_))
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def lanes_copy(typingctx, src, si, dst, di, lanes):
    """``dst[di + d] = src[si + d]`` for ``d < lanes`` (int16 arrays); the other lanes of ``dst`` are rewritten with
    their own values (read, then written back)."""
    sig = types.void(src, si, dst, di, lanes)

    def codegen(context, builder, signature, args):
        src_, si_, dst_, di_, lanes_ = args
        st, _, dt = signature.args[:3]
        v = builder.select(_valid(builder, lanes_), _load(context, builder, st, src_, si_),
                           _load(context, builder, dt, dst_, di_))
        _store(context, builder, dt, dst_, di_, v)
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def lanes_sum(typingctx, a, b, ai, out, oi, lanes):
    """``out[oi + d] = a[ai + d] + b[ai + d]`` (uint16 arrays; the sum must fit, as SGM's half-sums do) for
    ``d < lanes``, 65535 past them; returns the minimum over the lanes (uint16)."""
    sig = types.uint16(a, b, ai, out, oi, lanes)

    def codegen(context, builder, signature, args):
        a_, b_, ai_, out_, oi_, lanes_ = args
        at, bt, _, ot = signature.args[:4]
        v = builder.add(_load(context, builder, at, a_, ai_), _load(context, builder, bt, b_, ai_))
        v = builder.select(_valid(builder, lanes_), v, ir.Constant(_V16, [65535] * LANES))
        _store(context, builder, ot, out_, oi_, v)
        return _reduce_min(builder, v, signed=False)

    return sig, codegen


@intrinsic
def lanes_find(typingctx, arr, index, value):
    """The first lane ``d`` with ``arr[index + d] == value`` (a 16-bit array), ``LANES`` if none (int64)."""
    sig = types.int64(arr, index, value)

    def codegen(context, builder, signature, args):
        arr_, index_, value_ = args
        v = _load(context, builder, signature.args[0], arr_, index_)
        hit = builder.icmp_unsigned("==", v, _splat(builder, value_))
        bits = builder.bitcast(hit, ir.IntType(LANES))
        first = builder.cttz(bits, ir.Constant(ir.IntType(1), 0))  # LANES where no lane hits
        return builder.zext(first, _I64)

    return sig, codegen
