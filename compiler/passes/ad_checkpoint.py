"""The per-lane checkpoint tape of ``ad_reverse``: a loop's carried state, stored by the
primal loop and loaded by the adjoint loop (docs/ad.md, "Reverse mode").

Not a pass: ``ad_reverse`` calls it in a build with ``tape`` = C > 0.  Each counted loop
(a loop with an active carried value) that no other loop encloses stores, at the start of
iteration n, its carried state (u64 as two Floats, Bools as 0 or 1, the rest bit for bit)
in slot min(n, C) of its part of the lane's row of ``ad_tape`` (slot C takes the
iterations beyond and is never read).  The row starts at ``ad_row_tape``; the kernel gets
the two as arguments after the others (a uniform Float buffer, a varying Int) and the
manifest's ``tape_floats`` is the row's length.  A row is interleaved with those of the
other lanes of its packet: its value j is at ``ad_row_tape + j * TAPE_LANES``, so that a
caller that gives the lanes of a packet consecutive rows (lane k of a block of
``TAPE_LANES`` samples: ``block * TAPE_LANES * tape_floats + k``, as
runtime/render/backward.py does) has each value of a packet stored and loaded as one
vector, not scattered and gathered (the LLVM backend checks that the indices are
consecutive at run time).  A loop inside another loop is not taped
(each outer iteration would overwrite its slots): its adjoint recomputes from the start.

The values the adjoint's sweep of an iteration reads from its run of the body forward (its
intermediate values: partial derivatives, branch conditions, scatter indices) are stored
the same way, after the carried state, so that the adjoint's iteration k < C loads them
instead of running the body forward again (:meth:`Checkpoints.keep`); beyond C it runs it.

With ``covers`` (``Build.tape_covers``: the caller expects no loop to run more than C
iterations, as a path tracer's bounce loop with ``max_depth`` < C), the adjoint has no code
for the iterations beyond C: no replay from the last checkpoint, no run of the body
forward; every iteration's state and forward values are loaded.  Element 0 of each row
is then an overflow word: a lane whose taped loop ran more than C iterations stores its
count there (as a Float's bits) and skips that loop's adjoint, so that the caller, which
set the word to -1 (all bits) before the pass, sees the overflow and runs the pass again
with a kernel built without ``covers`` (runtime/render/backward.py).
"""

from __future__ import annotations

from collections.abc import Iterator

from ..ir import BOOL, F32, I32, U32, U64, Block, BufferType, Builder, Function, Instr, Op, \
    Param, Value, type_to_json

TAPE, TAPE_ROW = "ad_tape", "ad_row_tape"
TAPE_LANES = 16  # rows interleaved per block of this many lanes (the widest SIMD packet)
OVERFLOW = 0  # with ``covers``: the element of a row that flags more iterations than C
TAPE_VALUE = "ad.tape"  # the attribute of a tape store or load: which value of a slot
# (its position in the row's part of slot 0), for passes/tape_stores.py
_TYPES = (F32, I32, U32, BOOL, U64)



class Checkpoints:
    """The tape of one function: ``cap`` (C) checkpoints per taped loop."""

    def __init__(self, cap: int, covers: bool = False) -> None:
        self.cap, self.covers = cap, covers and cap > 0
        self.buf, self.row = Value(BufferType(F32), TAPE), Value(I32, TAPE_ROW)
        self.size = 1 if self.covers else 0  # floats per lane (the overflow word first)
        self.stores: set[int] = set()  # the instructions the primal loops got (their ids)
        self.loops: dict[int, tuple[int, int]] = {}  # a taped loop -> (offset, floats)
        self.slots: dict[int, Value] = {}  # a taped loop -> its slot, in its body

    def store(self, block: Block) -> None:
        """Make each counted loop of ``block`` that no loop encloses store its state."""
        for ins in block.instrs:
            if ins.op is not Op.LOOP:
                for r in ins.regions:
                    self.store(r)
                continue
            body = ins.regions[0]
            state, n = body.args[:-1], body.args[-1]  # n: ad_reverse's trip counter
            if not ins.attrs.get("ad.counted") or any(a.type not in _TYPES for a in state):
                continue
            tb = Builder(Block(), ins.loc)
            cap = tb.const(self.cap, I32)
            slot = tb.op(Op.SELECT, I32, tb.op(Op.LT, BOOL, n, cap), n, cap)
            floats = [x for a in state for x in _pack(a, tb)]
            for j, (x, idx) in enumerate(zip(floats, self._slot(slot, len(floats), self.size,
                                                                 tb))):
                tb.emit(Op.STORE, [self.buf, idx, x], [], {TAPE_VALUE: self.size + j})
            self.stores.update(id(i) for i in tb.block.instrs)
            body.instrs[:0] = tb.block.instrs
            self.loops[id(ins)] = (self.size, len(floats))
            self.size += (self.cap + 1) * len(floats)
            self.slots[id(ins)] = slot

    def taped(self, loop: Instr) -> bool:
        """Whether ``loop``'s carried state is on the tape."""
        return id(loop) in self.loops

    def load(self, ins: Instr, k: Value, b: Builder) -> tuple[list[Value], Value] | None:
        """For taped loop ``ins``: its carried values at checkpoint c = min(k, C - 1) and
        k - c, the iterations left to run from there to reach iteration k (else None).
        With ``covers``: c = k, and k - c is None (no iterations to run)."""
        if id(ins) not in self.loops:
            return None
        offset, size = self.loops[id(ins)]
        if self.covers:
            xs = self._loads(k, size, offset, b)
            return [*[_unpack(xs, a.type, b) for a in ins.regions[0].args[:-1]], k], None
        last = b.const(self.cap - 1, I32)
        c = b.op(Op.SELECT, I32, b.op(Op.LT, BOOL, k, last), k, last)
        xs = self._loads(c, size, offset, b)
        state = [_unpack(xs, a.type, b) for a in ins.regions[0].args[:-1]]
        return [*state, c], b.op(Op.SUB, I32, k, c)

    def keep(self, loop: Instr, block: Block, new: list[Instr], k: Value,
             origin: dict[Value, Value]) -> None:
        """Tape the values the sweep of ``loop``'s adjoint reads from its copy of the body:
        the primal body stores them (slot min(n, C)), and the adjoint's iteration k < C
        loads them instead of running the body forward again (``new``: the copy's
        instructions in ``block``, the rest of ``block`` its sweep; ``origin``: a copied
        value -> the primal's)."""
        if id(loop) not in self.slots or not new:
            return
        start = next(i for i, x in enumerate(block.instrs) if x is new[0])
        sweep = block.instrs[start + len(new):]
        made = {r for i in new for r in i.results}
        used = list(dict.fromkeys(v for i in sweep for v in _operands(i) if v in made))
        if not used or any(v.type not in _TYPES or v not in origin for v in used):
            return
        body = loop.regions[0]
        end = body.instrs.pop()
        pb = Builder(body, end.loc)
        floats = [x for v in used for x in _pack(origin[v], pb)]
        offset, size = self.size, len(floats)
        for j, (x, idx) in enumerate(zip(floats, self._slot(self.slots[id(loop)], size,
                                                            offset, pb))):
            pb.emit(Op.STORE, [self.buf, idx, x], [], {TAPE_VALUE: offset + j})
        body.instrs.append(end)
        self.size += (self.cap + 1) * size
        b = Builder(Block(), loop.loc)
        if self.covers:  # every iteration's values are on the tape
            xs = self._loads(k, size, offset, b)
            loaded = [_unpack(xs, v.type, b) for v in used]
            _replace(sweep, dict(zip(used, loaded)))
            block.instrs = [*block.instrs[:start], *b.block.instrs, *sweep]
            return
        cond = b.op(Op.LT, BOOL, k, b.const(self.cap, I32))
        then, other = Block(), Block()
        tb = Builder(then, loop.loc)
        xs = self._loads(k, size, offset, tb)
        tb.yield_(*[_unpack(xs, v.type, tb) for v in used])
        other.instrs = list(new)
        Builder(other, loop.loc).yield_(*used)
        choice = b.emit(Op.IF, [cond], [v.type for v in used], regions=[then, other])
        _replace(sweep, dict(zip(used, choice.results)))
        block.instrs = [*block.instrs[:start], *b.block.instrs, *sweep]

    def guard(self, loop: Instr, trips: Value, b: Builder) -> Value | None:
        """With ``covers``, for taped loop ``loop`` that ran ``trips`` iterations: store an
        overflow (more than C) in the row's overflow word; return the condition under which
        its adjoint may run (at most C iterations).  None: no guard needed."""
        if not self.covers or id(loop) not in self.loops:
            return None
        over = b.op(Op.GT, BOOL, trips, b.const(self.cap, I32))
        then, other = Block(), Block()
        tb = Builder(then, loop.loc)
        word = tb.op(Op.ADD, I32, self.row, tb.const(OVERFLOW * TAPE_LANES, I32))
        tb.emit(Op.STORE, [self.buf, word, tb.op(Op.BITCAST, F32, trips)], [])
        tb.yield_()
        Builder(other, loop.loc).yield_()
        b.emit(Op.IF, [over], [], regions=[then, other])
        return b.op(Op.NOT, BOOL, over)

    def add_params(self, fn: Function) -> list[dict]:
        """Give ``fn`` the tape's arguments, if it has a tape; their ABI entries."""
        if not self.loops:  # no loop taped (a covering tape's overflow word alone is none)
            return []
        fn.params += [Param(self.buf, uniform=True), Param(self.row)]
        return [{"name": TAPE, "type": type_to_json(self.buf.type), "uniform": True,
                 "default": None, "leaves": [TAPE], "tape_floats": self.size,
                 "tape_covers": self.covers},
                {"name": TAPE_ROW, "type": {"kind": "scalar", "dtype": "i32"},
                 "uniform": False, "default": None, "leaves": [TAPE_ROW]}]

    def _loads(self, slot: Value, size: int, offset: int, b: Builder) -> Iterator[Value]:
        """The ``size`` floats of slot ``slot`` of a loop's part, loaded from the tape."""
        return iter([b.op(Op.LOAD, F32, self.buf, i, **{TAPE_VALUE: offset + j})
                     for j, i in enumerate(self._slot(slot, size, offset, b))])

    def _slot(self, slot: Value, size: int, offset: int, b: Builder,
              count: int | None = None) -> list[Value]:
        """The tape indices of the first ``count`` (all ``size``) values of slot ``slot``
        of a loop's part (value j of the lane's row at ``row + j * TAPE_LANES``)."""
        lanes = b.const(TAPE_LANES, I32)
        first = b.op(Op.ADD, I32, b.op(Op.MUL, I32, slot, b.const(size, I32)),
                     b.const(offset, I32))
        base = b.op(Op.ADD, I32, self.row, b.op(Op.MUL, I32, first, lanes))
        return [base, *[b.op(Op.ADD, I32, base, b.const(j * TAPE_LANES, I32))
                        for j in range(1, size if count is None else count)]]


def _operands(ins: Instr) -> Iterator[Value]:
    """The values ``ins`` reads, in its regions too."""
    yield from ins.operands
    for r in ins.regions:
        for i in r.instrs:
            yield from _operands(i)


def _replace(instrs: list[Instr], new: dict[Value, Value]) -> None:
    """Read ``new[v]`` for each ``v`` in ``instrs`` and their regions."""
    for ins in instrs:
        ins.operands = [new.get(v, v) for v in ins.operands]
        for r in ins.regions:
            _replace(r.instrs, new)


def _pack(v: Value, b: Builder) -> list[Value]:
    """A carried value as the Floats the tape stores, bit for bit (a u64: two)."""
    if v.type == F32:
        return [v]
    if v.type == BOOL:
        return [b.op(Op.SELECT, F32, v, b.const(1.0, F32), b.const(0.0, F32))]
    if v.type == U64:
        hi = b.op(Op.SHR, U64, v, b.const(32, U64))
        return [b.op(Op.BITCAST, F32, b.op(Op.CAST, U32, w)) for w in (v, hi)]
    return [b.op(Op.BITCAST, F32, v)]


def _unpack(xs, t, b: Builder) -> Value:
    """The inverse of :func:`_pack`: a value of type ``t`` from the Floats ``xs``."""
    if t == F32:
        return next(xs)
    if t == BOOL:
        return b.op(Op.NE, BOOL, next(xs), b.const(0.0, F32))
    if t == U64:
        lo, hi = (b.op(Op.CAST, U64, b.op(Op.BITCAST, U32, next(xs))) for _ in range(2))
        return b.op(Op.OR, U64, lo, b.op(Op.SHL, U64, hi, b.const(32, U64)))
    return b.op(Op.BITCAST, t, next(xs))
