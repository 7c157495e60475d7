"""``eliminate``: vertex elimination on the linearized graph of each reverse sweep.

Expects: the output of ``ad_reverse`` (its sweeps tagged ``ad.sweep``: passes/ad_tape.py).
Runs right after it in a ``reverse`` build that asks for it (``Build.of(..., eliminate=)``);
a threshold of 0 (or a build without it) leaves the IR exactly as ``ad_reverse`` made it.

Guarantees: the same adjoints up to float rounding, with the sweep of each block (a kernel's
body, one iteration of an adjoint loop) reading no more values of its forward part than
before (a function whose elimination would make one sweep read more is left as it was).

The sweep is linear in the adjoints: each of its instructions that computes an adjoint from
adjoints (``add``/``sub``/``neg`` of adjoints, ``mul`` of an adjoint by a primal value,
``div`` of an adjoint by one, ``select`` of adjoints and zeros on a primal condition) is a
vertex of the linearized computational graph (LCG, transposed), its local partials the
weights of its in-edges.  ``ad_reverse`` guards each product of an adjoint and a partial
(``zero_guard``: 0 where the adjoint is 0, even through an infinite partial); the pass
reads a guard as an edge of weight 1 and keeps the guard's meaning on what it builds: every
edge applied (a * w) and every product of weights (w_ij * w_jk) is 0 where its first factor
is 0, so that the guards cost elimination nothing.  Everything else is a barrier: its
adjoint operands are dependent vertices (kept), its adjoint results independent ones
(loads of ``gPRM``, the results of the adjoint ``if``s and loops, the seeds).  Per
straight-line region of the sweep (the block after its forward part, and each branch of its
adjoint ``if``s), the pass

1. builds the LCG, with weights as small expressions of primal values;
2. eliminates intermediate vertices greedily, lowest Markowitz cost d_in*d_out first,
   skipping a vertex while its cost exceeds the threshold (default 10, as in Mitsuba 2's
   paper); eliminating j adds w_ij*w_jk to the edge i->k of each predecessor i and
   successor k;
3. computes every edge weight of the eliminated graph at the end of the forward part (the
   primal values a weight needs are there: values of a branch leave it as its ``if``'s
   results), or in place where a weight needs a value computed only in the sweep;
4. rewrites the region: each vertex left = the sum of its predecessors times the weights.

The sweep then reads the weights instead of the primal values the local partials were made
of: fewer values kept live (or taped) between one iteration's forward part and its sweep,
for some more arithmetic in the forward part.  ``bench/ad_eliminate.py`` counts both.
"""

from __future__ import annotations

import dataclasses
import heapq
import sys
from typing import Union

from ..ir import F32, PURE_OPS, Block, Builder, Function, Instr, Module, Op, Value, \
    clone_block, replace_uses
from . import Pass, register
from .ad_reverse import DIFFERENTIATED, GUARD, SWEEP, zero_guard

GRADIENTS = {grad for grad, _ in DIFFERENTIATED.values()}  # gPRM, gT
from .ad_tape import sweep_blocks, tape

DEFAULT_THRESHOLD = 10

# a weight: a float, a primal Value, or ("inv", w) 1/w, ("sel", cond, flip, w) w where cond
# (flip: where not cond) and else 0, ("mul", w, w), ("add", w, w).  A select stays a select
# (never a product with 0 or 1): an infinite partial the primal sweep selected away must
# not become inf * 0 = NaN; so are products ("mul") and applications (_apply) zero-guarded.
W = Union[float, Value, tuple]


@register
class Eliminate(Pass):
    """Greedy vertex elimination on the reverse sweeps; ``threshold``: the largest
    d_in*d_out a vertex may have to be eliminated (0: the pass does nothing)."""

    name = "eliminate"

    def __init__(self, threshold: int = DEFAULT_THRESHOLD) -> None:
        self.threshold = int(threshold)

    def run(self, module: Module) -> None:
        if self.threshold <= 0:
            return
        limit = sys.getrecursionlimit()
        sys.setrecursionlimit(max(limit, 20000))  # weights are products of long chains
        try:
            for fn in module.functions.values():
                self._function(fn)
        finally:
            sys.setrecursionlimit(limit)

    def _function(self, fn: Function) -> None:
        """Eliminate on a copy of ``fn``'s body; keep it unless some sweep of it would read
        more forward values than before (greedy elimination can make a product of weights
        that needs more than the partials it replaced)."""
        if not sweep_blocks(fn):
            return
        trial = dataclasses.replace(fn, body=clone_block(fn.body, {}))
        for blk, m in sweep_blocks(trial):
            _Sweep(trial, blk, m, self.threshold).run()
        # tape's DCE changes ``fn`` itself, harmlessly (a second copy of a body was most of
        # this pass's time on a large adjoint: roughplastic's eval, 140k instructions)
        before = [t.values for t in tape(fn)]
        after = [t.values for t in tape(trial)]  # its DCE only drops what the sweeps left
        if all(a <= b for a, b in zip(after, before)):
            fn.body = trial.body


class _Sweep:
    """The sweep of one block: its instructions from index ``m`` to the terminator."""

    def __init__(self, fn: Function, blk: Block, m: int, threshold: int) -> None:
        self.blk, self.m, self.threshold = blk, m, threshold
        self.defs: dict[Value, Instr | None] = {}  # values the sweep defines
        self.users: dict[Value, list[Instr]] = {}
        self.adj: set[Value] = set()
        if blk is fn.body:
            self.adj.update(p.value for p in fn.params
                            if p.value.type == F32 and (p.value.name or "").startswith("a."))
        else:
            self.adj.update(a for a in blk.args if a.type == F32)
        self.head = Block()  # the weights, computed at the end of the forward part
        self.memo: dict[W, Value] = {}
        self.movable: dict[Value, bool] = {}
        self.forward = {r for i in blk.instrs[:m] for r in i.results}
        self.varies: dict[W, bool] = {}
        self.tests: set[Instr] = set()  # the ``a == 0`` tests of ad_reverse's guards

    def run(self) -> None:
        blk, m = self.blk, self.m
        body = blk.instrs[m:-1]
        self._analyze(blk.instrs[m:])
        new, mp = self._region(body)
        term = blk.instrs[-1]
        term.operands = [mp.get(v, v) for v in term.operands]
        for ins in blk.instrs:
            ins.attrs.pop(SWEEP, None)
        rest = [*new, term]
        rest[0].attrs[SWEEP] = True
        blk.instrs = [*blk.instrs[:m], *self.head.instrs, *rest]

    # -- analysis -------------------------------------------------------------------------
    def _analyze(self, instrs: list[Instr]) -> None:
        """Definitions, users and the adjoints (values that depend on an adjoint)."""
        for ins in instrs:
            for v in ins.operands:
                self.users.setdefault(v, []).append(ins)
            for r in ins.results:
                self.defs[r] = ins
            if ins.op in (Op.IF, Op.LOOP):
                self.adj.update(r for r in ins.results if r.type == F32)
                if ins.op is Op.IF:
                    for r in ins.regions:
                        self._analyze(r.instrs)
                else:  # an adjoint loop: its body is a sweep of its own; note its reads
                    for i in ins.regions[0].walk():
                        for v in i.operands:
                            self.users.setdefault(v, []).append(ins)
                    self.defs.update((a, None) for a in ins.regions[0].args)
                    self.defs.update((r, ins) for i in ins.regions[0].walk()
                                     for r in i.results)
            elif ins.op is Op.SELECT and ins.attrs.get(GUARD):
                self.tests.add(self.defs[ins.operands[0]])
                self.adj.update(ins.results)
            elif ins.op is Op.LOAD and ins.operands[0].name in GRADIENTS:
                self.adj.add(ins.result)
            elif any(v in self.adj for v in ins.operands) and ins.results \
                    and ins.results[0].type == F32:
                self.adj.update(ins.results)

    def _edges(self, ins: Instr) -> list[tuple[Value, W]] | None:
        """The in-edges (source, weight) of an adjoint computed linearly from adjoints;
        None for anything else (a barrier)."""
        A, op, x = self.adj, ins.op, ins.operands
        if len(ins.results) != 1 or ins.result not in A or ins.regions:
            return None
        if op in (Op.ADD, Op.SUB) and x[0] in A and x[1] in A:
            return [(x[0], 1.0), (x[1], 1.0 if op is Op.ADD else -1.0)]
        if op is Op.NEG and x[0] in A:
            return [(x[0], -1.0)]
        if op is Op.MUL and (x[0] in A) != (x[1] in A):
            a, c = (x[0], x[1]) if x[0] in A else (x[1], x[0])
            return [(a, self._coef(c))]
        if op is Op.DIV and x[0] in A and x[1] not in A:
            return [(x[0], ("inv", self._coef(x[1])))]
        if op is Op.SELECT and ins.attrs.get(GUARD):
            return [(x[2], 1.0)]  # every edge is guarded (_apply), so this is the identity
        if op is Op.SELECT and x[0] not in A:
            out: list[tuple[Value, W]] = []
            for val, flip in ((x[1], False), (x[2], True)):
                if val in A:
                    out.append((val, ("sel", x[0], flip, 1.0)))
                elif self._coef(val) != 0.0:
                    return None
            return out
        return None

    def _coef(self, v: Value) -> W:
        d = self.defs.get(v) or getattr(v, "owner", None)
        if isinstance(d, Instr) and d.op is Op.CONST and v.type == F32:
            return float(d.attrs["value"])
        return v

    # -- one straight-line region -----------------------------------------------------------
    def _region(self, instrs: list[Instr]) -> tuple[list[Instr], dict[Value, Value]]:
        """Eliminate in ``instrs`` (after the branches of its ``if``s); the new
        instructions and what the kept adjoints became."""
        for ins in instrs:
            if ins.op is Op.IF:
                for r in ins.regions:
                    new, mp = self._region(r.instrs[:-1])
                    y = r.instrs[-1]
                    y.operands = [mp.get(v, v) for v in y.operands]
                    r.instrs = [*new, y]
        lin = {ins: e for ins in instrs if (e := self._edges(ins)) is not None}
        preds: dict[Value, dict[Value, W]] = {}
        succs: dict[Value, dict[Value, W]] = {}
        inner: list[Value] = []
        for ins, edges in lin.items():
            v = ins.result
            preds[v] = {}
            for src, w in edges:
                _add_edge(preds, succs, src, v, w)
            if all(u in lin or u in self.tests for u in self.users.get(v, ())):
                inner.append(v)
        # a guarded product (ad_reverse's a * p, read only by its guard): merged into its
        # guard first, so that the graph is the one the sweep has without guards
        merged = {x for ins in lin if ins.attrs.get(GUARD) and (x := ins.operands[2]) in
                  inner and len(self.users[x]) == 1}
        for v in merged:
            _drop(v, preds, succs)
        inner = [v for v in inner if v not in merged]
        best = (self._kept(preds), preds, merged)
        for guard in (True, False):
            p = {v: dict(e) for v, e in preds.items()}
            s = {v: dict(e) for v, e in succs.items()}
            gone = self._eliminate(inner, p, s, guard) | merged
            if self._kept(p) <= best[0]:
                best = (self._kept(p), p, gone)
        return self._rebuild(instrs, lin, best[1], best[2])

    def _kept(self, preds: dict) -> int:
        """The distinct weights that vary per block on the edges of a graph."""
        return len({w for e in preds.values() for w in e.values() if self._varies(w)})

    def _eliminate(self, inner: list[Value], preds: dict, succs: dict, guard: bool
                   ) -> set[Value]:
        """Greedy vertex elimination, lowest d_in*d_out first, none above the threshold;
        with ``guard``, only vertices whose elimination keeps no more weights."""
        order = {v: k for k, v in enumerate(inner)}

        def cost(v: Value) -> int:
            return len(preds[v]) * len(succs.get(v, ()))

        heap = [(cost(v), order[v], v) for v in inner]
        heapq.heapify(heap)
        gone: set[Value] = set()
        while heap:
            c, k, v = heapq.heappop(heap)
            if v in gone or c != cost(v):
                if v not in gone:
                    heapq.heappush(heap, (cost(v), k, v))
                continue
            if c > self.threshold or (guard and not self._saves(v, preds, succs)):
                continue  # pushed again if a neighbour's elimination changes its cost
            gone.add(v)
            ins_, outs = _drop(v, preds, succs)
            for u in (*ins_, *outs):
                if u in order and u not in gone:
                    heapq.heappush(heap, (cost(u), order[u], u))
        return gone

    def _saves(self, v: Value, preds: dict, succs: dict) -> bool:
        """Whether eliminating ``v`` leaves no more weights to keep than before: the
        weights that vary per block (see :meth:`_varies`) on its edges, against those of
        the edges it adds or changes."""
        ins_, outs = preds[v], succs.get(v, {})
        removed = sum(map(self._varies, [*ins_.values(), *outs.values()]))
        added = 0
        for i, wi in ins_.items():
            for j, wj in outs.items():
                old = preds[j].get(i)
                new = _mul(wi, wj) if old is None else ("add", old, _mul(wi, wj))
                added += self._varies(new) - (old is not None and self._varies(old))
        return added <= removed

    def _varies(self, w: W) -> bool:
        """Whether weight ``w`` depends on a value of this block's forward part (what a
        tape keeps); one that does not is computed where the sweep needs it."""
        if isinstance(w, (float, bool)):
            return False
        if w not in self.varies:
            if isinstance(w, tuple):
                self.varies[w] = any(self._varies(x) for x in w[1:])
            else:
                d = self.defs.get(w)
                self.varies[w] = w in self.forward or (
                    isinstance(d, Instr) and any(self._varies(x) for x in d.operands))
        return self.varies[w]

    def _rebuild(self, instrs: list[Instr], lin: dict, preds: dict, gone: set[Value]
                 ) -> tuple[list[Instr], dict[Value, Value]]:
        out = Block()
        mp: dict[Value, Value] = {}
        local: dict[W, Value] = {}
        for ins in instrs:
            if ins in self.tests:
                continue  # its guard is rebuilt (_apply) or eliminated
            if ins not in lin:
                ins.operands = [mp.get(v, v) for v in ins.operands]
                for r in ins.regions:
                    replace_uses(r, mp)
                out.instrs.append(ins)
                continue
            v = ins.result
            if v in gone:
                continue
            b = Builder(out, ins.loc)
            total = None
            for u, w in preds[v].items():
                t = self._apply(mp.get(u, u), w, b, local)
                total = t if total is None else b.op(Op.ADD, F32, total, t)
            mp[v] = total if total is not None else b.const(0.0, F32)
        return out.instrs, mp

    # -- weights --------------------------------------------------------------------------
    def _apply(self, a: Value, w: W, b: Builder, local: dict) -> Value:
        """a * w, 0 where a is 0 (w may be infinite there: ad_reverse's guard)."""
        if isinstance(w, float) and w == 1.0:
            return a
        if isinstance(w, float) and w == -1.0:
            return b.op(Op.NEG, F32, a)
        zero = b.const(0.0, F32)
        if isinstance(w, tuple) and w[0] == "sel":
            c, t = self._weight(w[1], b, local), self._apply(a, w[3], b, local)
            return b.op(Op.SELECT, F32, c, *((zero, t) if w[2] else (t, zero)))
        p = b.op(Op.MUL, F32, a, self._weight(w, b, local))
        return p if isinstance(w, float) else zero_guard(b, a, p)

    def _weight(self, w: W, b: Builder, local: dict) -> Value:
        """The value of ``w`` for the sweep: computed at the end of the forward part if it
        varies there, else where the sweep is."""
        if w in self.memo:
            return self.memo[w]
        if w in local:
            return local[w]
        if self._varies(w) and self._can_move(w):
            return self._emit(w, Builder(self.head, b.loc), self.memo, True)
        return self._emit(w, b, local, False)

    def _can_move(self, w: W) -> bool:
        """Whether weight ``w`` can be computed at the end of the forward part."""
        if isinstance(w, float):
            return True
        if isinstance(w, tuple):
            return all(self._can_move(x) for x in w[1:] if not isinstance(x, bool))
        if w not in self.movable:
            d = self.defs.get(w, "outside")
            self.movable[w] = d == "outside" or (
                isinstance(d, Instr) and d.op in PURE_OPS and not d.regions
                and len(d.results) == 1 and w not in self.adj
                and all(self._can_move(x) for x in d.operands))
        return self.movable[w]

    def _emit(self, w: W, b: Builder, memo: dict, moved: bool) -> Value:
        """The value of weight ``w``, computed into ``b`` (copying the sweep's primal
        instructions it needs there when ``moved``)."""
        if w in memo:
            return memo[w]
        if isinstance(w, float):
            v = b.const(w, F32)
        elif isinstance(w, Value):
            d = self.defs.get(w)
            if not moved or d is None:
                return w
            v = b.emit(d.op, [self._emit(x, b, memo, True) for x in d.operands],
                       [w.type], dict(d.attrs)).result
        elif w[0] == "inv":
            v = b.op(Op.DIV, F32, b.const(1.0, F32), self._emit(w[1], b, memo, moved))
        elif w[0] == "sel":
            zero = b.const(0.0, F32)
            c = self._emit(w[1], b, memo, moved)
            x = self._emit(w[3], b, memo, moved)
            v = b.op(Op.SELECT, F32, c, *((zero, x) if w[2] else (x, zero)))
        elif w[0] == "mul" and 0.0 in w[1:]:  # (a float) 0, even times an infinite partial
            v = b.const(0.0, F32)
        else:
            x, y = (self._emit(u, b, memo, moved) for u in w[1:])
            v = b.op(Op.MUL if w[0] == "mul" else Op.ADD, F32, x, y)
            if w[0] == "mul" and not any(isinstance(u, float) for u in w[1:]):
                v = zero_guard(b, x, v)  # a zero partial upstream: 0 even through an infinite one
        memo[w] = v
        return v


def _mul(a: W, b: W) -> W:
    if isinstance(a, tuple) and a[0] == "sel":
        return ("sel", a[1], a[2], _mul(a[3], b))
    if isinstance(b, tuple) and b[0] == "sel":
        return ("sel", b[1], b[2], _mul(a, b[3]))
    if isinstance(a, float) and isinstance(b, float):
        return a * b
    if isinstance(a, float) and a == 1.0:
        return b
    if isinstance(b, float) and b == 1.0:
        return a
    return ("mul", a, b)


def _drop(v: Value, preds: dict, succs: dict) -> tuple[dict, dict]:
    """Eliminate vertex ``v``: an edge i -> j of weight w_iv * w_vj for each of its
    predecessors i and successors j; its in- and out-edges."""
    ins_, outs = preds.pop(v), succs.pop(v, {})
    for i in ins_:
        succs[i].pop(v, None)
    for j in outs:
        preds[j].pop(v, None)
    for i, wi in ins_.items():
        for j, wj in outs.items():
            _add_edge(preds, succs, i, j, _mul(wi, wj))
    return ins_, outs


def _add_edge(preds: dict, succs: dict, src: Value, dst: Value, w: W) -> None:
    old = preds[dst].get(src)
    if old is not None:
        w = old + w if isinstance(old, float) and isinstance(w, float) else ("add", old, w)
    preds[dst][src] = w
    succs.setdefault(src, {})[dst] = w

