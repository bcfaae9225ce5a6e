"""The SGM passes' runs along a row (:func:`lanes_run_pair`): LLVM vector code (Numba intrinsics; the conventions
of :mod:`.lanes`) that steps a run of pixels whose tubes start at the same disparity as their row neighbour's, the
row's path costs carried from pixel to pixel in registers (:func:`..sgm_pass._pair_steps`,
:func:`..sgm_pass._wide_pair_steps`).

Inside riverbed's runtime ``Env`` (the program, the tests) kernels are cached per digest of the kernel sources
(:mod:`riverbed_cli.runtime.numba_cache`): editing this module recompiles the kernels that use it. A program that
imports riverbed without the ``Env`` has Numba's own cache, which keys a kernel on its own file: after editing this
module, delete the cached kernels of ``riverbed_cli/matching/__pycache__/sgm.*.nb[ic]``.
"""

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from .lanes import SENTINEL, neighbour_min
from .vector_ir import (I32, I64, LANES, V16, VI32, Args, load_i16, masked_store, reduce_min, smin, splat,
                        store_vector, typed, valid)

# shuffle_vector(sentinels, pv, _LANE_BEFORE): lane d holds pv[d - 1] (lane 0 the sentinel before the tube);
# shuffle_vector(pv, sentinels, _LANE_AFTER): lane d holds pv[d + 1] (the last lane the sentinel chunk's)
_LANE_BEFORE = ir.Constant(VI32, [LANES - 1 + d for d in range(LANES)])
_LANE_AFTER = ir.Constant(VI32, [d + 1 for d in range(LANES)])


def _spread_min(builder, v):
    # the minimum over the lanes in every lane, by swapping halves, quarters, ... (no trip through a scalar register:
    # on the run's chain from pixel to pixel)
    n = LANES
    while n > 1:
        n //= 2
        swap = ir.Constant(VI32, [i ^ n for i in range(LANES)])
        v = smin(builder, v, builder.shuffle_vector(v, ir.Constant(V16, ir.Undefined), swap))
    return v


#: the widest tubes (in chunks of LANES) whose steps go in runs (lanes_run_pair): an aerial pair's 0..143 holes are 9
RUN_CHUNKS_MAX = 12


def _run_codegen(a, C):
    # lanes_run_pair's loop for tubes of C chunks (a: its Args); returns the first pixel after the run
    context, builder = a.context, a.builder
    lt = a.type("L")
    get = a.at  # an element of a 1-D argument: get("rws", x) is rws[x]
    lanes = ir.Constant(I64, LANES)
    span = ir.Constant(I64, C * LANES)
    one = ir.Constant(I64, 1)
    sent = ir.Constant(V16, [SENTINEL] * LANES)

    def entry(base, x):  # the start of a ring-buffer entry
        return builder.add(builder.mul(builder.add(base, x), a.R), a.guard)

    def chunks(w):  # how many chunks a tube of w (>= 0) disparities takes
        return builder.udiv(builder.add(w, ir.Constant(I64, LANES - 1)), lanes)

    x_ptr = cgutils.alloca_once_value(builder, a.xx)
    pent = entry(a.cbase0, builder.sub(a.xx, one))
    pv_ptrs = [cgutils.alloca_once_value(builder, load_i16(context, builder, lt, a.L,
                                                           builder.add(pent, ir.Constant(I64, i * LANES))))
               for i in range(C)]
    mp_ptr = cgutils.alloca_once_value(builder, splat(builder, get("Lmin", builder.sub(builder.add(a.cbase0, a.xx),
                                                                                        one))))
    body = builder.append_basic_block(f"run{C}_body")
    check = builder.append_basic_block(f"run{C}_check")
    exit_ = builder.append_basic_block(f"run{C}_exit")
    builder.branch(body)

    builder.position_at_end(body)
    x = builder.load(x_ptr)
    b = get("rb", x)
    w = get("rws", x)
    prev = builder.sub(builder.add(entry(a.pbase1, x), builder.sub(get("ros", x), get("rop1", x))), one)
    mp1 = get("Lmin", builder.add(a.pbase1, x))
    cur1 = entry(a.cbase1, x)
    pv = [builder.load(ptr) for ptr in pv_ptrs]
    mpv = builder.load(mp_ptr)  # the previous pixel's minimum in every lane
    rows, rmin, cmin = [], None, None
    for i in range(C):
        off = ir.Constant(I64, i * LANES)
        mask = valid(builder, builder.sub(w, off))
        c = a.load("cost", builder.add(b, off))
        # the row's step from the previous pixel's costs in registers (lane shifts across its chunks)
        before = builder.shuffle_vector(pv[i - 1] if i else sent, pv[i], _LANE_BEFORE)
        after = builder.shuffle_vector(pv[i], pv[i + 1] if i < C - 1 else sent, _LANE_AFTER)
        v0 = smin(builder, pv[i], builder.add(smin(builder, before, after), splat(builder, a.p1)))
        # c + min(v0, mp + P2) - mp as c + min(v0 - mp, P2) (the same integers): v0 does not wait for the minimum
        v0 = smin(builder, builder.sub(v0, mpv), splat(builder, a.p2))
        row = builder.select(mask, builder.add(c, v0), sent)
        # the column's step from the row before's entry, shifted by the difference of the tubes' offsets
        v1 = neighbour_min(context, builder, lt, a.L, builder.add(prev, off), a.p1, builder.add(mp1, a.p2))
        col = builder.select(mask, builder.sub(builder.add(c, v1), splat(builder, mp1)), sent)
        store_vector(context, builder, lt, a.L, builder.add(cur1, off), col)
        masked_store(builder, builder.add(row, col), a.ptr("out", builder.add(b, off)), mask)
        rows.append(row)
        rmin = row if rmin is None else smin(builder, rmin, row)
        cmin = col if cmin is None else smin(builder, cmin, col)
    store_vector(context, builder, lt, a.L, builder.add(cur1, span), sent)
    builder.store(reduce_min(builder, cmin), a.element("Lmin", builder.add(a.cbase1, x)))
    builder.store(ir.Constant(ir.IntType(8), 1), a.element("done", x))
    for ptr, row in zip(pv_ptrs, rows):
        builder.store(row, ptr)
    builder.store(_spread_min(builder, rmin), mp_ptr)
    nx = builder.add(x, one)
    builder.store(nx, x_ptr)
    builder.branch(check)

    # whether the next pixel qualifies (each test in its own block: the later ones read its layout)
    builder.position_at_end(check)
    tests = [lambda: builder.icmp_signed("<", nx, a.W),
             lambda: builder.icmp_signed("==", chunks(get("rws", nx)), ir.Constant(I64, C)),
             lambda: builder.icmp_signed("<=", builder.add(get("rb", nx), span), a.n),
             lambda: builder.icmp_signed("==", get("ros", nx), get("ros", x))]

    def reach():  # sgm_pass._reaches of the column's shift
        s = builder.sub(get("ros", nx), get("rop1", nx))
        top = builder.and_(builder.add(get("rwp1", nx), ir.Constant(I64, LANES - 1)), ir.Constant(I64, -LANES))
        return builder.and_(builder.icmp_signed(">=", s, builder.sub(one, a.guard)),
                            builder.icmp_signed("<=", s, builder.sub(builder.add(top, lanes),
                                                                     builder.add(span, one))))

    tests.append(reach)
    for k, test in enumerate(tests):
        nxt = body if k == len(tests) - 1 else builder.append_basic_block(f"run{C}_check{k}")
        builder.cbranch(test(), nxt, exit_)
        if nxt is not body:
            builder.position_at_end(nxt)

    # the run's last pixel's row path costs and minimum, for the step after the run
    builder.position_at_end(exit_)
    x = builder.load(x_ptr)
    last = builder.sub(x, one)
    cur0 = entry(a.cbase0, last)
    for i, ptr in enumerate(pv_ptrs):
        store_vector(context, builder, lt, a.L, builder.add(cur0, ir.Constant(I64, i * LANES)), builder.load(ptr))
    store_vector(context, builder, lt, a.L, builder.add(cur0, span), sent)
    builder.store(builder.extract_element(builder.load(mp_ptr), ir.Constant(I32, 0)),
                  a.element("Lmin", builder.add(a.cbase0, last)))
    return x


@intrinsic
def lanes_run_pair(typingctx, L, cost, Lmin, rb, rws, ros, rwp1, rop1, done, out, xx, W, n, guard, cbase0, cbase1,
                   pbase1, R, p1, p2, chunks):
    """:func:`lanes_step_pair` (``chunks`` 1) or :func:`lanes_step_wide_pair` over a run of a row's pixels from
    ``xx`` on, each starting at the same disparity as its row neighbour, in tubes of ``chunks`` chunks of ``LANES``
    (nearly every step: the tubes are made per cell, and a hole's pixels all search the whole range).

    The row's path costs are carried from pixel to pixel in registers: the neighbour's costs at ``d - 1``, ``d``,
    ``d + 1`` are lane shifts across its chunks (the sentinel before and after them), its minimum is spread over the
    lanes without a scalar register, and the step is ``c + min(v - mp, P2)`` (the same integers as ``c + min(v, mp +
    P2) - mp``), so that ``v`` does not wait for the minimum. Loads one disparity off the address where the
    neighbour's step had just stored its costs waited for the store; a step per pixel reloaded the run's few values
    from the stack.

    The arguments are :func:`..sgm_pass._pair_steps`'s (the sweep's layout ``rb``, ``rws``, ``ros`` of this row and
    ``rwp1``, ``rop1`` of the row before, indexed by the sweep's pixel; ``n`` the volume's size, ``guard`` the ring
    buffer's entries' guard). The caller has checked that pixel ``xx`` qualifies, that its row neighbour's tube takes
    ``chunks`` chunks too, and ``1 <= chunks <=`` :data:`RUN_CHUNKS_MAX`; the run goes on while the next pixel
    qualifies: a tube of ``chunks`` chunks lying inside the volume, starting at the same disparity as its row
    neighbour's, whose column neighbour's entry holds all its reads. Each pixel's column path costs and minimum, its
    half-sum and ``done`` are written as :func:`lanes_step_pair`'s caller writes them; the row's path costs and
    minimum only for the run's last pixel (the only one another step reads). Returns the first pixel after the run
    (``xx`` itself for ``chunks`` out of bounds)."""
    names, sig = typed(locals(), types.int64)

    def codegen(context, builder, signature, args):
        a = Args(names, context, builder, signature, args)
        result = cgutils.alloca_once_value(builder, a.xx)
        merge = builder.append_basic_block("run_merge")
        switch = builder.switch(a.chunks, merge)
        for C in range(1, RUN_CHUNKS_MAX + 1):
            block = builder.append_basic_block(f"run{C}")
            switch.add_case(ir.Constant(a.chunks.type, C), block)
            builder.position_at_end(block)
            builder.store(_run_codegen(a, C), result)
            builder.branch(merge)
        builder.position_at_end(merge)
        return builder.load(result)

    return sig, codegen
