"""Fixed-width vector steps for the SGM passes, the selection, the guidance and the census cost, written as LLVM
vector code (Numba intrinsics).

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

The guidance's walls (:func:`lanes_walls`, :func:`lanes_flat`) work on ``LANES`` disparities of one pixel's tube in
float64 (float32 where the walls are flat, as the scalar code did). Their ``_whole`` forms read and write all lanes
(those past the tube written back unchanged), for chunks inside a block of pixels one thread modulates; the masked
forms neither read nor write the lanes past a tube, for chunks that reach into another thread's block. Measured on
the captured inputs of the dev pairs: the modulation 2-2.3x faster than its scalar loops, the same bits
(docs/tubes.md). The
ownership's claims (:func:`lanes_claim` and its variants) work on ``LANES`` pixels of a window row in float64, the
comparisons of the scalar code lane by lane: 0.64-0.70x of its time on the dev pairs, the same owners and weights.
Inside a row they load and store whole vectors (the lanes past the window written back unchanged: only the thread
of that band writes the row); masked loads and stores, about 1.3x slower on this VM's CPU, serve the rows' ends.
The census cost (:func:`lanes_census`) writes ``LANES`` costs of a tube whole, its lanes past the tube left for the
next pixels to overwrite: 0.53-0.6x of the scalar loop's time on the aerial pair. A step that reads lanes its
neighbour has just stored whole at a shifted address waits for that store (no store-to-load forwarding): the
right image's votes of the left-right check done this way took as long as the scalar loop, so they stay scalar.
The census transform (:func:`lanes_census_bits`) keeps 16 pixels' words in registers across the window's
neighbours: 0.62-0.70x of the loop that wrote each word back once per neighbour.
An SGM step of a tube wider than ``LANES`` (:func:`lanes_step_min`) folds its chunk into a running minimum, reduced
once per pixel (:func:`lanes_reduce`) instead of once per chunk: the passes 0.92-0.97x on the dev pairs.

Numba's cache keys a kernel on its own source file only: after editing this module, delete the cached kernels of the
modules that use it (``riverbed_cli/matching/__pycache__/{sgm,disparity,guidance,census}.*.nb[ic]``), or they keep
the old steps.
"""

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

LANES = 16  # 256 bits of int16: on the dev machine 16 lanes beat 32 (most tubes are under 16 wide)
SENTINEL = 16384  # above any path cost (sgm.check_sgm_bounds); SENTINEL + P1 still fits int16

_I16 = ir.IntType(16)
_I32 = ir.IntType(32)
_I64 = ir.IntType(64)
_F32 = ir.FloatType()
_F64 = ir.DoubleType()
_V16 = ir.VectorType(_I16, LANES)
_VI64 = ir.VectorType(_I64, LANES)
_VI32 = ir.VectorType(_I32, LANES)
_VF32 = ir.VectorType(_F32, LANES)
_VF64 = ir.VectorType(_F64, LANES)
_MASK = ir.VectorType(ir.IntType(1), LANES)
_LANE_INDEX = ir.Constant(_VI64, list(range(LANES)))
_REVERSE = ir.Constant(ir.VectorType(_I32, LANES), list(range(LANES - 1, -1, -1)))


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
    if value.type != vty.element and isinstance(value.type, ir.IntType):
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


def _store_path_costs(context, builder, sig_args, v, mask, L, cur, acc, ai, keep):
    # lanes past the tube hold the sentinel (unreachable for the next pixel); the path cost joins the half-sum
    # (keep 0: the pixel's first direction starts it, so the half-sum needs no zeroing per pixel); returns the
    # stored lanes
    v = builder.select(mask, v, ir.Constant(_V16, [SENTINEL] * LANES))
    _store(context, builder, sig_args[0], L, cur, v)
    accty = sig_args[1]
    kept = builder.and_(_load(context, builder, accty, acc, ai), _splat(builder, keep))
    _store(context, builder, accty, acc, ai, builder.add(kept, v))
    return v


def _finish(context, builder, sig_args, v, mask, L, cur, acc, ai, keep):
    # _store_path_costs, then the minimum over the lanes
    return _reduce_min(builder, _store_path_costs(context, builder, sig_args, v, mask, L, cur, acc, ai, keep))


def _step_value(context, builder, sig_args, L, cost, ci, prev, p1, jump, mp):
    # cost + min(a, min(b, e) + P1, jump) - mp with a, b, e the previous path costs at prev + 1, prev, prev + 2
    lt = sig_args[0]
    b = _load(context, builder, lt, L, prev)
    a = _load(context, builder, lt, L, builder.add(prev, ir.Constant(_I64, 1)))
    e = _load(context, builder, lt, L, builder.add(prev, ir.Constant(_I64, 2)))
    v = _smin(builder, a, builder.add(_smin(builder, b, e), _splat(builder, p1)))
    v = _smin(builder, v, _splat(builder, jump))
    c = _load(context, builder, sig_args[3], cost, ci)
    return builder.sub(builder.add(c, v), _splat(builder, mp))


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
        v = _step_value(context, builder, signature.args, L_, cost_, ci_, prev_, p1_, jump_, mp_)
        return _finish(context, builder, signature.args, v, _valid(builder, lanes_), L_, cur_, acc_, ai_, keep_)

    return sig, codegen


@intrinsic
def lanes_step_min(typingctx, L, acc, cur, cost, ci, ai, lanes, prev, p1, jump, mp, keep, mv, first):
    """:func:`lanes_step` for one chunk of a tube wider than ``LANES``: instead of returning the chunk's minimum, its
    lanes join a running minimum ``mv[0:LANES]`` (int16; ``first``: start it), reduced once for the pixel by
    :func:`lanes_reduce` (one horizontal reduction per pixel, not per chunk)."""
    sig = types.void(L, acc, cur, cost, ci, ai, lanes, prev, p1, jump, mp, keep, mv, first)

    def codegen(context, builder, signature, args):
        L_, acc_, cur_, cost_, ci_, ai_, lanes_, prev_, p1_, jump_, mp_, keep_, mv_, first_ = args
        v = _step_value(context, builder, signature.args, L_, cost_, ci_, prev_, p1_, jump_, mp_)
        v = _store_path_costs(context, builder, signature.args, v, _valid(builder, lanes_), L_, cur_, acc_, ai_,
                              keep_)
        zero = ir.Constant(_I64, 0)
        old = _load(context, builder, signature.args[12], mv_, zero)
        first_ = builder.icmp_signed("!=", first_, ir.Constant(first_.type, 0))
        _store(context, builder, signature.args[12], mv_, zero, builder.select(first_, v, _smin(builder, old, v)))
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def lanes_reduce(typingctx, mv):
    """The minimum of ``mv[0:LANES]`` (int16)."""
    sig = types.int16(mv)

    def codegen(context, builder, signature, args):
        return _reduce_min(builder, _load(context, builder, signature.args[0], args[0], ir.Constant(_I64, 0)))

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
def lanes_vote(typingctx, sums, si, lanes, cost, best, top, xr0, W, d0):
    """The right image's votes of ``LANES`` disparities of one left pixel (:func:`.disparity._select_tube_lr_kernel`).

    Lane ``l``: the aggregated cost ``sums[si + l]`` (uint16) of disparity index ``d0 + l`` is a candidate for the
    right pixel ``xr0 - l``, whose best cost ``cost[top - l]`` and index ``best[top - l]`` (int32) it replaces where
    lower, or equal with a lower index (what the scalar scan in row order kept: the lowest disparity wins a tie), for
    ``l < lanes`` and ``0 <= xr0 - l < W``. ``cost`` and ``best`` are read and written whole at ``top - LANES + 1 ..
    top`` (the other lanes written back unchanged), so the caller pads them.
    """
    sig = types.void(sums, si, lanes, cost, best, top, xr0, W, d0)

    def codegen(context, builder, signature, args):
        sums_, si_, lanes_, cost_, best_, top_, xr0_, W_, d0_ = args
        st, _, _, ct, bt = signature.args[:5]
        lane = ir.Constant(_VI32, list(range(LANES)))

        def i32(v):
            return builder.trunc(v, _I32) if v.type.width > 32 else builder.sext(v, _I32)

        few = builder.icmp_signed("<", lanes_, ir.Constant(lanes_.type, LANES))
        lanes_c = builder.select(few, lanes_, ir.Constant(lanes_.type, LANES))
        s = builder.zext(_load(context, builder, st, sums_, si_), _VI32)
        low = builder.sub(top_, ir.Constant(_I64, LANES - 1))
        cptr = _vector_ptr(context, builder, ct, cost_, low, _I32)
        bptr = _vector_ptr(context, builder, bt, best_, low, _I32)
        undef = ir.Constant(_VI32, ir.Undefined)
        rc = builder.shuffle_vector(builder.load(cptr, align=4), undef, _REVERSE)
        rb = builder.shuffle_vector(builder.load(bptr, align=4), undef, _REVERSE)
        xr = builder.sub(_splat(builder, i32(xr0_), _VI32), lane)
        inside = builder.and_(builder.icmp_signed(">=", xr, ir.Constant(_VI32, [0] * LANES)),
                              builder.icmp_signed("<", xr, _splat(builder, i32(W_), _VI32)))
        valid = builder.and_(builder.icmp_signed("<", lane, _splat(builder, i32(lanes_c), _VI32)), inside)
        dv = builder.add(_splat(builder, i32(d0_), _VI32), lane)
        better = builder.or_(builder.icmp_signed("<", s, rc),
                             builder.and_(builder.icmp_signed("==", s, rc), builder.icmp_signed("<", dv, rb)))
        take = builder.and_(valid, better)
        builder.store(builder.shuffle_vector(builder.select(take, s, rc), undef, _REVERSE), cptr, align=4)
        builder.store(builder.shuffle_vector(builder.select(take, dv, rb), undef, _REVERSE), bptr, align=4)
        return context.get_dummy_value()

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


def _fmin(builder, a, b):
    # Python's min(a, b) of floats: b if b < a else a
    return builder.select(builder.fcmp_ordered("<", b, a), b, a)


def _declared(builder, name, ret, argtys):
    fn = builder.module.globals.get(name)
    return fn if fn is not None else ir.Function(builder.module, ir.FunctionType(ret, argtys), name=name)


def _masked_load(builder, ptr, mask, vty=_V16):
    # lanes outside the mask are not read (no fault past an array's end) and load as 0
    name = f"llvm.masked.load.v{LANES}{_elem_name(vty)}.p0"
    align = ir.Constant(ir.IntType(32), _elem_bytes(vty))
    fn = _declared(builder, name, vty, [ptr.type, ir.IntType(32), _MASK, vty])
    return builder.call(fn, [ptr, align, mask, ir.Constant(vty, [0] * LANES)])


def _masked_store(builder, value, ptr, mask):
    # lanes outside the mask are not written
    vty = value.type
    name = f"llvm.masked.store.v{LANES}{_elem_name(vty)}.p0"
    align = ir.Constant(ir.IntType(32), _elem_bytes(vty))
    fn = _declared(builder, name, ir.VoidType(), [vty, ptr.type, ir.IntType(32), _MASK])
    builder.call(fn, [value, ptr, align, mask])


def _elem_name(vty):
    e = vty.element
    return f"i{e.width}" if isinstance(e, ir.IntType) else ("f64" if isinstance(e, ir.DoubleType) else "f32")


def _elem_bytes(vty):
    e = vty.element
    return e.width // 8 if isinstance(e, ir.IntType) else (8 if isinstance(e, ir.DoubleType) else 4)


def _flat_wall(builder, q16, a1, g1, fcap):
    # min(a1 * q + g1, fcap) in float32, truncated to uint16: where the walls are flat (g = 1)
    flat = builder.fmul(_splat(builder, a1, _VF32), builder.uitofp(q16, _VF32))
    flat = builder.fadd(flat, _splat(builder, g1, _VF32))
    return builder.fptoui(_fmin(builder, flat, _splat(builder, fcap, _VF32)), _V16)


#: exp(-x) by the 32nd power of a degree-9 Taylor polynomial of exp(-x / 32): relative error under 4e-7 for
#: 0 <= x <= 22 (where the walls are not flat: t < 6.5 c + 1 px); no call, so it vectorises (Numba has no SVML here)
_TAYLOR = [1.0 / f for f in (362880.0, 40320.0, 5040.0, 720.0, 120.0, 24.0, 6.0, 2.0, 1.0, 1.0)]
_NEG_EXP_MAX = 40.0  # x is clipped here: lanes farther out are flat and take the flat value


def _neg_exp(builder, x):
    y = builder.fmul(x, ir.Constant(_VF64, [-1.0 / 32.0] * LANES))
    p = ir.Constant(_VF64, [_TAYLOR[0]] * LANES)
    for c in _TAYLOR[1:]:
        p = builder.fadd(builder.fmul(p, y), ir.Constant(_VF64, [c] * LANES))
    for _ in range(5):
        p = builder.fmul(p, p)
    return p


def _load_lanes(builder, ptr, mask, vty, masked):
    # masked: lanes outside the mask are not read (0); else all LANES are read
    return _masked_load(builder, ptr, mask, vty) if masked else builder.load(ptr, align=_elem_bytes(vty))


def _store_lanes(builder, value, old, ptr, mask, masked):
    # masked: lanes outside the mask are not written; else they are written back with their own values (old)
    if masked:
        _masked_store(builder, value, ptr, mask)
    else:
        builder.store(builder.select(mask, value, old), ptr, align=_elem_bytes(value.type))


def _walls_intrinsic(masked):
    def lanes_walls(typingctx, arr, ai, i0, dmin, right, left, lo, hi, alpha, beta, gamma, a1, g1, inv2c2, cap, fcap,
                    lanes):
        sig = types.void(arr, ai, i0, dmin, right, left, lo, hi, alpha, beta, gamma, a1, g1, inv2c2, cap, fcap, lanes)

        def codegen(context, builder, signature, args):
            arr_, ai_, i0_, dmin_, right_, left_, lo_, hi_, alpha_, beta_, gamma_, a1_, g1_, k_, cap_, fcap_, lanes_ = (
                args)
            mask = _valid(builder, lanes_)
            ptr = _vector_ptr(context, builder, signature.args[0], arr_, ai_)
            q16 = _load_lanes(builder, ptr, mask, _V16, masked)
            idx = builder.add(_splat(builder, i0_, _VI64), _LANE_INDEX)
            d = builder.sitofp(builder.add(idx, _splat(builder, dmin_, _VI64)), _VF64)
            tr = builder.fsub(d, _splat(builder, right_, _VF64))
            tl = builder.fsub(_splat(builder, left_, _VF64), d)
            t = builder.select(builder.fcmp_ordered(">", tl, tr), tl, tr)
            zero = ir.Constant(_VF64, [0.0] * LANES)
            t = builder.select(builder.fcmp_ordered(">", t, zero), t, zero)
            x = _fmin(builder, builder.fmul(builder.fmul(t, t), _splat(builder, k_, _VF64)),
                      ir.Constant(_VF64, [_NEG_EXP_MAX] * LANES))
            g = builder.fsub(ir.Constant(_VF64, [1.0] * LANES), _neg_exp(builder, x))
            q = builder.uitofp(q16, _VF64)
            height = builder.fadd(_splat(builder, alpha_, _VF64), builder.fmul(_splat(builder, beta_, _VF64), g))
            wall = builder.fadd(builder.fadd(builder.fmul(height, q), builder.fmul(_splat(builder, gamma_, _VF64), g)),
                                ir.Constant(_VF64, [0.5] * LANES))
            wall = builder.fptoui(_fmin(builder, wall, _splat(builder, cap_, _VF64)), _V16)
            flat = builder.or_(builder.icmp_signed("<", idx, _splat(builder, lo_, _VI64)),
                               builder.icmp_signed(">=", idx, _splat(builder, hi_, _VI64)))
            out = builder.select(flat, _flat_wall(builder, q16, a1_, g1_, fcap_), wall)
            _store_lanes(builder, out, q16, ptr, mask, masked)
            return context.get_dummy_value()

        return sig, codegen

    return lanes_walls


def _flat_intrinsic(masked):
    def lanes_flat(typingctx, arr, ai, a1, g1, fcap, lanes):
        sig = types.void(arr, ai, a1, g1, fcap, lanes)

        def codegen(context, builder, signature, args):
            arr_, ai_, a1_, g1_, fcap_, lanes_ = args
            mask = _valid(builder, lanes_)
            ptr = _vector_ptr(context, builder, signature.args[0], arr_, ai_)
            q16 = _load_lanes(builder, ptr, mask, _V16, masked)
            _store_lanes(builder, _flat_wall(builder, q16, a1_, g1_, fcap_), q16, ptr, mask, masked)
            return context.get_dummy_value()

        return sig, codegen

    return lanes_flat


_WALLS_DOC = """The riverbed modulation of ``LANES`` disparities of a pixel's tube (:func:`.guidance._modulate_kernel`).

    Lane ``i`` (``i0 + lane``, disparity ``d = dmin + i``) of ``q = arr[ai + lane]`` (uint16): where ``i < lo`` or
    ``i >= hi`` (the walls are flat) ``min(a1 * q + g1, fcap)`` in float32; elsewhere, with ``t = max(d - right,
    left - d, 0)`` the distance past the band ``[left, right]`` and the wall height ``g = 1 - exp(-t^2 inv2c2)``,
    ``min((alpha + beta g) q + gamma g + 0.5, cap)`` in float64; truncated to uint16 in place, for the first
    ``lanes`` lanes. {reads}
    """
_FLAT_DOC = """``arr[ai + lane] = min(a1 * q + g1, fcap)`` (float32, truncated to uint16) for the first ``lanes``
    lanes: a chunk of a tube where the walls are flat (:func:`lanes_walls` there, without the wall). {reads}
    """
_MASKED = "Only those lanes are read and written."
_WHOLE = ("All ``LANES`` elements are read and written (the others written back unchanged): masked loads and stores "
          "took 1.3-1.7x as long on this VM's CPU; for lanes no other thread writes meanwhile.")

lanes_walls = intrinsic(_walls_intrinsic(True))
lanes_walls.__doc__ = _WALLS_DOC.format(reads=_MASKED)
lanes_walls_whole = intrinsic(_walls_intrinsic(False))
lanes_walls_whole.__doc__ = _WALLS_DOC.format(reads=_WHOLE)
lanes_flat = intrinsic(_flat_intrinsic(True))
lanes_flat.__doc__ = _FLAT_DOC.format(reads=_MASKED)
lanes_flat_whole = intrinsic(_flat_intrinsic(False))
lanes_flat_whole.__doc__ = _FLAT_DOC.format(reads=_WHOLE)


def _colour_intrinsic(masked):
    def lanes_colour(typingctx, planes, pi, ref, dd, first, lanes):
        sig = types.void(planes, pi, ref, dd, first, lanes)

        def codegen(context, builder, signature, args):
            planes_, pi_, ref_, dd_, first_, lanes_ = args
            mask = _valid(builder, lanes_)
            ptr = _vector_ptr(context, builder, signature.args[0], planes_, pi_, _F32)
            t = builder.fsub(_load_lanes(builder, ptr, mask, _VF32, masked), _splat(builder, ref_, _VF32))
            sq = builder.fpext(builder.fmul(t, t), _VF64)
            ptr = _vector_ptr(context, builder, signature.args[3], dd_, ir.Constant(_I64, 0), _F64)
            acc = builder.fadd(builder.load(ptr, align=8), sq)
            first_ = builder.icmp_signed("!=", first_, ir.Constant(first_.type, 0))
            builder.store(builder.select(first_, sq, acc), ptr, align=8)
            return context.get_dummy_value()

        return sig, codegen

    return lanes_colour


def _claim_codegen(context, builder, dd, dissim, owner, ki, dr2, dc0, a, b, e_lo, e_hi, j, mask, arrtys, masked):
    # point j's claim of the lanes, given their colour distances dd (a float64 vector): see _CLAIM_DOC
    dc = builder.add(_splat(builder, dc0, _VI64), _LANE_INDEX)
    sq = builder.sitofp(builder.add(_splat(builder, dr2, _VI64), builder.mul(dc, dc)), _VF64)
    e = builder.fadd(builder.fmul(sq, _splat(builder, a, _VF64)), builder.fmul(dd, _splat(builder, b, _VF64)))
    dptr = _vector_ptr(context, builder, arrtys[0], dissim, ki, _F64)
    optr = _vector_ptr(context, builder, arrtys[1], owner, ki, _I32)
    d = _load_lanes(builder, dptr, mask, _VF64, masked)
    o = _load_lanes(builder, optr, mask, _VI32, masked)
    jv = _splat(builder, j, _VI64)
    inside = builder.and_(builder.fcmp_ordered("<", _splat(builder, e_lo, _VF64), e),
                          builder.fcmp_ordered("<=", e, _splat(builder, e_hi, _VF64)))
    tie = builder.and_(builder.fcmp_ordered("==", e, d), builder.icmp_signed("<", jv, builder.sext(o, _VI64)))
    take = builder.and_(mask, builder.and_(inside, builder.or_(builder.fcmp_ordered("<", e, d), tie)))
    _store_lanes(builder, builder.select(take, e, d), d, dptr, mask, masked)
    _store_lanes(builder, builder.select(take, builder.trunc(jv, _VI32), o), o, optr, mask, masked)


def _claim_intrinsic(masked):
    def lanes_claim(typingctx, dissim, owner, ki, dd, dr2, dc0, a, b, e_lo, e_hi, j, lanes):
        sig = types.void(dissim, owner, ki, dd, dr2, dc0, a, b, e_lo, e_hi, j, lanes)

        def codegen(context, builder, signature, args):
            dissim_, owner_, ki_, dd_, dr2_, dc0_, a_, b_, elo_, ehi_, j_, lanes_ = args
            ddv = builder.load(_vector_ptr(context, builder, signature.args[3], dd_, ir.Constant(_I64, 0), _F64),
                               align=8)
            _claim_codegen(context, builder, ddv, dissim_, owner_, ki_, dr2_, dc0_, a_, b_, elo_, ehi_, j_,
                           _valid(builder, lanes_), signature.args[:2], masked)
            return context.get_dummy_value()

        return sig, codegen

    return lanes_claim


def _claim_rgb_intrinsic(masked):
    def lanes_claim_rgb(typingctx, planes, pi, stride, r0, r1, r2, dissim, owner, ki, dr2, dc0, a, b, e_lo, e_hi, j,
                        lanes):
        sig = types.void(planes, pi, stride, r0, r1, r2, dissim, owner, ki, dr2, dc0, a, b, e_lo, e_hi, j, lanes)

        def codegen(context, builder, signature, args):
            planes_, pi_, stride_, r0_, r1_, r2_, dissim_, owner_, ki_, dr2_, dc0_, a_, b_, elo_, ehi_, j_, lanes_ = (
                args)
            mask = _valid(builder, lanes_)
            dd = None
            for ch, ref in enumerate((r0_, r1_, r2_)):
                index = builder.add(pi_, builder.mul(stride_, ir.Constant(_I64, ch)))
                ptr = _vector_ptr(context, builder, signature.args[0], planes_, index, _F32)
                t = builder.fsub(_load_lanes(builder, ptr, mask, _VF32, masked), _splat(builder, ref, _VF32))
                sq = builder.fpext(builder.fmul(t, t), _VF64)
                dd = sq if dd is None else builder.fadd(dd, sq)  # (0 + x0) + x1 + x2 as the channel loop adds them
            _claim_codegen(context, builder, dd, dissim_, owner_, ki_, dr2_, dc0_, a_, b_, elo_, ehi_, j_, mask,
                           signature.args[6:8], masked)
            return context.get_dummy_value()

        return sig, codegen

    return lanes_claim_rgb


_COLOUR_DOC = """One channel's squared colour differences of the ownership (:func:`.guidance._claim`), ``LANES`` pixels.

    Lane ``i``: ``t = planes[pi + i] - ref`` (float32), ``dd[i] = t * t`` widened to float64, added to ``dd[i]``
    unless ``first`` (true for the first channel); ``dd`` holds ``LANES`` float64. {reads}
    """
_CLAIM_DOC = """Point ``j``'s claim of ``LANES`` pixels of one window row (:func:`.guidance._claim`).

    Lane ``i``: ``e = (dr2 + dc^2) a + dd[i] b`` with ``dc = dc0 + i`` (the column offset to the point); the pixel
    ``ki + i`` of the flat ``dissim`` (float64) and ``owner`` (int32) takes ``e`` and ``j`` where ``e_lo < e <=
    e_hi`` and ``e`` is below its ``dissim`` (or equal to it, with ``j`` below its owner), for the first ``lanes``
    lanes. {reads}
    """

lanes_colour = intrinsic(_colour_intrinsic(True))
lanes_colour.__doc__ = _COLOUR_DOC.format(reads="Only those lanes of ``planes`` are read.")
lanes_colour_whole = intrinsic(_colour_intrinsic(False))
lanes_colour_whole.__doc__ = _COLOUR_DOC.format(reads="All ``LANES`` elements of ``planes`` are read.")
lanes_claim = intrinsic(_claim_intrinsic(True))
lanes_claim.__doc__ = _CLAIM_DOC.format(reads=_MASKED)
lanes_claim_whole = intrinsic(_claim_intrinsic(False))
lanes_claim_whole.__doc__ = _CLAIM_DOC.format(reads=_WHOLE)

_RGB_DOC = """:func:`lanes_claim` with the colour distances of three channels computed on the way:
    ``planes[pi + c * stride + i]`` against ``r0``, ``r1``, ``r2`` (float32), as :func:`lanes_colour` adds them.
    {reads}
    """
lanes_claim_rgb = intrinsic(_claim_rgb_intrinsic(True))
lanes_claim_rgb.__doc__ = _RGB_DOC.format(reads=_MASKED)
lanes_claim_rgb_whole = intrinsic(_claim_rgb_intrinsic(False))
lanes_claim_rgb_whole.__doc__ = _RGB_DOC.format(reads=_WHOLE)


@intrinsic
def lanes_census(typingctx, flat, fi, a, row, top, scale):
    """``LANES`` census costs of one left pixel: lane ``i`` is ``popcount(a ^ row[top - i]) * scale`` (``row`` uint64,
    the right image's census row; ``flat`` uint16), written to ``flat[fi + i]``, every lane. Reads
    ``row[top - LANES + 1 .. top]``. The lanes past the pixel's tube are the next pixels' in the volume: the caller
    writes those after (and keeps both ranges inside the arrays). Nothing is read from ``flat``: a load of lanes a
    neighbour's store had just written whole, shifted, waited for that store (no store-to-load forwarding), and took
    longer than the scalar loop."""
    sig = types.void(flat, fi, a, row, top, scale)

    def codegen(context, builder, signature, args):
        flat_, fi_, a_, row_, top_, scale_ = args
        low = builder.sub(top_, ir.Constant(_I64, LANES - 1))
        r = builder.load(_vector_ptr(context, builder, signature.args[3], row_, low, _I64), align=8)
        r = builder.shuffle_vector(r, ir.Constant(_VI64, ir.Undefined), _REVERSE)
        x = builder.xor(r, _splat(builder, a_, _VI64))
        ctpop = _declared(builder, f"llvm.ctpop.v{LANES}i64", _VI64, [_VI64])
        c = builder.mul(builder.trunc(builder.call(ctpop, [x]), _V16), _splat(builder, scale_))
        builder.store(c, _vector_ptr(context, builder, signature.args[0], flat_, fi_), align=2)
        return context.get_dummy_value()

    return sig, codegen


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
        centre = builder.load(_vector_ptr(context, builder, padty, pad_, ci_, _F32), align=4)
        offs = context.make_array(offty)(context, builder, offsets_)
        n = builder.extract_value(offs.shape, 0)
        acc = cgutils.alloca_once_value(builder, ir.Constant(_VI64, [0] * LANES))
        with cgutils.for_range(builder, n) as loop:
            k = builder.load(builder.gep(offs.data, [loop.index]))
            nb = builder.load(_vector_ptr(context, builder, padty, pad_, builder.add(ci_, k), _F32), align=4)
            bit = builder.zext(builder.fcmp_ordered("<", nb, centre), _VI64)
            shifted = builder.shl(builder.load(acc), ir.Constant(_VI64, [1] * LANES))
            builder.store(builder.or_(shifted, bit), acc)
        builder.store(builder.load(acc), _vector_ptr(context, builder, outty, out_, oi_, _I64), align=8)
        return context.get_dummy_value()

    return sig, codegen
