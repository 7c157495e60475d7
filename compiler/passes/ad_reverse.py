"""``ad_reverse``: reverse-mode automatic differentiation (the adjoint) of scalarized kernels.

Expects: a scalarized module (every value a scalar or a buffer, no calls); with
``Inline(mark_partials=True)``, an ``ad.rule`` for each call of a math function of
``ad_forward.PARTIALS``.  Runs in place of ``ad_forward`` in a ``reverse`` build.

Guarantees: no ``ad.*`` op is left; ``derivative(x)`` is 0.  Each kernel keeps its own
parameters and results, computed as before, and gets after its own parameters:

* ``a.NAME`` (varying Float), one per ``Float`` result leaf: the adjoint of that result
  (d loss / d result), the seed of the reverse sweep;
* with a parameter buffer ``PRM``: a gradient buffer ``gPRM`` and ``ad_row`` (varying Int):
  d loss / d ``PRM[i]`` is *added* to ``gPRM[ad_row + i]``, so each lane (each sample) adds
  into a row of its own (no two lanes write one element: no atomics); the caller sums the
  rows;
* likewise with the scene's texel buffer ``T`` (bitmap textures): ``gT`` and ``ad_row_T``
  (the caller chooses rows so that no two lanes running at once share one: a texel is
  read by many samples);
* a ``Float`` argument ``x`` gets a result ``g.x`` after the kernel's own (a vector-Jacobian
  product), recorded in ``abi_params``/``abi_result`` as ``ad_forward`` records tangents.

The adjoint is the primal function followed by the reverse sweep of its body.  Only *active*
values (Floats that depend on a seed, not through ``detach``) get adjoints.  An ``if`` with
an active result also yields every value its branches compute (DCE later drops those the
adjoint does not read); its adjoint is an ``if`` on the same condition whose branches sweep
the branch backwards, reading those values.  A ``loop``: the primal loop counts its
iterations N, and the adjoint loop runs k = N-1 .. 0, each time getting the carried state
before iteration k, then running the body once more forward and its sweep (with a
covering tape, k = C-1 .. 0 in every lane, the iterations k >= N idle: the lanes of a
packet then read the same tape slot together, as vectors).  In a build
with ``tape`` = C > 0 the primal loop checkpoints its carried state before iterations
0 .. C-1 per lane (in ``ad_tape`` at row ``ad_row_tape``, two more kernel arguments:
passes/ad_checkpoint.py) and the adjoint loads it for k < C, beyond recomputing the body
k - C + 1 times from the last checkpoint (linear in N up to C).  Loops inside other loops,
and all with ``tape`` 0, recompute from the initial values (k bodies: quadratic in N;
docs/ad.md).  The adjoints of the outer values a loop body reads are carried by the
adjoint loop and added after it.
Integers, comparisons, ``floor``/``ceil``, loads from other buffers and ray hits have no
derivative (as in ``ad_forward``).  A build with ``seeds`` (``Build.seeds``: the scene
parameters ``backward`` asks for) differentiates only the loads of those parameters
(``_Reverse``): the others are constants to the sweep, which gets shorter, and so does the
tape.
"""

from __future__ import annotations

from ..ir import (
    BOOL,
    F32,
    I32,
    Block,
    BufferType,
    Builder,
    Function,
    Instr,
    Module,
    Op,
    Param,
    Value,
    clone_block,
    replace_uses,
)
from . import Pass, register
from .ad_checkpoint import Checkpoints
from .ad_forward import PARAM_BUFFER

GRAD_BUFFER, ROW = "gPRM", "ad_row"
# the scene's texel buffer (runtime/render/textures.py): its loads are differentiated too,
# into gT at row ad_row_T (d loss / d texel, for bitmap textures' ``<id>.data``)
TEXEL_BUFFER = "T"
DIFFERENTIATED = {PARAM_BUFFER: (GRAD_BUFFER, ROW), TEXEL_BUFFER: ("gT", "ad_row_T")}
SWEEP = "ad.sweep"  # on the first instruction of a sweep that follows its forward part
GUARD = "ad.guard"  # on the select of a zero-adjoint guard (zero_guard), for ``eliminate``
_NO_DERIVATIVE = {Op.FLOOR, Op.CEIL, Op.CAST, Op.BITCAST, Op.CONST, Op.LOAD, Op.REM}


@register
class AdReverse(Pass):
    name = "ad_reverse"

    def __init__(self, tape: int = 0, seeds: tuple[int | str, ...] | None = None,
                 covers: bool = False) -> None:
        self.tape = tape  # iterations checkpointed per loop (0: recompute from the start)
        self.seeds = seeds  # the loads differentiated (None: every one; see _Reverse)
        self.covers = covers  # no code for iterations beyond the tape (ad_checkpoint.py)

    def run(self, module: Module) -> None:
        for fn in module.functions.values():
            _Reverse(fn, self.tape, self.seeds, self.covers).run()


class _Reverse:
    """The adjoint of one function.  ``seeds``: None differentiates every load from ``PRM``
    and ``T``; otherwise only the loads from ``PRM`` at a constant element it names and,
    if it holds ``"T"``, the loads from ``T`` (the scene parameters ``backward`` was asked
    for: no adjoint code for the others)."""

    def __init__(self, fn: Function, cap: int = 0,
                 seeds: tuple[int | str, ...] | None = None, covers: bool = False) -> None:
        self.fn = fn
        self.seeds = None if seeds is None else frozenset(seeds)
        self.tape = Checkpoints(cap, covers)  # the loops' carried state (cap 0: none)
        # a differentiated buffer (PRM, T) -> its gradient buffer and row
        self.bufs: dict[Value, tuple[Value, Value]] = {
            p.value: (Value(BufferType(F32), DIFFERENTIATED[p.value.name][0]),
                      Value(I32, DIFFERENTIATED[p.value.name][1]))
            for p in fn.params if p.value.name in DIFFERENTIATED
            and p.value.type == BufferType(F32)}
        self.varied: set[Value] = set()
        self.rules: dict[Value, tuple[list[Value], list[Value]]] = {}
        self.detached: set[Value] = set()  # the copies detach(x) made
        # a value of a branch -> the result of its `if` that exports it, where the sweep is
        self.sub: dict[Value, Value] = {}

    # -- setup ----------------------------------------------------------------------------
    def run(self) -> None:
        fn = self.fn
        self._lower_ad_ops(fn.body)
        seeds = [p for p in fn.params if p.value.type == F32]
        self.varied.update(p.value for p in seeds)
        self._activity()
        self._count_loops(fn.body)
        self._export(fn.body)
        if self.tape.cap > 0:
            self.tape.store(fn.body)
        ret = fn.body.instrs.pop()
        assert ret.op is Op.RETURN
        adj: dict[Value, Value] = {}
        b = Builder(fn.body, ret.loc)
        floats = [(n, v) for n, v in zip(fn.ret_names or [], ret.operands) if v.type == F32]
        seed_params = []
        for name, v in floats:
            a = Value(F32, f"a.{name}")
            seed_params.append(Param(a))
            self.acc(adj, v, a, b)
        mark = len(fn.body.instrs)
        self.sweep(fn.body.instrs[:], adj, b)
        _mark_sweep(fn.body, mark)
        grads = [adj.get(p.value) or b.const(0.0, F32) for p in seeds]
        ret.operands = [*ret.operands, *grads]
        fn.body.instrs.append(ret)
        fn.params += seed_params
        extra = [{"name": f"a_{n.replace('.', '_')}", "type": _F32_JSON, "uniform": False,
                  "default": None, "leaves": [p.value.name]} for (n, _), p in
                 zip(floats, seed_params)]
        for buf, (grad, row) in self.bufs.items():
            fn.params += [Param(grad, uniform=True), Param(row)]
            entry = next((e for e in fn.attrs.get("abi_params", [])
                          if e["name"] == buf.name), None)
            if entry is not None:
                extra += [dict(entry, name=grad.name, leaves=[grad.name]),
                          {"name": row.name, "type": {"kind": "scalar", "dtype": "i32"},
                           "uniform": False, "default": None, "leaves": [row.name]}]
        extra += self.tape.add_params(fn)
        fn.attrs["abi_params"] = [*fn.attrs.get("abi_params", []), *extra]
        if seeds:
            self._abi_results(seeds)
        for ins in fn.walk():
            ins.attrs.pop("ad.counted", None)
            ins.attrs.pop("ad.export", None)

    def _abi_results(self, seeds: list[Param]) -> None:
        fn = self.fn
        leaves = [f"g.{p.value.name}" for p in seeds]
        result = fn.attrs.get("abi_result", {})
        fn.ret_names = [*(fn.ret_names or []), *leaves]
        fn.ret_types = [*fn.ret_types, *[F32] * len(seeds)]
        fn.attrs["abi_result"] = {"type": {"kind": "tuple", "elems": [
            result.get("type"), *[_F32_JSON] * len(seeds)]},
            "leaves": [*result.get("leaves", []), *leaves], "vjp": True}

    def _lower_ad_ops(self, block: Block) -> None:
        """derivative(x) -> 0; detach(x) of a Float and a rule -> a copy (x - 0) that the
        sweep treats as a leaf (detach) or through the rule's partials; detach of any other
        type -> x (it has no adjoint anyway)."""
        out: list[Instr] = []
        renamed: dict[Value, Value] = {}
        for ins in block.instrs:
            for r in ins.regions:
                self._lower_ad_ops(r)
            if ins.op is Op.DERIV:
                ins.op, ins.operands, ins.attrs = Op.CONST, [], {"value": 0.0}
            elif ins.op is Op.DETACH and ins.operands[0].type != F32:
                renamed[ins.result] = ins.operands[0]
                continue
            elif ins.op in (Op.DETACH, Op.AD_RULE):
                n = (len(ins.operands) - 1) // 2
                if ins.op is Op.AD_RULE:
                    ops = ins.operands
                    self.rules[ins.result] = (ops[:n], ops[n + 1:])
                    x = ops[n]
                else:
                    x = ins.operands[0]
                    self.detached.add(ins.result)
                zero = Instr(Op.CONST, [], [F32], {"value": 0.0}, loc=ins.loc)
                ins.op, ins.operands, ins.attrs = Op.SUB, [x, zero.result], {}
                out.append(zero)
            out.append(ins)
        block.instrs = out
        replace_uses(block, renamed)

    def _activity(self) -> None:
        """The Float values that depend on a seed (PRM loads, Float arguments); a global
        fixpoint over loops and ifs."""
        changed = True
        while changed:
            changed = False
            for ins in self.fn.walk():
                for v in self._varied_results(ins):
                    if v not in self.varied:
                        self.varied.add(v)
                        changed = True

    def _varied_results(self, ins: Instr) -> list[Value]:
        op, V = ins.op, self.varied
        if op is Op.LOAD:
            return [ins.result] if self._seed_load(ins) else []
        if op is Op.IF:
            return [r for i, r in enumerate(ins.results) if r.type == F32 and any(
                reg.instrs[-1].operands[i] in V for reg in ins.regions)]
        if op is Op.LOOP:
            body = ins.regions[0]
            y = body.instrs[-1].operands[1:]
            hot = [i for i, a in enumerate(body.args) if a.type == F32 and (
                ins.operands[i] in V or y[i] in V)]
            return [body.args[i] for i in hot] + [ins.results[i] for i in hot]
        if len(ins.results) != 1 or ins.result.type != F32 or op in _NO_DERIVATIVE:
            return []
        if ins.result in self.rules:
            return [ins.result] if any(x in V for x in self.rules[ins.result][0]) else []
        if ins.result in self.detached:
            return []
        return [ins.result] if any(v in V for v in ins.operands) else []

    def _seed_load(self, ins: Instr) -> bool:
        """Whether load ``ins`` is differentiated (see ``seeds``)."""
        buf = ins.operands[0]
        if buf not in self.bufs:
            return False
        if self.seeds is None:
            return True
        if buf.name == TEXEL_BUFFER:
            return TEXEL_BUFFER in self.seeds
        index = ins.operands[1].owner
        return isinstance(index, Instr) and index.op is Op.CONST and \
            index.attrs["value"] in self.seeds

    def _count_loops(self, block: Block) -> None:
        """Give each loop that carries an active value a trip counter (its last carried
        value, an Int from 0): the adjoint loop runs that many times."""
        out = []
        for ins in block.instrs:
            for r in ins.regions:
                self._count_loops(r)
            if ins.op is Op.LOOP and any(r in self.varied for r in ins.results):
                zero = Instr(Op.CONST, [], [I32], {"value": 0}, loc=ins.loc)
                out.append(zero)
                body = ins.regions[0]
                n = Value(I32, "ad.n")
                n.owner = body
                body.args.append(n)
                y = body.instrs.pop()
                one = Builder(body, y.loc).const(1, I32)
                y.operands.append(Builder(body, y.loc).op(Op.ADD, I32, n, one))
                body.instrs.append(y)
                ins.operands.append(zero.result)
                trips = Value(I32, "ad.trips")
                trips.owner = ins
                ins.results.append(trips)
                ins.attrs["ad.counted"] = True
            out.append(ins)
        block.instrs = out

    def _export(self, block: Block) -> None:
        """Make each ``if`` with an active result also yield every value its branches
        compute (innermost first, so a branch's exports include its inner ifs'): the
        adjoint reads them there instead of recomputing the branch.  DCE drops the ones
        the adjoint does not use.  ``ad.export`` = the number exported per branch."""
        for ins in block.instrs:
            for r in ins.regions:
                self._export(r)
            if ins.op is not Op.IF or not any(r in self.varied for r in ins.results):
                continue
            per = [[v for i in r.instrs[:-1] for v in i.results
                    if not isinstance(v.type, BufferType)] for r in ins.regions]
            for k, r in enumerate(ins.regions):
                y = r.instrs.pop()
                rb = Builder(r, y.loc)
                for j, vals in enumerate(per):
                    y.operands += vals if j == k else [rb.const(_zero(v.type), v.type)
                                                       for v in vals]
                r.instrs.append(y)
            for vals in per:
                for v in vals:
                    res = Value(v.type)
                    res.owner = ins
                    ins.results.append(res)
            ins.attrs["ad.export"] = [len(v) for v in per]

    def P(self, v: Value) -> Value:
        """The value the adjoint reads for primal value ``v`` where it is."""
        return self.sub.get(v, v)

    # -- the reverse sweep ----------------------------------------------------------------
    def acc(self, adj: dict[Value, Value], v: Value, c: Value, b: Builder) -> None:
        """adj[v] += c, for an active v."""
        if v in self.varied:
            old = adj.get(v)
            adj[v] = c if old is None else b.op(Op.ADD, F32, old, c)

    def sweep(self, instrs: list[Instr], adj: dict[Value, Value], b: Builder) -> None:
        """Emit, into ``b``, the adjoint of ``instrs`` (already computed in its scope)."""
        for ins in reversed(instrs):
            b.loc = ins.loc
            if ins.op is Op.IF:
                self.if_(ins, adj, b)
            elif ins.op is Op.LOOP:
                if ins.attrs.get("ad.counted"):
                    self.loop(ins, adj, b)
            elif len(ins.results) == 1 and ins.result in adj:
                self.instr(ins, adj.pop(ins.result), adj, b)

    def clone_into(self, block: Block, args: list[Value], b: Builder
                   ) -> tuple[list[Instr], dict[Value, Value]]:
        """Append a copy of ``block``'s instructions (not its terminator) to ``b``, its
        arguments bound to ``args``; the copies keep the originals' activity."""
        m: dict[Value, Value] = dict(self.sub)
        m.update(zip(block.args, args))
        tmp = Block()
        tmp.instrs = [i for i in block.instrs[:-1] if id(i) not in self.tape.stores]
        new = clone_block(tmp, m).instrs
        b.block.instrs += new
        for old, v in m.items():
            if old in self.varied:
                self.varied.add(v)
            if old in self.detached:
                self.detached.add(v)
            if old in self.rules:
                xs, ps = self.rules[old]
                self.rules[v] = ([m.get(x, x) for x in xs], [m.get(p, p) for p in ps])
        return new, m

    def region(self, block: Block, args: list[Value], seeds: dict[int, Value], b: Builder
               ) -> tuple[dict[Value, Value], dict[Value, Value], set[Value], list[Instr]]:
        """Recompute ``block`` into ``b`` and sweep it, seeded with the adjoints of its
        yielded values (index -> adjoint): (adjoints, mapping, values defined there, the
        recomputing instructions)."""
        new, m = self.clone_into(block, args, b)
        y = block.instrs[-1].operands
        local: dict[Value, Value] = {}
        mark = len(b.block.instrs)
        for i, a in seeds.items():
            self.acc(local, m.get(y[i], y[i]), a, b)
        self.sweep(new, local, b)
        _mark_sweep(b.block, mark)
        defined = {r for ins in new for r in _defined(ins)}
        return local, m, defined, new

    def if_(self, ins: Instr, adj: dict[Value, Value], b: Builder) -> None:
        seeds = {i: adj.pop(r) for i, r in enumerate(ins.results) if r in adj}
        if not seeds:
            return
        counts = ins.attrs.get("ad.export", [0, 0])
        base = len(ins.results) - sum(counts)
        blocks, locals_ = [], []
        outer = self.sub
        for k, reg in enumerate(ins.regions):
            nb = Block()
            rb = Builder(nb, ins.loc)
            first = base + sum(counts[:k])
            y = reg.instrs[-1].operands
            self.sub = dict(outer)
            self.sub.update((y[i], outer.get(ins.results[i], ins.results[i]))
                            for i in range(first, first + counts[k]))
            for i in reg.instrs[:-1]:  # buffers (tables) are not exported: copies
                if any(isinstance(v.type, BufferType) for v in i.results):
                    _, m = self.clone_into(_one(i), [], rb)
                    self.sub.update(m)
            local: dict[Value, Value] = {}
            for i, a in seeds.items():
                self.acc(local, y[i], a, rb)
            self.sweep(reg.instrs[:-1], local, rb)
            defined = {r for i in reg.instrs for r in _defined(i)}
            blocks.append(nb)
            locals_.append({v: a for v, a in local.items() if v not in defined})
        self.sub = outer
        free = list(dict.fromkeys(v for lo in locals_ for v in lo))
        if not free and not any(i.op is Op.STORE for nb in blocks for i in nb.walk()):
            return  # nothing flows out and no gradient is stored
        for nb, lo in zip(blocks, locals_):
            rb = Builder(nb, ins.loc)
            rb.yield_(*[lo.get(v) or rb.const(0.0, F32) for v in free])
        new = b.emit(Op.IF, [self.P(ins.operands[0])], [F32] * len(free), regions=blocks)
        for v, r in zip(free, new.results):
            self.acc(adj, v, r, b)

    # long: the adjoint loop, its state recomputation and its carried adjoints
    def loop(self, ins: Instr, adj: dict[Value, Value], b: Builder) -> None:
        body = ins.regions[0]
        hot = [i for i, a in enumerate(body.args) if a.type == F32 and a in self.varied]
        seeds = {i: adj.pop(ins.results[i]) for i in hot if ins.results[i] in adj}
        if not seeds:
            return
        init, trips = ins.operands, self.P(ins.results[-1])
        k = Value(I32, "ad.k")
        ads = [Value(F32, f"ad.{body.args[i].name or i}") for i in hot]
        ab = Block([k, *ads])
        rb = Builder(ab, ins.loc)
        # a covering tape holds every iteration: the adjoint runs k = C-1 .. 0 for every
        # lane, each lane's iterations k < trips doing the work, so that the lanes of a
        # packet are at the same k and load their slots as vectors (one slot per k; with
        # k = trips-1 .. 0 the lanes of different trips gather from different slots)
        aligned = self.tape.covers and self.tape.taped(ins)
        ib = Block() if aligned else ab
        wb = Builder(ib, ins.loc) if aligned else rb
        state = self._state_at(ins, k, wb)
        self.varied.update(state[i] for i in hot)
        local, m, defined, fwd = self.region(
            body, state, {1 + i: a for i, a in zip(hot, ads)}, wb)
        carried = set(state)
        free = [v for v in local if v not in defined and v not in carried]
        sums = [Value(F32, "ad.sum") for _ in free]
        for s in sums:
            s.owner = ab
        ab.args += sums
        out = [*[local.get(state[i]) or wb.const(0.0, F32) for i in hot],
               *[wb.op(Op.ADD, F32, s, local[v]) for s, v in zip(sums, free)]]
        if aligned:
            wb.yield_(*out)
            idle = Block()
            Builder(idle, ins.loc).yield_(*ads, *sums)
            out = rb.emit(Op.IF, [rb.op(Op.LT, BOOL, k, trips)], [F32] * len(out),
                          regions=[ib, idle]).results
        more = rb.op(Op.GT, BOOL, k, rb.const(0, I32))
        rb.yield_(more, rb.op(Op.SUB, I32, k, rb.const(1, I32)), *out)
        zero = b.const(0.0, F32)
        first = b.const(self.tape.cap - 1, I32) if aligned else \
            b.op(Op.SUB, I32, trips, b.const(1, I32))
        operands = [first, *[seeds.get(i) or zero for i in hot], *[zero] * len(free)]
        types = [I32, *[F32] * (len(hot) + len(free))]
        ok = self.tape.guard(ins, trips, b)  # covers: a lane that overflowed skips it
        if ok is None:
            res = b.emit(Op.LOOP, operands, types, regions=[ab]).results[1:]
        else:
            then, other = Block(), Block()
            tb = Builder(then, ins.loc)
            tb.yield_(*tb.emit(Op.LOOP, operands, types, regions=[ab]).results[1:])
            ob = Builder(other, ins.loc)
            ob.yield_(*[ob.const(0.0, F32)] * (len(types) - 1))
            res = b.emit(Op.IF, [ok], types[1:], regions=[then, other]).results
        # a taped loop: iteration k < C loads what its sweep reads instead of running fwd
        self.tape.keep(ins, ib, fwd, k, {c: o for o, c in m.items()})
        for i, r in zip(hot, res):
            self.acc(adj, init[i], r, b)
        back = {v: k for k, v in self.sub.items()}  # exported results -> their values
        for v, r in zip(free, res[len(hot):]):
            self.acc(adj, back.get(v, v), r, b)

    def _state_at(self, ins: Instr, k: Value, b: Builder) -> list[Value]:
        """The loop's carried values before iteration ``k`` (0 = the initial values): the
        body run k times from them, or, for a taped loop, run k - c times from checkpoint
        c = min(k, cap - 1) (0 times for k < cap)."""
        body, init, count = ins.regions[0], [self.P(v) for v in ins.operands], k
        init, count = self.tape.load(ins, k, b) or (init, count)
        if count is None:  # covers: the state of iteration k is on the tape
            return init
        types = [a.type for a in body.args]
        then, other = Block(), Block()
        tb = Builder(then, ins.loc)
        i = Value(I32, "ad.i")
        s = [Value(t, a.name) for t, a in zip(types, body.args)]
        lb = Block([i, *s])
        bb = Builder(lb, ins.loc)
        _, m = self.clone_into(body, s, bb)
        y = [m.get(v, v) for v in body.instrs[-1].operands[1:]]
        i1 = bb.op(Op.ADD, I32, i, bb.const(1, I32))
        bb.yield_(bb.op(Op.LT, BOOL, i1, count), i1, *y)
        inner = tb.emit(Op.LOOP, [tb.const(0, I32), *init], [I32, *types], regions=[lb])
        tb.yield_(*inner.results[1:])
        Builder(other, ins.loc).yield_(*init)
        cond = b.op(Op.GT, BOOL, count, b.const(0, I32))
        return b.emit(Op.IF, [cond], types, regions=[then, other]).results

    # long: one rule per op, as a table would hold them
    def instr(self, ins: Instr, a: Value, adj: dict[Value, Value], b: Builder) -> None:
        """Propagate the adjoint ``a`` of ``ins``'s result to its operands."""
        op, x, y = ins.op, ins.operands, ins.result  # x, y: the keys of adjoints
        v, yv = [self.P(o) for o in x], self.P(y)  # and their values where the sweep is
        acc = self.acc
        if y in self.rules:
            xs, ps = self.rules[y]
            for xi, p in zip(xs, ps):
                if xi in self.varied:
                    acc(adj, xi, zero_guard(b, a, b.op(Op.MUL, F32, a, self.P(p))), b)
            return
        if y in self.detached:
            return
        if op is Op.LOAD:
            if x[0] in self.bufs:
                grad, row = self.bufs[x[0]]
                idx = v[1] if v[1].type == I32 else b.op(Op.CAST, I32, v[1])
                j = b.op(Op.ADD, I32, row, idx)
                old = b.op(Op.LOAD, F32, grad, j)
                b.emit(Op.STORE, [grad, j, b.op(Op.ADD, F32, old, a)], [])
            return
        zero = None if op not in (Op.SQRT, Op.ABS, Op.MIN, Op.MAX, Op.SELECT) \
            else b.const(0.0, F32)
        if op is Op.ADD:
            acc(adj, x[0], a, b)
            acc(adj, x[1], a, b)
        elif op is Op.SUB:
            acc(adj, x[0], a, b)
            if x[1] in self.varied:
                acc(adj, x[1], b.op(Op.NEG, F32, a), b)
        elif op is Op.NEG:
            acc(adj, x[0], b.op(Op.NEG, F32, a), b)
        elif op is Op.MUL:
            for i in (0, 1):
                if x[i] in self.varied:
                    acc(adj, x[i], zero_guard(b, a, b.op(Op.MUL, F32, a, v[1 - i])), b)
        elif op is Op.DIV:  # d/da = 1/b, d/db = -y/b
            q = zero_guard(b, a, b.op(Op.DIV, F32, a, v[1]))
            acc(adj, x[0], q, b)
            if x[1] in self.varied:
                acc(adj, x[1], zero_guard(b, a, b.op(Op.NEG, F32, b.op(Op.MUL, F32, q, yv))), b)
        elif op is Op.SQRT:  # a / (2 y), 0 at y = 0
            q = b.op(Op.DIV, F32, a, b.op(Op.ADD, F32, yv, yv))
            acc(adj, x[0], b.op(Op.SELECT, F32, b.op(Op.GT, BOOL, yv, zero), q, zero), b)
        elif op is Op.ABS:
            neg = b.op(Op.LT, BOOL, v[0], zero)
            acc(adj, x[0], b.op(Op.SELECT, F32, neg, b.op(Op.NEG, F32, a), a), b)
        elif op in (Op.MIN, Op.MAX, Op.SELECT):
            if op is Op.SELECT:
                c, pair = v[0], x[1:]
            else:
                c, pair = b.op(Op.LT if op is Op.MIN else Op.GT, BOOL, v[0], v[1]), x
            if pair[0] in self.varied:
                acc(adj, pair[0], b.op(Op.SELECT, F32, c, a, zero), b)
            if pair[1] in self.varied:
                acc(adj, pair[1], b.op(Op.SELECT, F32, c, zero, a), b)


_F32_JSON = {"kind": "scalar", "dtype": "f32"}


def zero_guard(b: Builder, a: Value, p: Value) -> Value:
    """``p`` (a product of the adjoint ``a`` and a local partial), 0 where ``a`` is 0: a
    zero adjoint contributes nothing even where the partial is infinite or NaN (a ``sqrt``,
    a division or a rule's partial on the side of a ``select``/``if`` not taken), as
    inf * 0 = NaN would otherwise poison every adjoint upstream.  The select is tagged
    (``GUARD``): ``eliminate`` reads it as the edge ``p`` -> result of weight 1 and keeps
    the guard on every edge it composes."""
    zero = b.const(0.0, F32)
    return b.op(Op.SELECT, F32, b.op(Op.EQ, BOOL, a, zero), zero, p, **{GUARD: True})


def _zero(t) -> object:
    return 0.0 if t == F32 else False if t == BOOL else 0


def _mark_sweep(block: Block, start: int) -> None:
    """Tag the first instruction of the reverse sweep that follows a forward part in
    ``block`` (a function's body, an adjoint loop's body): where ``eliminate`` and the tape
    count (passes/ad_tape.py) split the block."""
    if start < len(block.instrs):
        block.instrs[start].attrs[SWEEP] = True


def _one(ins: Instr) -> Block:
    """A block holding ``ins`` and a terminator (for clone_into)."""
    blk = Block()
    blk.instrs = [ins, Instr(Op.YIELD, [], [])]
    return blk


def _defined(ins: Instr) -> list[Value]:
    """The values ``ins`` and its regions define."""
    out = list(ins.results)
    for r in ins.regions:
        out += r.args
        for i in r.instrs:
            out += _defined(i)
    return out
