"""The riverbed modulation's and the ownership's vector steps (LLVM vector code, Numba intrinsics; the conventions of
:mod:`.lanes`).

The guidance's walls (:func:`lanes_walls`, :func:`lanes_flat`) work on ``LANES`` disparities of one pixel's tube in
float32 (float64 took 1.6x the time, for costs within one unit). Their ``_whole`` forms
read and write all lanes (those past the tube written back unchanged), for chunks inside a block of pixels one thread
modulates; the masked forms neither read nor write the lanes past a tube, for chunks that reach into another thread's
block. Measured on the captured inputs of the dev pairs: the modulation 2-2.3x faster than its scalar loops
(docs/tubes.md).

The ownership's claims (:func:`lanes_claim` and its variants) work on ``LANES`` pixels of a window row in float64,
the comparisons of the scalar code lane by lane: 0.64-0.70x of its time on the dev pairs, the same owners and weights.
Inside a row they load and store whole vectors (the lanes past the window written back unchanged: only the thread
of that band writes the row); masked loads and stores, about 1.3x slower on this VM's CPU, serve the rows' ends.

Inside riverbed's runtime ``Env`` (the program, the tests) kernels are cached per digest of the kernel sources
(:mod:`riverbed_cli.runtime.numba_cache`): editing this module recompiles the kernels that use it. A program that
imports riverbed without the ``Env`` has Numba's own cache, which keys a kernel on its own file: after editing this
module, delete the cached kernels of ``riverbed_cli/matching/__pycache__/guidance.*.nb[ic]``.
"""

from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from .vector_ir import (F32, F64, I16, I32, I64, LANES, V16, VF32, VF64, VI32, elem_bytes, fma, masked_load,
                        masked_store, splat, valid, vector_ptr)



def _fmin(builder, a, b):
    # Python's min(a, b) of floats: b if b < a else a
    return builder.select(builder.fcmp_ordered("<", b, a), b, a)


def _flat_wall(builder, q16, a1, g1, ceiling):
    # min(a1 * q + g1, ceiling) in float32, truncated to uint16: where the walls are flat (g = 1)
    vf32 = ir.VectorType(F32, q16.type.count)
    flat = builder.fmul(splat(builder, a1, vf32), builder.uitofp(q16, vf32))
    flat = builder.fadd(flat, splat(builder, g1, vf32))
    return builder.fptoui(_fmin(builder, flat, splat(builder, ceiling, vf32)), q16.type)


#: exp(-x) by the 32nd power of a degree-9 Taylor polynomial of exp(-x / 32) (Horner's steps fused: one rounding
#: each): relative error under 1e-6 in float32 for 0 <= x <= 22 (where the walls are not flat: t < 6.5 c + 1 px); no
#: call, so it vectorises (Numba has no SVML here)
_TAYLOR = [1.0 / f for f in (362880.0, 40320.0, 5040.0, 720.0, 120.0, 24.0, 6.0, 2.0, 1.0, 1.0)]
_NEG_EXP_MAX = 40.0  # x is clipped here: lanes farther out are flat and take the flat value


def _neg_exp(builder, x):
    n = x.type.count
    y = builder.fmul(x, ir.Constant(x.type, [-1.0 / 32.0] * n))
    p = ir.Constant(x.type, [_TAYLOR[0]] * n)
    for c in _TAYLOR[1:]:
        p = fma(builder, p, y, ir.Constant(x.type, [c] * n))
    for _ in range(5):
        p = builder.fmul(p, p)
    return p


def _load_lanes(builder, ptr, mask, vty, masked):
    # masked: lanes outside the mask are not read (0); else all LANES are read
    return masked_load(builder, ptr, mask, vty) if masked else builder.load(ptr, align=elem_bytes(vty))


def _store_lanes(builder, value, old, ptr, mask, masked):
    # masked: lanes outside the mask are not written; else they are written back with their own values (old)
    if masked:
        masked_store(builder, value, ptr, mask)
    else:
        builder.store(builder.select(mask, value, old), ptr, align=elem_bytes(value.type))


def _walls_intrinsic(masked, n=LANES):
    # n lanes (LANES, or LANES // 2 for tubes that narrow: half the polynomial's work, lane by lane the same). In
    # float32, the band's edges taken relative to dmin in float64 first (the lanes' t as exact at disparity 10000 as
    # at 10): float64 took 1.6x as long on the speed pair's modulation (docs/tubes.md)
    v16, vi32, vf = ir.VectorType(I16, n), ir.VectorType(I32, n), ir.VectorType(F32, n)
    lane_index = ir.Constant(vi32, list(range(n)))

    def lanes_walls(typingctx, arr, ai, i0, dmin, right, left, lo, hi, alpha, beta, gamma, a1, g1, inv2c2, ceiling,
                    lanes):
        sig = types.void(arr, ai, i0, dmin, right, left, lo, hi, alpha, beta, gamma, a1, g1, inv2c2, ceiling, lanes)

        def codegen(context, builder, signature, args):
            arr_, ai_, i0_, dmin_, right_, left_, lo_, hi_, alpha_, beta_, gamma_, a1_, g1_, k_, fcap_, lanes_ = args

            def f32(v):  # a float64 scalar argument, rounded to float32 and splat
                return splat(builder, builder.fptrunc(v, F32), vf)

            mask = builder.icmp_signed("<", lane_index, splat(builder, lanes_, vi32))
            ptr = builder.bitcast(vector_ptr(context, builder, signature.args[0], arr_, ai_), v16.as_pointer())
            q16 = _load_lanes(builder, ptr, mask, v16, masked)
            idx = builder.add(splat(builder, i0_, vi32), lane_index)  # i: disparity dmin + i
            base = builder.sitofp(dmin_, F64)
            d = builder.sitofp(idx, vf)
            tr = builder.fsub(d, f32(builder.fsub(right_, base)))
            tl = builder.fsub(f32(builder.fsub(left_, base)), d)
            t = builder.select(builder.fcmp_ordered(">", tl, tr), tl, tr)
            zero = ir.Constant(vf, [0.0] * n)
            t = builder.select(builder.fcmp_ordered(">", t, zero), t, zero)
            x = _fmin(builder, builder.fmul(builder.fmul(t, t), f32(k_)), ir.Constant(vf, [_NEG_EXP_MAX] * n))
            g = builder.fsub(ir.Constant(vf, [1.0] * n), _neg_exp(builder, x))
            q = builder.uitofp(q16, vf)
            height = fma(builder, f32(beta_), g, f32(alpha_))
            wall = fma(builder, height, q, fma(builder, f32(gamma_), g, ir.Constant(vf, [0.5] * n)))
            wall = builder.fptoui(_fmin(builder, wall, splat(builder, fcap_, vf)), v16)
            flat = builder.or_(builder.icmp_signed("<", idx, splat(builder, lo_, vi32)),
                               builder.icmp_signed(">=", idx, splat(builder, hi_, vi32)))
            out = builder.select(flat, _flat_wall(builder, q16, a1_, g1_, fcap_), wall)
            _store_lanes(builder, out, q16, ptr, mask, masked)
            return context.get_dummy_value()

        return sig, codegen

    return lanes_walls


def _flat_intrinsic(masked):
    def lanes_flat(typingctx, arr, ai, a1, g1, ceiling, lanes):
        sig = types.void(arr, ai, a1, g1, ceiling, lanes)

        def codegen(context, builder, signature, args):
            arr_, ai_, a1_, g1_, fcap_, lanes_ = args
            mask = valid(builder, lanes_)
            ptr = vector_ptr(context, builder, signature.args[0], arr_, ai_)
            q16 = _load_lanes(builder, ptr, mask, V16, masked)
            _store_lanes(builder, _flat_wall(builder, q16, a1_, g1_, fcap_), q16, ptr, mask, masked)
            return context.get_dummy_value()

        return sig, codegen

    return lanes_flat


_WALLS_DOC = """The riverbed modulation of ``LANES`` disparities of a pixel's tube (:func:`.guidance._modulate_kernel`).

    Lane ``i`` (``i0 + lane``, disparity ``d = dmin + i``) of ``q = arr[ai + lane]`` (uint16): where ``i < lo`` or
    ``i >= hi`` (the walls are flat) ``min(a1 * q + g1, ceiling)`` in float32; elsewhere, with ``t = max(d - right,
    left - d, 0)`` the distance past the band ``[left, right]`` and the wall height ``g = 1 - exp(-t^2 inv2c2)``,
    ``min((alpha + beta g) q + gamma g + 0.5, ceiling)`` in float32 with fused multiply-adds (``right`` and ``left``
    taken relative to ``dmin`` in float64 first); truncated to uint16 in place, for the first ``lanes`` lanes
    (``i0``, ``lo``, ``hi`` and ``lanes`` fit int32). {reads}
    """
_FLAT_DOC = """``arr[ai + lane] = min(a1 * q + g1, ceiling)`` (float32, truncated to uint16) for the first ``lanes``
    lanes: a chunk of a tube where the walls are flat (:func:`lanes_walls` there, without the wall). {reads}
    """
_MASKED = "Only those lanes are read and written."
_WHOLE = ("All ``LANES`` elements are read and written (the others written back unchanged): masked loads and stores "
          "took 1.3-1.7x as long on this VM's CPU; for lanes no other thread writes meanwhile.")

lanes_walls = intrinsic(_walls_intrinsic(True))
lanes_walls.__doc__ = _WALLS_DOC.format(reads=_MASKED)
lanes_walls_whole = intrinsic(_walls_intrinsic(False))
lanes_walls_whole.__doc__ = _WALLS_DOC.format(reads=_WHOLE)
lanes_walls_half_whole = intrinsic(_walls_intrinsic(False, LANES // 2))
lanes_walls_half_whole.__doc__ = (":func:`lanes_walls_whole` on ``LANES // 2`` lanes, for tubes that end within them "
                                  "(most are under 8 wide): half the polynomial's work, lane by lane the same bits.")
lanes_flat = intrinsic(_flat_intrinsic(True))
lanes_flat.__doc__ = _FLAT_DOC.format(reads=_MASKED)
lanes_flat_whole = intrinsic(_flat_intrinsic(False))
lanes_flat_whole.__doc__ = _FLAT_DOC.format(reads=_WHOLE)


def _colour_intrinsic(masked):
    def lanes_colour(typingctx, planes, pi, ref, dd, first, lanes):
        sig = types.void(planes, pi, ref, dd, first, lanes)

        def codegen(context, builder, signature, args):
            planes_, pi_, ref_, dd_, first_, lanes_ = args
            mask = valid(builder, lanes_)
            ptr = vector_ptr(context, builder, signature.args[0], planes_, pi_, F32)
            t = builder.fsub(_load_lanes(builder, ptr, mask, VF32, masked), splat(builder, ref_, VF32))
            sq = builder.fpext(builder.fmul(t, t), VF64)
            ptr = vector_ptr(context, builder, signature.args[3], dd_, ir.Constant(I64, 0), F64)
            acc = builder.fadd(builder.load(ptr, align=8), sq)
            first_ = builder.icmp_signed("!=", first_, ir.Constant(first_.type, 0))
            builder.store(builder.select(first_, sq, acc), ptr, align=8)
            return context.get_dummy_value()

        return sig, codegen

    return lanes_colour


def _claim_codegen(context, builder, dd, dissim, owner, ki, spatial, si, b, e_lo, e_hi, j, mask, arrtys, masked):
    # point j's claim of the lanes, given their colour distances dd (a float64 vector): see _CLAIM_DOC. The spatial
    # terms (dr^2 + dc^2) a come from a table (the same for every point: no integer-to-float conversion per claim)
    sp = builder.load(vector_ptr(context, builder, arrtys[2], spatial, si, F64), align=8)
    e = builder.fadd(sp, builder.fmul(dd, splat(builder, b, VF64)))
    dptr = vector_ptr(context, builder, arrtys[0], dissim, ki, F64)
    optr = vector_ptr(context, builder, arrtys[1], owner, ki, I32)
    d = _load_lanes(builder, dptr, mask, VF64, masked)
    o = _load_lanes(builder, optr, mask, VI32, masked)
    jv = splat(builder, j, VI32)  # point indices fit the int32 owners
    inside = builder.and_(builder.fcmp_ordered("<", splat(builder, e_lo, VF64), e),
                          builder.fcmp_ordered("<=", e, splat(builder, e_hi, VF64)))
    tie = builder.and_(builder.fcmp_ordered("==", e, d), builder.icmp_signed("<", jv, o))
    take = builder.and_(mask, builder.and_(inside, builder.or_(builder.fcmp_ordered("<", e, d), tie)))
    _store_lanes(builder, builder.select(take, e, d), d, dptr, mask, masked)
    _store_lanes(builder, builder.select(take, jv, o), o, optr, mask, masked)


def _claim_intrinsic(masked):
    def lanes_claim(typingctx, dissim, owner, ki, dd, spatial, si, b, e_lo, e_hi, j, lanes):
        sig = types.void(dissim, owner, ki, dd, spatial, si, b, e_lo, e_hi, j, lanes)

        def codegen(context, builder, signature, args):
            dissim_, owner_, ki_, dd_, spatial_, si_, b_, elo_, ehi_, j_, lanes_ = args
            ddv = builder.load(vector_ptr(context, builder, signature.args[3], dd_, ir.Constant(I64, 0), F64),
                               align=8)
            _claim_codegen(context, builder, ddv, dissim_, owner_, ki_, spatial_, si_, b_, elo_, ehi_, j_,
                           valid(builder, lanes_), (signature.args[0], signature.args[1], signature.args[4]), masked)
            return context.get_dummy_value()

        return sig, codegen

    return lanes_claim


def _claim_rgb_intrinsic(masked):
    def lanes_claim_rgb(typingctx, planes, pi, stride, r0, r1, r2, dissim, owner, ki, spatial, si, b, e_lo, e_hi, j,
                        lanes):
        sig = types.void(planes, pi, stride, r0, r1, r2, dissim, owner, ki, spatial, si, b, e_lo, e_hi, j, lanes)

        def codegen(context, builder, signature, args):
            planes_, pi_, stride_, r0_, r1_, r2_, dissim_, owner_, ki_, spatial_, si_, b_, elo_, ehi_, j_, lanes_ = (
                args)
            mask = valid(builder, lanes_)
            dd = None
            for ch, ref in enumerate((r0_, r1_, r2_)):
                index = builder.add(pi_, builder.mul(stride_, ir.Constant(I64, ch)))
                ptr = vector_ptr(context, builder, signature.args[0], planes_, index, F32)
                t = builder.fsub(_load_lanes(builder, ptr, mask, VF32, masked), splat(builder, ref, VF32))
                sq = builder.fpext(builder.fmul(t, t), VF64)
                dd = sq if dd is None else builder.fadd(dd, sq)  # (0 + x0) + x1 + x2 as the channel loop adds them
            _claim_codegen(context, builder, dd, dissim_, owner_, ki_, spatial_, si_, b_, elo_, ehi_, j_, mask,
                           (signature.args[6], signature.args[7], signature.args[9]), masked)
            return context.get_dummy_value()

        return sig, codegen

    return lanes_claim_rgb


_COLOUR_DOC = """One channel's squared colour differences of the ownership (:func:`.guidance._claim`), ``LANES`` pixels.

    Lane ``i``: ``t = planes[pi + i] - ref`` (float32), ``dd[i] = t * t`` widened to float64, added to ``dd[i]``
    unless ``first`` (true for the first channel); ``dd`` holds ``LANES`` float64. {reads}
    """
_CLAIM_DOC = """Point ``j``'s claim of ``LANES`` pixels of one window row (:func:`.guidance._claim`).

    Lane ``i``: ``e = spatial[si + i] + dd[i] b``, ``spatial`` (float64) holding the spatial terms ``(dr^2 + dc^2) a``
    of the window row's column offsets ``dc`` to the point (:func:`.guidance.spatial_terms`); the pixel
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
