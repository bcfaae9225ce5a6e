"""LLVM IR helpers for the vector steps of :mod:`.lanes` and :mod:`.lanes_guidance`: the vector types of ``LANES``
lanes and the loads, stores, splats, masks and reductions they are written with (llvmlite)."""

from llvmlite import ir

LANES = 16  # 256 bits of int16: on the dev machine 16 lanes beat 32 (most tubes are under 16 wide)

I16 = ir.IntType(16)
I32 = ir.IntType(32)
I64 = ir.IntType(64)
F32 = ir.FloatType()
F64 = ir.DoubleType()
V16 = ir.VectorType(I16, LANES)
VI64 = ir.VectorType(I64, LANES)
VI32 = ir.VectorType(I32, LANES)
VF32 = ir.VectorType(F32, LANES)
VF64 = ir.VectorType(F64, LANES)
LANE_INDEX = ir.Constant(VI64, list(range(LANES)))


def element_ptr(context, builder, arrty, arr, index):
    """A pointer to ``arr[index]`` of a 1-D array (or of a C-contiguous array's flat data)."""
    return builder.gep(context.make_array(arrty)(context, builder, arr).data, [index])


def vector_ptr(context, builder, arrty, arr, index, elem=None):
    vty = ir.VectorType(elem or I16, LANES)
    return builder.bitcast(element_ptr(context, builder, arrty, arr, index), vty.as_pointer())


def load_i16(context, builder, arrty, arr, index):
    """``LANES`` elements from ``arr[index]`` as int16 lanes (uint8 widened with zeros)."""
    elem = context.get_value_type(arrty.dtype)
    v = builder.load(vector_ptr(context, builder, arrty, arr, index, elem), align=elem.width // 8)
    return builder.zext(v, V16) if elem.width < 16 else v


def store_vector(context, builder, arrty, arr, index, value):
    builder.store(value, vector_ptr(context, builder, arrty, arr, index), align=2)


def elem_name(vty):
    """The element type of a vector type as LLVM's intrinsic names spell it (``i16``, ``f32``, ``f64``)."""
    e = vty.element
    return f"i{e.width}" if isinstance(e, ir.IntType) else ("f64" if isinstance(e, ir.DoubleType) else "f32")


def elem_bytes(vty):
    """The size in bytes of a vector type's element (its natural alignment)."""
    e = vty.element
    return e.width // 8 if isinstance(e, ir.IntType) else (8 if isinstance(e, ir.DoubleType) else 4)


def masked_load(builder, ptr, mask, vty):
    """Load a ``vty`` vector where ``mask`` holds (``llvm.masked.load``); the other lanes are not read (no fault past
    an array's end) and load as 0."""
    maskty = ir.VectorType(ir.IntType(1), vty.count)
    fn = declared(builder, f"llvm.masked.load.v{vty.count}{elem_name(vty)}.p0", vty,
                  [ptr.type, ir.IntType(32), maskty, vty])
    return builder.call(fn, [ptr, ir.Constant(ir.IntType(32), elem_bytes(vty)), mask,
                             ir.Constant(vty, [0] * vty.count)])


def masked_store(builder, value, ptr, mask):
    """Store the lanes of ``value`` where ``mask`` holds (``llvm.masked.store``); the others are not written."""
    vty = value.type
    fn = declared(builder, f"llvm.masked.store.v{vty.count}{elem_name(vty)}.p0", ir.VoidType(),
                  [vty, ptr.type, ir.IntType(32), ir.VectorType(ir.IntType(1), vty.count)])
    builder.call(fn, [value, ptr, ir.Constant(ir.IntType(32), elem_bytes(vty)), mask])


def splat(builder, value, vty=V16):
    if value.type != vty.element and isinstance(value.type, ir.IntType):
        value = builder.trunc(value, vty.element) if value.type.width > vty.element.width else \
            builder.sext(value, vty.element)
    undef = ir.Constant(vty, ir.Undefined)
    one = builder.insert_element(undef, value, ir.Constant(ir.IntType(32), 0))
    return builder.shuffle_vector(one, undef, ir.Constant(ir.VectorType(ir.IntType(32), vty.count), [0] * vty.count))


def smin(builder, a, b):
    return builder.select(builder.icmp_signed("<", a, b), a, b)


def valid(builder, lanes):
    return builder.icmp_signed("<", LANE_INDEX, splat(builder, lanes, ir.VectorType(I64, LANES)))


def reduce_min(builder, v, signed=True):
    # a tree of halving shuffles: portable across LLVM versions (no reduction intrinsic needed)
    n = LANES
    while n > 1:
        n //= 2
        undef = ir.Constant(v.type, ir.Undefined)
        hi = builder.shuffle_vector(v, undef, ir.Constant(ir.VectorType(ir.IntType(32), LANES),
                                                           [i + n if i < n else i for i in range(LANES)]))
        v = builder.select(builder.icmp_signed("<", v, hi) if signed else builder.icmp_unsigned("<", v, hi), v, hi)
    return builder.extract_element(v, ir.Constant(ir.IntType(32), 0))


def declared(builder, name, ret, argtys):
    fn = builder.module.globals.get(name)
    return fn if fn is not None else ir.Function(builder.module, ir.FunctionType(ret, argtys), name=name)


def fma(builder, a, b, c):
    """``a * b + c`` lane by lane, rounded once (``llvm.fma``; one instruction where the CPU has FMA)."""
    vty = a.type
    fn = declared(builder, f"llvm.fma.v{vty.count}{elem_name(vty)}", vty, [vty, vty, vty])
    return builder.call(fn, [a, b, c])


def typed(params, restype):
    """An intrinsic's argument names and signature from its typing function's ``locals()`` (called first thing, so
    they hold just the parameters, in order): ``names, sig = typed(locals(), types.int16)``. The names are the
    parameters', so :class:`Args` reads each argument by the name the typing function gives it."""
    names = tuple(k for k in params if k != "typingctx")
    return names, restype(*(params[k] for k in names))


class Args:
    """An intrinsic's arguments by name (``names`` from :func:`typed`), so a code generator reads none by its
    position: ``a.rws`` is the LLVM value, ``a.type("rws")`` its Numba type, ``a.at("rws", i)`` the element
    ``rws[i]`` of a 1-D array (``a.element("rws", i)`` a pointer to it), ``a.load("cost", i)`` and
    ``a.store("L", i, v)`` ``LANES`` lanes from and to ``[i]`` (:func:`load_i16`, :func:`store_vector`),
    ``a.ptr("out", i)`` a vector pointer to ``out[i]``."""

    def __init__(self, names, context, builder, signature, args):
        self.context, self.builder = context, builder
        self._values = dict(zip(names, args))
        self._types = dict(zip(names, signature.args))

    def __getattr__(self, name):
        try:
            return self.__dict__["_values"][name]
        except KeyError:
            raise AttributeError(name) from None

    def type(self, name):
        return self._types[name]

    def element(self, name, index):
        return element_ptr(self.context, self.builder, self._types[name], self._values[name], index)

    def at(self, name, index):
        return self.builder.load(self.element(name, index))

    def load(self, name, index):
        return load_i16(self.context, self.builder, self._types[name], self._values[name], index)

    def store(self, name, index, value):
        store_vector(self.context, self.builder, self._types[name], self._values[name], index, value)

    def ptr(self, name, index, elem=None):
        return vector_ptr(self.context, self.builder, self._types[name], self._values[name], index, elem)
