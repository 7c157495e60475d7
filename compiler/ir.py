"""The rdsl SSA IR: types, ops, values, instructions, blocks, functions and modules.

The IR is SSA with *structured* control flow, in the style of MLIR's ``scf`` dialect:

* ``if``   has one operand (the condition) and two regions (then, else).  Each region ends
  in ``yield``; the yielded values become the results of the ``if``.
* ``loop`` has the initial values of its loop-carried variables as operands and one region
  (the body) whose block arguments are the carried values.  The body ends in
  ``yield %continue, %v0, %v1, ...``.  Semantics are do-while: run the body; if ``%continue``
  is true run it again with the block arguments bound to ``%v...``; otherwise the loop's
  results are ``%v...``.
* A function body ends in ``return %v...`` (possibly no values).

A region may use any value defined earlier in an enclosing region (lexical dominance).
There are no branches, no phis and no unstructured exits: ``break``, ``continue`` and early
``return`` are turned into flag variables by the frontend's lowering.

Types carry a ``lanes`` count.  Before ``vectorize`` every value has ``lanes == 1``.  After
``vectorize(W)`` a *varying* scalar has ``lanes == W``; uniform values keep ``lanes == 1``.
Aggregates (vectors, structs, tuples, the abstract ``Spectrum``) exist until ``scalarize``,
which splits them into scalars; ``vectorize`` and the backends see scalars only.

Every instruction carries a :class:`Loc` so that a diagnostic raised in any pass points at
the user's ``.rdsl`` line.
"""

from __future__ import annotations

import enum
import itertools
import weakref
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

# --------------------------------------------------------------------------------------
# Source locations


@dataclass(frozen=True)
class Loc:
    """A position in a source file (1-based line and column)."""

    file: str
    line: int
    col: int

    def __str__(self) -> str:
        return f"{self.file}:{self.line}:{self.col}"


UNKNOWN_LOC = Loc("<unknown>", 0, 0)

# --------------------------------------------------------------------------------------
# Types

SCALAR_NAMES = ("f32", "i32", "u32", "u64", "bool")


@dataclass(frozen=True)
class Type:
    """Base class of IR types.  ``lanes`` is 1 for uniform values and W for varying ones."""

    lanes: int = field(default=1, kw_only=True)

    def with_lanes(self, lanes: int) -> Type:
        raise NotImplementedError

    @property
    def is_aggregate(self) -> bool:
        return False


@dataclass(frozen=True)
class ScalarType(Type):
    """``f32``, ``i32``, ``u32``, ``u64`` or ``bool``."""

    name: str

    def __post_init__(self) -> None:
        assert self.name in SCALAR_NAMES, self.name

    def with_lanes(self, lanes: int) -> ScalarType:
        return ScalarType(self.name, lanes=lanes)

    @property
    def is_float(self) -> bool:
        return self.name == "f32"

    @property
    def is_int(self) -> bool:
        return self.name in ("i32", "u32", "u64")

    @property
    def is_signed(self) -> bool:
        return self.name == "i32"

    @property
    def bits(self) -> int:
        return {"f32": 32, "i32": 32, "u32": 32, "u64": 64, "bool": 1}[self.name]

    def __str__(self) -> str:
        return self.name if self.lanes == 1 else f"{self.name}x{self.lanes}"


@dataclass(frozen=True)
class VecType(Type):
    """``vecN``: N components of ``elem`` (f32 for Vec2/3/4; also the lifted RGB spectrum)."""

    n: int
    elem: ScalarType = ScalarType("f32")

    def with_lanes(self, lanes: int) -> VecType:
        return VecType(self.n, self.elem, lanes=lanes)

    @property
    def is_aggregate(self) -> bool:
        return True

    def __str__(self) -> str:
        return f"vec{self.n}" if self.elem.name == "f32" else f"vec{self.n}<{self.elem}>"


@dataclass(frozen=True)
class MatType(Type):
    """``matN``: an N×N f32 matrix stored row-major (N*N components)."""

    n: int

    def with_lanes(self, lanes: int) -> MatType:
        return MatType(self.n, lanes=lanes)

    @property
    def is_aggregate(self) -> bool:
        return True

    def __str__(self) -> str:
        return f"mat{self.n}"


@dataclass(frozen=True)
class SpectrumType(Type):
    """The abstract ``Spectrum``.  ``lift`` replaces it with a concrete type."""

    def with_lanes(self, lanes: int) -> SpectrumType:
        return SpectrumType(lanes=lanes)

    @property
    def is_aggregate(self) -> bool:
        return True

    def __str__(self) -> str:
        return "spectrum"


@dataclass(frozen=True)
class UnpolarizedType(SpectrumType):
    """The abstract ``Unpolarized`` spectrum: what ``Spectrum`` is without polarization (one
    value per wavelength; Mitsuba's ``UnpolarizedSpectrum``).  In unpolarized variants it
    lifts to the same type as ``Spectrum``; in polarized ones to one entry of a Mueller
    matrix."""

    def with_lanes(self, lanes: int) -> UnpolarizedType:
        return UnpolarizedType(lanes=lanes)

    def __str__(self) -> str:
        return "unpolarized"


@dataclass(frozen=True)
class StructType(Type):
    """A named struct.  ``fields`` is a tuple of (name, type) pairs."""

    name: str
    fields: tuple[tuple[str, Type], ...] = ()

    def with_lanes(self, lanes: int) -> StructType:
        return StructType(self.name, self.fields, lanes=lanes)

    @property
    def is_aggregate(self) -> bool:
        return True

    def field_index(self, name: str) -> int:
        for i, (fname, _) in enumerate(self.fields):
            if fname == name:
                return i
        raise KeyError(name)

    def __str__(self) -> str:
        return f"%{self.name}"


@dataclass(frozen=True)
class TupleType(Type):
    """An anonymous tuple."""

    elems: tuple[Type, ...] = ()

    def with_lanes(self, lanes: int) -> TupleType:
        return TupleType(self.elems, lanes=lanes)

    @property
    def is_aggregate(self) -> bool:
        return True

    def __str__(self) -> str:
        return "tuple<" + ", ".join(str(e) for e in self.elems) + ">"


@dataclass(frozen=True)
class BufferType(Type):
    """A pointer to an array of ``elem`` scalars in memory (always uniform)."""

    elem: ScalarType = ScalarType("f32")

    def with_lanes(self, lanes: int) -> BufferType:
        return self

    def __str__(self) -> str:
        return f"buffer<{self.elem}>"


F32 = ScalarType("f32")
F32_OVERFLOW = 2.0**128 * (1.0 - 2.0**-25)  # FLT_MAX + half an ulp: rounds to infinity
I32 = ScalarType("i32")
U32 = ScalarType("u32")
U64 = ScalarType("u64")
BOOL = ScalarType("bool")
VEC2, VEC3, VEC4 = VecType(2), VecType(3), VecType(4)
SPECTRUM = SpectrumType()
UNPOLARIZED = UnpolarizedType()


def components(t: Type) -> list[Type]:
    """The component types of an aggregate, in storage order."""
    if isinstance(t, VecType):
        return [t.elem.with_lanes(t.lanes)] * t.n
    if isinstance(t, MatType):
        return [F32.with_lanes(t.lanes)] * (t.n * t.n)
    if isinstance(t, StructType):
        return [ft for _, ft in t.fields]
    if isinstance(t, TupleType):
        return list(t.elems)
    raise TypeError(f"{t} is not a concrete aggregate")


def element_type(t: Type) -> Type:
    """The scalar type of each component of a homogeneous aggregate (or t itself)."""
    if isinstance(t, VecType):
        return t.elem
    if isinstance(t, MatType):
        return F32
    return t


# --------------------------------------------------------------------------------------
# Ops


class Op(enum.Enum):
    """Every IR operation, grouped by category.  The value is the printed mnemonic."""

    # members are singletons: hash by identity (Enum's default hashes the name, and the
    # passes hash ops millions of times per scene)
    __hash__ = object.__hash__

    # constants and parameters
    CONST = "const"  # attrs: value (python int/float/bool)
    # arithmetic: elementwise on scalars and on homogeneous aggregates of the same type
    ADD = "add"
    SUB = "sub"
    MUL = "mul"  # on spectrum×spectrum this is the spectral product (Mueller product later)
    DIV = "div"  # integer division by 0 yields 0; INT_MIN / -1 wraps
    REM = "rem"  # integer: remainder by 0 yields 0; float: fmod semantics
    NEG = "neg"
    # bitwise / logical (ints and bools)
    AND = "and"
    OR = "or"
    XOR = "xor"
    NOT = "not"
    SHL = "shl"  # shift amount taken modulo the bit width
    SHR = "shr"  # arithmetic for i32, logical for unsigned
    # comparisons (scalars only) -> bool
    EQ = "eq"
    NE = "ne"
    LT = "lt"
    LE = "le"
    GT = "gt"
    GE = "ge"
    SELECT = "select"  # select %cond, %a, %b
    # math intrinsics (f32, exactly rounded): everything else is written in rdsl
    SQRT = "sqrt"
    FLOOR = "floor"
    CEIL = "ceil"
    ABS = "abs"  # float or int
    MIN = "min"  # select(a < b, a, b)
    MAX = "max"  # select(a > b, a, b)
    # conversions
    CAST = "cast"  # numeric conversion; f32 -> int saturates (NaN -> 0)
    BITCAST = "bitcast"  # same-width reinterpretation (f32 <-> i32/u32)
    # aggregates
    MAKE = "make"  # build a vec/mat/struct/tuple from its components
    EXTRACT = "extract"  # attrs: index
    INSERT = "insert"  # insert %agg, %value ; attrs: index
    BROADCAST = "broadcast"  # scalar f32 -> vec/spectrum (all components), or uniform -> varying
    # spectrum (abstract until lift)
    SPEC_AVG = "spec.avg"  # mean over the spectrum's components -> f32
    SPEC_MAX = "spec.max"  # max component -> f32
    SPEC_RGB = "spec.from_rgb"  # (r, g, b) f32 -> spectrum; attrs: illuminant, spectrum
    SPEC_TABLE = "spec.table"  # buffer<f32>, i32 offset -> spectrum: a tabulated spectrum
    # stored there (the generic build's PRM; spectral variants only, see passes/lift/spectral.py)
    SPEC_MAKE = "spec.make"  # one f32 per component (spectral: 4) -> spectrum
    SPEC_SET = "spec.set_wavelengths"  # spectrum: this sample's wavelengths (nm), no result
    SPEC_LAMBDA = "spec.wavelengths"  # -> spectrum: this sample's wavelengths (nm)
    SPEC_SRGB = "spec.to_srgb"  # spectrum -> vec3 linear sRGB
    # polarization (spectrum = a Mueller matrix in polarized variants; see passes/lift/mueller.py)
    SPEC_UNPOL = "spec.unpolarized"  # spectrum -> unpolarized: entry [0][0]
    SPEC_FROM = "spec.from_unpolarized"  # unpolarized u -> spectrum u * identity
    SPEC_DEPOL = "spec.depolarizer"  # unpolarized u -> spectrum with only [0][0] = u
    SPEC_MUELLER = "spec.mueller"  # 16 unpolarized entries (row-major) -> spectrum
    SPEC_ENTRY = "spec.entry"  # spectrum -> unpolarized entry; attrs: row, col
    # constant data
    TABLE = "table"  # attrs: values (floats) -> buffer<f32> (read-only)
    # memory
    LOAD = "load"  # load %buf, %index
    STORE = "store"  # store %buf, %index, %value
    GATHER = "gather"  # gather %buf, %index, %mask   (after vectorize)
    SCATTER = "scatter"  # scatter %buf, %index, %value, %mask   (after vectorize)
    # calls (removed by inline)
    CALL = "call"  # attrs: callee
    # automatic differentiation (removed by ad_forward)
    DERIV = "ad.derivative"  # %x -> the derivative of x along the build's tangent (0 without)
    DETACH = "ad.detach"  # %x -> x, whose derivative is 0
    AD_RULE = "ad.rule"  # %x1..%xn, %y, %p1..%pn -> y = f(x..), partials p_k = df/dx_k
    # vector
    ANY = "any"  # varying bool -> uniform bool
    LANE = "lane"  # the lane index within the vector (varying i32)
    # ray tracing intrinsics (renderer)
    INTERSECT = "intersect"
    OCCLUDED = "occluded"
    # structured control flow
    IF = "if"
    LOOP = "loop"
    YIELD = "yield"
    RETURN = "return"


ARITH_OPS = {Op.ADD, Op.SUB, Op.MUL, Op.DIV, Op.REM, Op.NEG}
BIT_OPS = {Op.AND, Op.OR, Op.XOR, Op.NOT, Op.SHL, Op.SHR}
CMP_OPS = {Op.EQ, Op.NE, Op.LT, Op.LE, Op.GT, Op.GE}
MATH_OPS = {Op.SQRT, Op.FLOOR, Op.CEIL, Op.ABS, Op.MIN, Op.MAX}
ELEMENTWISE_OPS = ARITH_OPS | BIT_OPS | MATH_OPS
TERMINATORS = {Op.YIELD, Op.RETURN}
SIDE_EFFECT_OPS = {Op.STORE, Op.SCATTER, Op.CALL, Op.YIELD, Op.RETURN}
PURE_OPS = set(Op) - SIDE_EFFECT_OPS - {Op.IF, Op.LOOP, Op.LOAD, Op.GATHER, Op.INTERSECT,
                                        Op.OCCLUDED, Op.SPEC_SET}

# --------------------------------------------------------------------------------------
# Values, instructions, blocks

_ids = itertools.count(1)


def _nobody() -> None:  # the owner of a value that has none
    return None


class Value:
    """An SSA value.  ``name`` is a hint for printing (and the ABI name of a kernel param).
    ``owner`` (its instruction, or the block whose argument it is) is a weak reference: with
    no cycles in the IR a compile's ~800k objects are freed as it goes, not by the cycle
    collector (18% of a compile)."""

    __slots__ = ("_owner", "id", "name", "type")

    def __init__(self, type: Type, name: str | None = None) -> None:
        self.id = next(_ids)
        self.type = type
        self.name = name
        self._owner: Callable[[], Instr | Block | None] = _nobody

    @property
    def owner(self) -> Instr | Block | None:
        return self._owner()

    @owner.setter
    def owner(self, owner: Instr | Block | None) -> None:
        self._owner = _nobody if owner is None else weakref.ref(owner)

    def __getstate__(self) -> tuple[Any, ...]:  # copy/pickle hold the owner strongly
        return self.id, self.name, self.type, self.owner

    def __setstate__(self, state: tuple[Any, ...]) -> None:
        self.id, self.name, self.type, owner = state
        self.owner = owner

    def __repr__(self) -> str:
        return f"<%{self.name or self.id}: {self.type}>"


class Instr:
    """One instruction: op, operands, results, attributes, nested regions and a location."""

    __slots__ = ("__weakref__", "attrs", "loc", "op", "operands", "regions", "results")

    def __init__(
        self,
        op: Op,
        operands: list[Value],
        result_types: list[Type],
        attrs: dict[str, Any] | None = None,
        regions: list[Block] | None = None,
        loc: Loc = UNKNOWN_LOC,
    ) -> None:
        self.op = op
        self.operands = list(operands)
        self.results = [Value(t) for t in result_types]
        ref = weakref.ref(self)  # one reference, shared by the results (what `owner=` makes)
        for r in self.results:
            r._owner = ref
        self.attrs = dict(attrs or {})
        self.regions = list(regions or [])
        self.loc = loc

    @property
    def result(self) -> Value:
        assert len(self.results) == 1, f"{self.op} has {len(self.results)} results"
        return self.results[0]

    @property
    def type(self) -> Type:
        return self.result.type

    def __repr__(self) -> str:
        return f"<Instr {self.op.value} {self.operands} -> {self.results}>"


class Block:
    """A region's single block: arguments, then instructions ending in a terminator."""

    __slots__ = ("__weakref__", "args", "instrs")

    def __init__(self, args: list[Value] | None = None) -> None:
        self.args = list(args or [])
        for a in self.args:
            a.owner = self
        self.instrs: list[Instr] = []

    @property
    def terminator(self) -> Instr | None:
        if self.instrs and self.instrs[-1].op in TERMINATORS:
            return self.instrs[-1]
        return None

    def walk(self) -> Iterator[Instr]:
        """Every instruction in this block and nested regions, in program order."""
        stack = [iter(self.instrs)]  # not nested generators: they cost a step per level
        while stack:
            for ins in stack[-1]:
                yield ins
                if ins.regions:  # its regions' instructions, then the rest of this block
                    stack.append(itertools.chain.from_iterable(r.instrs for r in ins.regions))
                    break
            else:
                stack.pop()


@dataclass
class Param:
    """A function parameter.  ``uniform`` params are the same for every lane (plugin params,
    buffers); the rest are mapped over arrays when the function becomes a kernel."""

    value: Value
    uniform: bool = False
    default: Any = None


@dataclass
class Function:
    """A function: parameters, result types and a body ending in ``return``."""

    name: str
    params: list[Param]
    ret_types: list[Type]
    body: Block
    loc: Loc = UNKNOWN_LOC
    attrs: dict[str, Any] = field(default_factory=dict)
    # ABI names of the flattened results (set by scalarize), e.g. ["ret.x", "ret.y"]
    ret_names: list[str] | None = None

    def walk(self) -> Iterator[Instr]:
        return self.body.walk()


@dataclass
class Module:
    """A compilation unit: functions, struct definitions and compile options."""

    functions: dict[str, Function] = field(default_factory=dict)
    structs: dict[str, StructType] = field(default_factory=dict)
    attrs: dict[str, Any] = field(default_factory=dict)  # variant, width, target, ...

    def add(self, fn: Function) -> Function:
        self.functions[fn.name] = fn
        return fn


# --------------------------------------------------------------------------------------
# Builder


class Builder:
    """Appends instructions to a block.  ``loc`` is stamped on every new instruction."""

    def __init__(self, block: Block, loc: Loc = UNKNOWN_LOC) -> None:
        self.block = block
        self.loc = loc

    def emit(
        self,
        op: Op,
        operands: list[Value],
        result_types: list[Type],
        attrs: dict[str, Any] | None = None,
        regions: list[Block] | None = None,
        loc: Loc | None = None,
    ) -> Instr:
        ins = Instr(op, operands, result_types, attrs, regions, loc or self.loc)
        self.block.instrs.append(ins)
        return ins

    def op(self, op: Op, type: Type, *operands: Value, **attrs: Any) -> Value:
        """Emit a single-result instruction and return its result."""
        return self.emit(op, list(operands), [type], attrs).result

    def const(self, value: Any, type: Type) -> Value:
        return self.emit(Op.CONST, [], [type], {"value": value}).result

    def yield_(self, *values: Value) -> Instr:
        return self.emit(Op.YIELD, list(values), [])

    def return_(self, *values: Value) -> Instr:
        return self.emit(Op.RETURN, list(values), [])


def replace_uses(block: Block, mapping: dict[Value, Value]) -> None:
    """Rewrite operands in ``block`` (recursively) through ``mapping``."""
    if not mapping:
        return
    for ins in block.walk():
        ins.operands = [mapping.get(v, v) for v in ins.operands]


def clone_block(block: Block, mapping: dict[Value, Value]) -> Block:
    """Deep-copy a block.  ``mapping`` maps outer values (and block args) to replacements and
    is extended with the new results."""
    new = Block([Value(a.type, a.name) for a in block.args])
    for old_arg, new_arg in zip(block.args, new.args):
        mapping.setdefault(old_arg, new_arg)
    get, out = mapping.get, new.instrs
    for ins in block.instrs:
        regions = [clone_block(r, mapping) for r in ins.regions] if ins.regions else []
        out.append(clone_instr(ins, [get(v, v) for v in ins.operands], regions, mapping))
    return new


def clone_function(fn: Function) -> Function:
    """A copy of ``fn`` that shares no value, instruction or block with it (its attributes
    copied one level deep), for a pass to rewrite while ``fn`` stays as it was."""
    mapping: dict[Value, Value] = {}
    params = [Param(Value(p.value.type, p.value.name), p.uniform, p.default) for p in fn.params]
    for old, new in zip(fn.params, params):
        mapping[old.value] = new.value
    return Function(fn.name, params, list(fn.ret_types), clone_block(fn.body, mapping), fn.loc,
                    dict(fn.attrs), list(fn.ret_names) if fn.ret_names is not None else None)


def clone_instr(ins: Instr, operands: list[Value], regions: list[Block],
                mapping: dict[Value, Value]) -> Instr:
    """A copy of ``ins`` with these operands and regions and new results, which ``mapping``
    records.  What ``Instr(...)`` does, without its copies (inlining's hot loop)."""
    c = Instr.__new__(Instr)
    c.op, c.attrs, c.loc = ins.op, dict(ins.attrs), ins.loc
    c.operands, c.regions = operands, regions
    ref, c.results = weakref.ref(c), []
    for o in ins.results:
        n = Value(o.type, o.name)
        n._owner = ref
        c.results.append(n)
        mapping[o] = n
    return c


def __getattr__(name: str) -> Any:  # what moved to ir_abi.py, still importable from here
    if name in ("leaf_types", "type_to_json"):
        from . import ir_abi

        return getattr(ir_abi, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
