"""What a reverse sweep keeps from its forward part: the "tape" of a ``reverse`` build.

Not a pass: an analysis of the IR that ``ad_reverse`` (and ``eliminate``) produce, for the
tests and ``bench/ad_eliminate.py``.  ``ad_reverse`` tags the first instruction of each
sweep that follows its forward part in one block (``ad.sweep``): a kernel's body, and the
body of each adjoint loop (one bounce: the state recomputed, the body run forward, then
swept).  The block splits there into F (the forward part) and S (the sweep, up to the
terminator).

**Tape values of a block** = the distinct non-constant values defined by F's top-level
instructions (a branch's values leave it as the results of its ``if``) that some
instruction of S reads, at any depth.  With recomputation these are what stays live per
lane between one iteration's forward part and its sweep; a per-lane tape would store
exactly them.  Values defined outside the block (loop-invariant ones) are not counted.
Bytes: 4 per value, 8 for 64-bit integers.  Count after DCE (:func:`tape`), since
``ad_reverse`` exports every value of a branch and leaves the unread ones to DCE.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..ir import Block, Function, Instr, Op, ScalarType, Value
from .ad_reverse import SWEEP
from .dce import eliminate_dead_code


@dataclass
class Tape:
    """The tape of one block: ``kind`` "loop" (per iteration) or "kernel" (per call)."""

    kind: str
    line: int
    values: int
    bytes: int


def sweep_blocks(fn: Function) -> list[tuple[Block, int]]:
    """Each block with a tagged sweep and the index of its first sweep instruction."""
    out = []
    for blk in _blocks(fn.body):
        for i, ins in enumerate(blk.instrs):
            if ins.attrs.get(SWEEP):
                out.append((blk, i))
                break
    return out


def tape(fn: Function, dce: bool = True) -> list[Tape]:
    """The tape of each of ``fn``'s sweeps, after DCE (``fn`` is changed by it)."""
    split = [(blk, set(map(id, blk.instrs[:m]))) for blk, m in sweep_blocks(fn)]
    if dce:
        eliminate_dead_code(fn)
    out = []
    for blk, fwd in split:
        f = [i for i in blk.instrs if id(i) in fwd]
        s = [i for i in blk.instrs[:-1] if id(i) not in fwd]
        defined = {r: i for i in f for r in i.results if i.op is not Op.CONST}
        read: set[Value] = set()
        for ins in s:
            for x in [ins, *_walk(ins)]:
                read.update(v for v in x.operands if v in defined)
        n = sum(8 if isinstance(v.type, ScalarType) and v.type.bits == 64 else 4
                for v in read)
        kind = "loop" if blk is not fn.body else "kernel"
        line = s[0].loc.line if s and getattr(s[0].loc, "line", None) else 0
        out.append(Tape(kind, line, len(read), n))
    return out


def _walk(ins: Instr):
    for r in ins.regions:
        yield from r.walk()


def _blocks(blk: Block):
    yield blk
    for ins in blk.instrs:
        for r in ins.regions:
            yield from _blocks(r)
