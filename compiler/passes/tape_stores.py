"""``tape_stores``: the adjoint kernel's primal stores only the tape values its sweep reads.

Expects: a reverse build's module after ``ad_reverse`` and ``optimize`` (and ``eliminate``,
if run), before ``vectorize``; tape stores and loads carry ``ad.tape`` (which value of a
slot: passes/ad_checkpoint.py).

Guarantees: every store of a tape value that no load of the function reads is removed,
with what only it used; nothing else changes (the row's layout, ``tape_floats``, stays).
``ad_checkpoint`` tapes every carried value of a loop and every value the sweep reads from
its copy of the body; ``optimize`` then drops the loads whose values the sweep does not
need (a carried value whose adjoint is zero, a forward value that folded), but the stores
are effects and stay: in the Cornell box's albedo adjoint, 20 of a bounce's 62 (one vector
store each per bounce, and a cache line of the lane block's row per value).
"""

from __future__ import annotations

from ..ir import Block, Module, Op
from . import Pass, register
from .ad_checkpoint import TAPE_VALUE
from .dce import eliminate_dead_code


@register
class TapeStores(Pass):
    name = "tape_stores"

    def run(self, module: Module) -> None:
        for fn in module.functions.values():
            read = {i.attrs[TAPE_VALUE] for i in fn.walk()
                    if i.op is Op.LOAD and TAPE_VALUE in i.attrs}
            if _drop(fn.body, read):
                eliminate_dead_code(fn)


def _drop(block: Block, read: set[int]) -> bool:
    """Remove the stores of tape values not in ``read`` from ``block`` and its regions."""
    kept = [i for i in block.instrs
            if not (i.op is Op.STORE and TAPE_VALUE in i.attrs
                    and i.attrs[TAPE_VALUE] not in read)]
    changed = len(kept) != len(block.instrs)
    block.instrs = kept
    for ins in kept:
        for r in ins.regions:
            changed |= _drop(r, read)
    return changed


__all__ = ["TapeStores"]
