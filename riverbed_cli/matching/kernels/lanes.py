"""Fixed-width vector steps for the SGM passes, the selection and the census cost, written as LLVM vector code
(Numba intrinsics); the guidance's are in :mod:`.lanes_guidance`.

Why not plain Numba loops: a tube is 5-30 disparities wide, and Numba's loop over them loses most of its time around
the arithmetic. Numba widens ``int16 + int16`` to int64 (8 lanes where 32 fit), every array view made per pixel
costs an atomic reference count, a loop of varying length ends in a scalar remainder and mispredicted branches, and
LLVM guards each vectorised loop with run-time aliasing checks. These intrinsics do one step on ``LANES``
disparities at once, as a handful of vector instructions with no branch: disparities past a tube's end are masked
to the sentinel. Measured on the tube volumes of the dev pairs (docs/tubes.md): one SGM pass 2x faster.

Each step's plain statement, lane by lane, is in :mod:`.lanes_reference` (``tests/test_lanes.py`` runs every step
against it). Conventions shared by all steps: arrays are 1-D, indices are element indices (int64),
``lanes`` is the number of valid lanes (``<= 0``: none; ``>= LANES``: all), and every access touches ``LANES``
consecutive elements from the index (+2 for the previous path costs), which the caller keeps inside the arrays. Path
costs are int16; costs (uint8 or uint16) are widened to int16. The vector type is generic: LLVM lowers it to
whatever SIMD the CPU has.

The right image's votes of the left-right check (:func:`lanes_vote`) go ``LANES`` disparities at a time, the pixels
taken ``LANES`` apart: a pixel's votes overlap its row neighbour's, and taken in row order each would wait for the
last one's store (below); the selection with the check 0.89x (cut speed pair) to 0.97x (whole-scene pair) of the
scalar votes' time, the same bits.
The census cost (:func:`lanes_census`) writes ``LANES`` costs of a tube whole, its lanes past the tube left for the
next pixels to overwrite: 0.53-0.6x of the scalar loop's time on the aerial pair. A step that reads lanes its
neighbour has just stored whole at a shifted address waits for that store (no store-to-load forwarding).
The census transform (:func:`lanes_census_bits`) keeps 16 pixels' words in registers across the window's
neighbours, in two 32-bit halves: 0.62-0.70x of the loop that wrote each word back once per neighbour, then 0.8x
of one 64-bit accumulator.
An SGM step of a tube wider than ``LANES`` (:func:`lanes_step_wide`) and the selection's sums of one
(:func:`lanes_sum_wide`) loop over its chunks inside one step, the running minimum in a register and reduced once
per pixel: kept in an array between one call per chunk (:func:`lanes_step_min`, still used where chunks read from
different places), each chunk's load waited for the last one's store. Votes of a tube of at most ``LANES // 2``
disparities take half the lanes (:func:`lanes_vote_half`, 32-bit lanes).

Inside riverbed's runtime ``Env`` (the program, the tests) kernels are cached per digest of the kernel sources
(:mod:`riverbed_cli.runtime.numba_cache`): editing this module recompiles the kernels that use it. A program that
imports riverbed without the ``Env`` has Numba's own cache, which keys a kernel on its own file: after editing this
module, delete the cached kernels of the modules that use it
(``riverbed_cli/matching/__pycache__/{sgm,disparity,guidance,census}.*.nb[ic]``), or they keep the old steps (after
editing :mod:`.vector_ir`, those of every module using it or :mod:`.lanes_guidance`).
"""

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from .vector_ir import (F32, I16, I32, I64, LANES, V16, VI32, VI64, Args, declared, load_i16, masked_store, reduce_min,
                        smin, splat, store_vector, typed, valid, vector_ptr)

SENTINEL = 16384  # above any path cost (sgm.check_sgm_bounds); SENTINEL + P1 still fits int16


def _store_path_costs(a, v, mask, cur, ai):
    # lanes past the tube hold the sentinel (unreachable for the next pixel); the path cost joins the half-sum
    # (a.sum_mask 0: the pixel's first direction starts it, so the half-sum needs no zeroing per pixel); returns the
    # stored lanes (a: the step's Args, with L, acc and sum_mask)
    builder = a.builder
    v = builder.select(mask, v, ir.Constant(V16, [SENTINEL] * LANES))
    a.store("L", cur, v)
    kept = builder.and_(a.load("acc", ai), splat(builder, a.sum_mask))
    a.store("acc", ai, builder.add(kept, v))
    return v


def _store_half_sum(a, v, mask, cur, ai, oi):
    # the last direction of a pass: as _store_path_costs, the half-sum (acc + the path costs) then stored to the
    # pass's result out[oi:] in the tube's lanes only (masked: the lanes past it are other pixels', some already
    # written); returns the stored path costs
    builder = a.builder
    v = builder.select(mask, v, ir.Constant(V16, [SENTINEL] * LANES))
    a.store("L", cur, v)
    masked_store(builder, builder.add(a.load("acc", ai), v), a.ptr("out", oi), mask)
    return v


def neighbour_min(context, builder, lt, L, prev, p1, jump):
    """``min(a, min(b, e) + P1, jump)`` with ``a, b, e`` the neighbour's path costs ``L[prev + 1]``, ``L[prev]``,
    ``L[prev + 2]`` (``LANES`` lanes each; ``lt`` the type of ``L``): the part of a step from its neighbour."""
    b = load_i16(context, builder, lt, L, prev)
    a = load_i16(context, builder, lt, L, builder.add(prev, ir.Constant(I64, 1)))
    e = load_i16(context, builder, lt, L, builder.add(prev, ir.Constant(I64, 2)))
    v = smin(builder, a, builder.add(smin(builder, b, e), splat(builder, p1)))
    return smin(builder, v, splat(builder, jump))


def _step_value(a, ci, prev):
    # cost[ci:] + min(a, min(b, e) + P1, jump) - mp with a, b, e the previous path costs at prev + 1, prev, prev + 2
    # (a: the step's Args, with L, cost, p1, jump and mp)
    builder = a.builder
    v = neighbour_min(a.context, builder, a.type("L"), a.L, prev, a.p1, a.jump)
    return builder.sub(builder.add(a.load("cost", ci), v), splat(builder, a.mp))


def _wide_codegen(a, store):
    # the chunks of a wide tube's step (a: lanes_step_wide's Args), each stored by store(v, mask, i) (chunk i); the
    # running minimum in a register, reduced once
    builder = a.builder
    mv = cgutils.alloca_once_value(builder, ir.Constant(V16, [SENTINEL] * LANES))
    step = ir.Constant(I64, LANES)
    with cgutils.for_range_slice(builder, ir.Constant(I64, 0), a.span, step) as (i, _):
        v = _step_value(a, builder.add(a.ci, i), builder.add(a.prev, i))
        v = store(v, valid(builder, builder.sub(a.lanes, i)), i)
        builder.store(smin(builder, builder.load(mv), v), mv)
    return reduce_min(builder, builder.load(mv))


@intrinsic
def lanes_first(typingctx, L, acc, cur, cost, ci, ai, lanes, sum_mask):
    """The first pixel of a path: its path costs are its costs.

    Lane ``d``: ``L[cur + d] = cost[ci + d]`` (the sentinel for ``d >= lanes``), ``acc[ai + d] = (acc[ai + d] &
    sum_mask) +`` that (``sum_mask`` int16 -1: adds to the half-sum, 0: starts it); returns the minimum over the lanes
    (int16).
    """
    names, sig = typed(locals(), types.int16)

    def codegen(context, builder, signature, args):
        a = Args(names, context, builder, signature, args)
        c = a.load("cost", a.ci)
        return reduce_min(builder, _store_path_costs(a, c, valid(builder, a.lanes), a.cur, a.ai))

    return sig, codegen


@intrinsic
def lanes_step(typingctx, L, acc, cur, cost, ci, ai, lanes, prev, p1, jump, mp, sum_mask):
    """One SGM step along a path on ``LANES`` disparities.

    Lane ``d``: with ``a, b, e = L[prev + d + 1], L[prev + d], L[prev + d + 2]`` (the previous pixel's path costs at
    the same disparity and its two neighbours), ``L[cur + d] = cost[ci + d] + min(a, min(b, e) + p1, jump) - mp``
    (``jump = mp + P2``, ``mp`` the previous pixel's minimum) for ``d < lanes``, the sentinel past them;
    ``acc[ai + d]`` as in :func:`lanes_first`. Returns the minimum over the lanes (int16).
    """
    names, sig = typed(locals(), types.int16)

    def codegen(context, builder, signature, args):
        a = Args(names, context, builder, signature, args)
        v = _step_value(a, a.ci, a.prev)
        return reduce_min(builder, _store_path_costs(a, v, valid(builder, a.lanes), a.cur, a.ai))

    return sig, codegen


@intrinsic
def lanes_step_out(typingctx, L, acc, cur, cost, ci, ai, lanes, prev, p1, jump, mp, out, oi):
    """:func:`lanes_step` in a pass's last direction: the half-sum ``acc[ai + d] +`` the path cost goes to
    ``out[oi + d]`` for ``d < lanes`` only (``acc`` is read, not written). Returns the minimum over the lanes."""
    names, sig = typed(locals(), types.int16)

    def codegen(context, builder, signature, args):
        a = Args(names, context, builder, signature, args)
        v = _step_value(a, a.ci, a.prev)
        return reduce_min(builder, _store_half_sum(a, v, valid(builder, a.lanes), a.cur, a.ai, a.oi))

    return sig, codegen


@intrinsic
def lanes_step_pair(typingctx, L, cur, cost, ci, lanes, prev, p1, jump, mp, cur2, prev2, jump2, mp2, out, oi):
    """Two directions' :func:`lanes_step` of one pixel at once, the first starting its half-sum and the second the
    pass's last (4 paths: the row's direction and the column's): the cost is loaded once, the path costs go to
    ``L[cur:]`` and ``L[cur2:]`` (neighbours at ``prev`` and ``prev2``), their sum to ``out[oi + d]`` for ``d <
    lanes``, with no half-sum in between. Returns both minima, the first in the low 16 bits (int32)."""
    names, sig = typed(locals(), types.int32)

    def codegen(context, builder, signature, args):
        vs = _pair_chunk(Args(names, context, builder, signature, args), ir.Constant(I64, 0))
        return _pair_minima(builder, [reduce_min(builder, v) for v in vs])

    return sig, codegen


def _pair_chunk(a, i):
    # chunk i of a pixel's two paired steps (a: lanes_step_pair's or lanes_step_wide_pair's Args): the cost loaded
    # once, each direction's path costs stored (the sentinel past the tube), their sum to out; returns both
    # directions' path costs
    builder = a.builder
    c = a.load("cost", builder.add(a.ci, i))
    mask = valid(builder, builder.sub(a.lanes, i))
    sent = ir.Constant(V16, [SENTINEL] * LANES)
    vs = []
    for cur, prev, jump, mp in ((a.cur, a.prev, a.jump, a.mp), (a.cur2, a.prev2, a.jump2, a.mp2)):
        v = neighbour_min(a.context, builder, a.type("L"), a.L, builder.add(prev, i), a.p1, jump)
        v = builder.select(mask, builder.sub(builder.add(c, v), splat(builder, mp)), sent)
        a.store("L", builder.add(cur, i), v)
        vs.append(v)
    masked_store(builder, builder.add(vs[0], vs[1]), a.ptr("out", builder.add(a.oi, i)), mask)
    return vs


def _pair_minima(builder, mins):
    # two int16 minima in one int32, the first in the low 16 bits
    lo, hi = (builder.zext(builder.bitcast(m, I16), I32) for m in mins)
    return builder.or_(lo, builder.shl(hi, ir.Constant(I32, 16)))


@intrinsic
def lanes_step_wide_pair(typingctx, L, cur, cost, ci, lanes, span, prev, p1, jump, mp, cur2, prev2, jump2, mp2, out,
                         oi):
    """:func:`lanes_step_pair` over a whole tube wider than ``LANES``: ``span`` disparities (a multiple of
    ``LANES``) a chunk at a time, chunk ``i`` at ``cur + i``, ``ci + i``, ``prev + i``, ``cur2 + i``, ``prev2 + i``,
    ``oi + i`` with ``lanes - i`` valid lanes; each direction's running minimum in a register, reduced once.
    Returns both minima, the first in the low 16 bits (int32)."""
    names, sig = typed(locals(), types.int32)

    def codegen(context, builder, signature, args):
        a = Args(names, context, builder, signature, args)
        mvs = [cgutils.alloca_once_value(builder, ir.Constant(V16, [SENTINEL] * LANES)) for _ in range(2)]
        with cgutils.for_range_slice(builder, ir.Constant(I64, 0), a.span, ir.Constant(I64, LANES)) as (i, _):
            for mv, v in zip(mvs, _pair_chunk(a, i)):
                builder.store(smin(builder, builder.load(mv), v), mv)
        return _pair_minima(builder, [reduce_min(builder, builder.load(mv)) for mv in mvs])

    return sig, codegen


@intrinsic
def lanes_step_min(typingctx, L, acc, cur, cost, ci, ai, lanes, prev, p1, jump, mp, sum_mask, mv, first):
    """:func:`lanes_step` for one chunk of a tube wider than ``LANES``: instead of returning the chunk's minimum, its
    lanes join a running minimum ``mv[0:LANES]`` (int16; ``first``: start it), reduced once for the pixel by
    :func:`lanes_reduce` (one horizontal reduction per pixel, not per chunk)."""
    names, sig = typed(locals(), types.void)

    def codegen(context, builder, signature, args):
        a = Args(names, context, builder, signature, args)
        v = _step_value(a, a.ci, a.prev)
        v = _store_path_costs(a, v, valid(builder, a.lanes), a.cur, a.ai)
        zero = ir.Constant(I64, 0)
        first = builder.icmp_signed("!=", a.first, ir.Constant(a.first.type, 0))
        a.store("mv", zero, builder.select(first, v, smin(builder, a.load("mv", zero), v)))
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def lanes_step_wide(typingctx, L, acc, cur, cost, ci, ai, lanes, span, prev, p1, jump, mp, sum_mask):
    """:func:`lanes_step` over a whole tube, ``span`` disparities (a multiple of ``LANES``) a chunk at a time, the
    chunk ``i`` at ``cur + i``, ``ci + i``, ``ai + i``, ``prev + i`` with ``lanes - i`` valid lanes; returns the
    minimum over all (int16). The running minimum stays in a register: kept in an array between one call per chunk,
    each chunk's load waited for the last one's store."""
    names, sig = typed(locals(), types.int16)

    def codegen(context, builder, signature, args):
        a = Args(names, context, builder, signature, args)

        def store(v, mask, i):
            return _store_path_costs(a, v, mask, builder.add(a.cur, i), builder.add(a.ai, i))

        return _wide_codegen(a, store)

    return sig, codegen


@intrinsic
def lanes_step_wide_out(typingctx, L, acc, cur, cost, ci, ai, lanes, span, prev, p1, jump, mp, out, oi):
    """:func:`lanes_step_wide` in a pass's last direction, the half-sums to ``out`` as :func:`lanes_step_out`."""
    names, sig = typed(locals(), types.int16)

    def codegen(context, builder, signature, args):
        a = Args(names, context, builder, signature, args)

        def store(v, mask, i):
            return _store_half_sum(a, v, mask, builder.add(a.cur, i), builder.add(a.ai, i), builder.add(a.oi, i))

        return _wide_codegen(a, store)

    return sig, codegen


@intrinsic
def lanes_reduce(typingctx, mv):
    """The minimum of ``mv[0:LANES]`` (int16)."""
    sig = types.int16(mv)

    def codegen(context, builder, signature, args):
        return reduce_min(builder, load_i16(context, builder, signature.args[0], args[0], ir.Constant(I64, 0)))

    return sig, codegen


@intrinsic
def lanes_fill(typingctx, arr, index, value):
    """``arr[index:index + LANES] = value`` (an int16 array)."""
    sig = types.void(arr, index, value)

    def codegen(context, builder, signature, args):
        arr_, index_, value_ = args
        store_vector(context, builder, signature.args[0], arr_, index_, splat(builder, value_))
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
        v = builder.select(valid(builder, lanes_), load_i16(context, builder, st, src_, si_),
                           load_i16(context, builder, dt, dst_, di_))
        store_vector(context, builder, dt, dst_, di_, v)
        return context.get_dummy_value()

    return sig, codegen


def _chunk_sums(context, builder, sig_args, a, b, ai, out, oi, lanes):
    # a[ai + d] + b[ai + d] for d < lanes, 65535 past them, stored to out[oi:]; returns them
    at, bt, _, ot = sig_args[:4]
    v = builder.add(load_i16(context, builder, at, a, ai), load_i16(context, builder, bt, b, ai))
    v = builder.select(valid(builder, lanes), v, ir.Constant(V16, [65535] * LANES))
    store_vector(context, builder, ot, out, oi, v)
    return v


@intrinsic
def lanes_sum(typingctx, a, b, ai, out, oi, lanes):
    """``out[oi + d] = a[ai + d] + b[ai + d]`` (uint16 arrays; the sum must fit, as SGM's half-sums do) for
    ``d < lanes``, 65535 past them; returns the minimum over the lanes (uint16)."""
    sig = types.uint16(a, b, ai, out, oi, lanes)

    def codegen(context, builder, signature, args):
        a_, b_, ai_, out_, oi_, lanes_ = args
        return reduce_min(builder, _chunk_sums(context, builder, signature.args, a_, b_, ai_, out_, oi_, lanes_),
                          signed=False)

    return sig, codegen


@intrinsic
def lanes_sum_wide(typingctx, a, b, ai, out, oi, lanes, span):
    """:func:`lanes_sum` over a whole tube, ``span`` disparities (a multiple of ``LANES``) a chunk at a time (chunk
    ``i`` at ``ai + i``, ``oi + i``, ``lanes - i`` valid lanes); returns its winner as ``minimum << 32 | index`` (the
    minimum's first index; int64), each lane's running minimum and the chunk that first held it in registers (a
    search of the stored sums for the minimum, chunk by chunk, took as long as the sums)."""
    sig = types.int64(a, b, ai, out, oi, lanes, span)

    def codegen(context, builder, signature, args):
        a_, b_, ai_, out_, oi_, lanes_, span_ = args
        mv = cgutils.alloca_once_value(builder, ir.Constant(V16, [65535] * LANES))
        mi = cgutils.alloca_once_value(builder, ir.Constant(VI32, [0] * LANES))
        with cgutils.for_range_slice(builder, ir.Constant(I64, 0), span_, ir.Constant(I64, LANES)) as (i, _):
            v = _chunk_sums(context, builder, signature.args, a_, b_, builder.add(ai_, i), out_, builder.add(oi_, i),
                            builder.sub(lanes_, i))
            old = builder.load(mv)
            lower = builder.icmp_unsigned("<", v, old)  # strictly: a lane keeps the first chunk of its minimum
            builder.store(builder.select(lower, v, old), mv)
            builder.store(builder.select(lower, splat(builder, builder.trunc(i, I32), VI32), builder.load(mi)), mi)
        m = reduce_min(builder, builder.load(mv), signed=False)
        lane = ir.Constant(VI32, list(range(LANES)))
        at_min = builder.icmp_unsigned("==", builder.load(mv), splat(builder, m))
        index = builder.select(at_min, builder.add(builder.load(mi), lane), ir.Constant(VI32, [2 ** 31 - 1] * LANES))
        first = reduce_min(builder, index)
        return builder.or_(builder.shl(builder.zext(m, I64), ir.Constant(I64, 32)), builder.zext(first, I64))

    return sig, codegen


def _vote_intrinsic(n):
    # lanes_vote on n lanes (LANES, or LANES // 2 for tubes that end within them: half the vector work, lane by lane
    # the same)
    vi32 = ir.VectorType(I32, n)
    reverse = ir.Constant(vi32, list(range(n - 1, -1, -1)))
    lane = ir.Constant(vi32, list(range(n)))

    def lanes_vote(typingctx, sums, si, lanes, cost, best, top, xr0, W, d0):
        sig = types.void(sums, si, lanes, cost, best, top, xr0, W, d0)

        def codegen(context, builder, signature, args):
            sums_, si_, lanes_, cost_, best_, top_, xr0_, W_, d0_ = args
            st, _, _, ct, bt = signature.args[:5]

            def i32(v):
                return builder.trunc(v, I32) if v.type.width > 32 else builder.sext(v, I32)

            few = builder.icmp_signed("<", lanes_, ir.Constant(lanes_.type, n))
            lanes_c = builder.select(few, lanes_, ir.Constant(lanes_.type, n))
            sptr = builder.bitcast(vector_ptr(context, builder, st, sums_, si_), ir.VectorType(I16, n).as_pointer())
            s = builder.zext(builder.load(sptr, align=2), vi32)
            low = builder.sub(top_, ir.Constant(I64, n - 1))
            cptr = builder.bitcast(vector_ptr(context, builder, ct, cost_, low, I32), vi32.as_pointer())
            bptr = builder.bitcast(vector_ptr(context, builder, bt, best_, low, I32), vi32.as_pointer())
            undef = ir.Constant(vi32, ir.Undefined)
            rc = builder.shuffle_vector(builder.load(cptr, align=4), undef, reverse)
            rb = builder.shuffle_vector(builder.load(bptr, align=4), undef, reverse)
            xr = builder.sub(splat(builder, i32(xr0_), vi32), lane)
            inside = builder.and_(builder.icmp_signed(">=", xr, ir.Constant(vi32, [0] * n)),
                                  builder.icmp_signed("<", xr, splat(builder, i32(W_), vi32)))
            valid = builder.and_(builder.icmp_signed("<", lane, splat(builder, i32(lanes_c), vi32)), inside)
            dv = builder.add(splat(builder, i32(d0_), vi32), lane)
            better = builder.or_(builder.icmp_signed("<", s, rc),
                                 builder.and_(builder.icmp_signed("==", s, rc), builder.icmp_signed("<", dv, rb)))
            take = builder.and_(valid, better)
            builder.store(builder.shuffle_vector(builder.select(take, s, rc), undef, reverse), cptr, align=4)
            builder.store(builder.shuffle_vector(builder.select(take, dv, rb), undef, reverse), bptr, align=4)
            return context.get_dummy_value()

        return sig, codegen

    return lanes_vote


lanes_vote = intrinsic(_vote_intrinsic(LANES))
lanes_vote.__doc__ = """The right image's votes of ``LANES`` disparities of one left pixel
    (:func:`.disparity._select_tube_lr_kernel`).

    Lane ``l``: the aggregated cost ``sums[si + l]`` (uint16) of disparity index ``d0 + l`` is a candidate for the
    right pixel ``xr0 - l``, whose best cost ``cost[top - l]`` and index ``best[top - l]`` (int32) it replaces where
    lower, or equal with a lower index (what the scalar scan in row order kept: the lowest disparity wins a tie), for
    ``l < lanes`` and ``0 <= xr0 - l < W``. ``cost`` and ``best`` are read and written whole at ``top - LANES + 1 ..
    top`` (the other lanes written back unchanged), so the caller pads them.
    """
lanes_vote_half = intrinsic(_vote_intrinsic(LANES // 2))
lanes_vote_half.__doc__ = (":func:`lanes_vote` on ``LANES // 2`` lanes (reads ``sums[si:si + LANES // 2]``, ``cost`` "
                           "and ``best`` at ``top - LANES // 2 + 1 .. top``), for a tube that ends within them.")


@intrinsic
def lanes_find(typingctx, arr, index, value):
    """The first lane ``d`` with ``arr[index + d] == value`` (a 16-bit array), ``LANES`` if none (int64)."""
    sig = types.int64(arr, index, value)

    def codegen(context, builder, signature, args):
        arr_, index_, value_ = args
        v = load_i16(context, builder, signature.args[0], arr_, index_)
        hit = builder.icmp_unsigned("==", v, splat(builder, value_))
        bits = builder.bitcast(hit, ir.IntType(LANES))
        first = builder.cttz(bits, ir.Constant(ir.IntType(1), 0))  # LANES where no lane hits
        return builder.zext(first, I64)

    return sig, codegen


def _census_intrinsic(n):
    # lanes_census on n lanes (LANES, or LANES // 2 for tubes that end within them: half the 64-bit work)
    vi64, v16 = ir.VectorType(I64, n), ir.VectorType(I16, n)
    reverse = ir.Constant(ir.VectorType(I32, n), list(range(n - 1, -1, -1)))

    def lanes_census(typingctx, flat, fi, a, row, top, scale):
        sig = types.void(flat, fi, a, row, top, scale)

        def codegen(context, builder, signature, args):
            flat_, fi_, a_, row_, top_, scale_ = args
            low = builder.sub(top_, ir.Constant(I64, n - 1))
            rptr = builder.bitcast(vector_ptr(context, builder, signature.args[3], row_, low, I64), vi64.as_pointer())
            r = builder.shuffle_vector(builder.load(rptr, align=8), ir.Constant(vi64, ir.Undefined), reverse)
            x = builder.xor(r, splat(builder, a_, vi64))
            ctpop = declared(builder, f"llvm.ctpop.v{n}i64", vi64, [vi64])
            c = builder.mul(builder.trunc(builder.call(ctpop, [x]), v16), splat(builder, scale_, v16))
            fptr = builder.bitcast(vector_ptr(context, builder, signature.args[0], flat_, fi_), v16.as_pointer())
            builder.store(c, fptr, align=2)
            return context.get_dummy_value()

        return sig, codegen

    return lanes_census


lanes_census = intrinsic(_census_intrinsic(LANES))
lanes_census.__doc__ = """``LANES`` census costs of one left pixel: lane ``i`` is ``popcount(a ^ row[top - i]) * scale``
    (``row`` uint64, the right image's census row; ``flat`` uint16), written to ``flat[fi + i]``, every lane. Reads
    ``row[top - LANES + 1 .. top]``. The lanes past the pixel's tube are the next pixels' in the volume: the caller
    writes those after (and keeps both ranges inside the arrays). Nothing is read from ``flat``: a load of lanes a
    neighbour's store had just written whole, shifted, waited for that store (no store-to-load forwarding), and took
    longer than the scalar loop."""
lanes_census_half = intrinsic(_census_intrinsic(LANES // 2))
lanes_census_half.__doc__ = (":func:`lanes_census` on ``LANES // 2`` lanes (reads ``row[top - LANES // 2 + 1 .. "
                             "top]``, writes ``flat[fi:fi + LANES // 2]``), for a tube that ends within them.")


@intrinsic
def lanes_census_bits(typingctx, pad, ci, offsets, out, oi):
    """Census transforms of ``LANES`` consecutive pixels at once (:func:`.census.census_transform`).

    Lane ``i``: for each neighbour offset ``k`` of ``offsets`` (int64, flat offsets in ``pad`` relative to the
    centre, in the window's bit order) the bit ``pad[ci + i + k] < pad[ci + i]`` (float32) is shifted in; the 64-bit
    word goes to ``out[oi + i]`` (uint64), every lane. The bits stay in registers across the neighbours: the loop
    over NumPy rows wrote each pixel's word back to memory once per neighbour.
    """
    sig = types.void(pad, ci, offsets, out, oi)

    def codegen(context, builder, signature, args):
        pad_, ci_, offsets_, out_, oi_ = args
        padty, _, offty, outty, _ = signature.args
        centre = builder.load(vector_ptr(context, builder, padty, pad_, ci_, F32), align=4)
        offs = context.make_array(offty)(context, builder, offsets_)
        n = builder.extract_value(offs.shape, 0)
        # the word's high bits (all but the last 32 neighbours) and its low 32 bits in two 32-bit accumulators: half
        # the vector work of shifting 64-bit lanes, the same word
        split = builder.select(builder.icmp_signed(">", n, ir.Constant(I64, 32)), builder.sub(n, ir.Constant(I64, 32)),
                               ir.Constant(I64, 0))
        halves = []
        for lo, hi in ((ir.Constant(I64, 0), split), (split, n)):
            acc = cgutils.alloca_once_value(builder, ir.Constant(VI32, [0] * LANES))
            with cgutils.for_range_slice(builder, lo, hi, ir.Constant(I64, 1)) as (index, _):
                k = builder.load(builder.gep(offs.data, [index]))
                nb = builder.load(vector_ptr(context, builder, padty, pad_, builder.add(ci_, k), F32), align=4)
                bit = builder.zext(builder.fcmp_ordered("<", nb, centre), VI32)
                shifted = builder.shl(builder.load(acc), ir.Constant(VI32, [1] * LANES))
                builder.store(builder.or_(shifted, bit), acc)
            halves.append(builder.zext(builder.load(acc), VI64))
        word = builder.or_(builder.shl(halves[0], ir.Constant(VI64, [32] * LANES)), halves[1])
        builder.store(word, vector_ptr(context, builder, outty, out_, oi_, I64), align=8)
        return context.get_dummy_value()

    return sig, codegen
