"""Dead code elimination for one function: mark and sweep, with per-slot liveness of
``if``/``loop`` results, so that an ``if`` or ``loop`` whose results are partly unused loses
those results (and the values yielded for them) rather than being kept whole.

Not a pass of its own: ``optimize`` runs it after each simplification sweep until nothing
changes.  Roots are the instructions with effects (stores, scatters, calls, returns,
spectral state); everything they transitively use, and the control flow that encloses them,
is live.
"""

from __future__ import annotations

from ..ir import TERMINATORS, Block, Function, Instr, Op, Value

EFFECT_OPS = {Op.STORE, Op.SCATTER, Op.CALL, Op.RETURN, Op.SPEC_SET}


def eliminate_dead_code(fn: Function) -> bool:
    """Remove ``fn``'s dead instructions and dead ``if``/``loop`` result slots in place;
    True if anything changed."""
    live = _Liveness(fn)
    return live.sweep(fn.body)


class _Liveness:
    """Which instructions and which (``if``/``loop``, result index) slots are live."""

    def __init__(self, fn: Function) -> None:
        self.parent: dict[Instr, Instr | None] = {}
        self.producer: dict[Value, tuple[Instr, int]] = {}
        self.live: set[Instr] = set()
        self.slots: set[tuple[Instr, int]] = set()
        self.seen: set[Value] = set()
        self.work: list[Value] = []
        roots: list[Instr] = []  # the instructions with effects, in program order
        self.index(fn.body, None, roots)
        for ins in roots:
            self.mark(ins)
        work, producer = self.work, self.producer
        while work:
            v = work.pop()
            if v in producer:
                ins, k = producer[v]
                self.mark(ins)
                if ins.op is Op.IF or ins.op is Op.LOOP:
                    self.mark_slot(ins, k)

    def index(self, block: Block, owner: Instr | None, roots: list[Instr]) -> None:
        producer, parent = self.producer, self.parent
        if owner is not None and owner.op is Op.LOOP:
            for k, a in enumerate(block.args):
                producer[a] = (owner, k)
        for ins in block.instrs:
            parent[ins] = owner
            results = ins.results
            if len(results) == 1:
                producer[results[0]] = (ins, 0)
            else:
                for k, r in enumerate(results):
                    producer[r] = (ins, k)
            if ins.op in EFFECT_OPS:
                roots.append(ins)
            for r in ins.regions:
                self.index(r, ins, roots)

    def push(self, v: Value) -> None:
        if v not in self.seen:
            self.seen.add(v)
            self.work.append(v)

    def mark(self, ins: Instr | None) -> None:
        live, seen, work, parent = self.live, self.seen, self.work, self.parent
        while ins is not None and ins not in live:
            live.add(ins)
            op = ins.op
            if op is Op.IF:
                self.push(ins.operands[0])
            elif op is Op.LOOP:
                self.push(ins.regions[0].instrs[-1].operands[0])
            elif op is not Op.YIELD:
                for v in ins.operands:
                    if v not in seen:
                        seen.add(v)
                        work.append(v)
            ins = parent[ins]

    def mark_slot(self, ins: Instr, k: int) -> None:
        if (ins, k) in self.slots:
            return
        self.slots.add((ins, k))
        self.mark(ins)
        if ins.op is Op.IF:
            for r in ins.regions:
                self.push(r.instrs[-1].operands[k])
        else:
            self.push(ins.operands[k])
            self.push(ins.regions[0].instrs[-1].operands[k + 1])

    def sweep(self, block: Block) -> bool:
        """Drop what is not live from ``block`` and its regions; True if anything went."""
        changed = False
        out = []
        for ins in block.instrs:
            if ins.op not in TERMINATORS and ins not in self.live:
                changed = True
                continue
            if ins.op in (Op.IF, Op.LOOP):
                keep = [k for k in range(len(ins.results)) if (ins, k) in self.slots]
                if len(keep) < len(ins.results):
                    changed = True
                    _prune_slots(ins, keep)
            for r in ins.regions:
                changed |= self.sweep(r)
            out.append(ins)
        block.instrs = out
        return changed


def _prune_slots(ins: Instr, keep: list[int]) -> None:
    ins.results = [ins.results[k] for k in keep]
    if ins.op is Op.IF:
        for r in ins.regions:
            y = r.instrs[-1]
            y.operands = [y.operands[k] for k in keep]
    else:
        body = ins.regions[0]
        y = body.instrs[-1]
        ins.operands = [ins.operands[k] for k in keep]
        body.args = [body.args[k] for k in keep]
        y.operands = [y.operands[0]] + [y.operands[k + 1] for k in keep]
