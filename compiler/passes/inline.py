"""``inline``: replace every call by the callee's body.

Expects: a verified module straight from lowering, with ``call`` ops naming functions in the
module, and function bodies whose only ``return`` is the last instruction of the body (the
frontend turns early returns into flags).

Guarantees: exported functions contain no ``call``; only exported functions remain (the
library functions they used have been copied into them).  Recursion, direct or mutual, is a
diagnostic at the call site that closes the cycle.

While it copies, it folds what a call's constant arguments decide (:class:`_Folder`): a
comparison or a boolean/integer op of constants becomes a constant, and an ``if`` on a
constant condition becomes its taken region.  A scene's kernel is mostly code that the
scene's constants switch off (``scene_has_shape_kind(4) && ...`` for every shape kind the
scene lacks): copied and then deleted by ``optimize``, it was 60-80% of what inlining
copied, and most of the time of both passes.  What this folds, ``optimize`` would fold
the same way (the interpreter's semantics), so the result's behaviour is unchanged.

``Inline(keep=evaluable)`` (the first of the pipeline's two) leaves the calls to the functions
``keep(module)`` names, and those of them still called, for ``evaluate`` to fold; their own
bodies are inlined all the same.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Any

from ..diagnostics import CompileError, Diagnostic
from ..interp import InterpError, eval_pure
from ..ir import BOOL, Block, Function, Instr, Module, Op, ScalarType, Value, clone_block
from ..ir import clone_instr
from . import Pass, register


@register
class Inline(Pass):
    name = "inline"

    def __init__(self, mark_partials: bool = False,
                 keep: Callable[[Module], set[str]] | None = None) -> None:
        # for automatic differentiation: each call of a math function with declared partial
        # derivatives (ad_forward.PARTIALS) leaves an `ad.rule` giving them
        self.mark_partials = mark_partials
        self.keep_fn = keep

    def run(self, module: Module) -> None:
        self.module = module
        self.keep = self.keep_fn(module) if self.keep_fn is not None else set()
        self.done: set[str] = set()
        self.stack: list[tuple[str, Instr | None]] = []
        # only what the exported functions reach (the rest is deleted below): a scene's
        # module holds every function of the stdlib files it imports
        roots = [f for f in module.functions.values() if f.attrs.get("export")]
        partial = _partials_and_helpers()
        self.movable = {n for n in _called_once(module) - self.keep - partial
                        if module.functions[n].attrs.get("source_name") not in partial}
        for fn in roots or list(module.functions.values()):
            self._inline_function(fn, None)
        called = _still_called(module)
        for name in [n for n, f in module.functions.items()
                     if not f.attrs.get("export") and n not in called]:
            del module.functions[name]

    def _inline_function(self, fn: Function, site: Instr | None) -> None:
        if fn.name in self.done:
            return
        names = [n for n, _ in self.stack]
        if fn.name in names:
            cycle = names[names.index(fn.name):] + [fn.name]
            pretty = " -> ".join(self.module.functions[n].attrs.get("source_name", n)
                                 for n in cycle)
            loc = site.loc if site is not None else fn.loc
            raise CompileError([Diagnostic(loc, f"recursion is not supported: {pretty}")])
        self.stack.append((fn.name, site))
        mapping: dict[Value, Value] = {}
        marking = self.mark_partials
        if marking:  # a partial derivative's own calls (pow_d0 calls pow) are not marked
            from .ad_forward import PARTIALS

            helpers = {h for names in PARTIALS.values() for h in names}
            self.mark_partials = fn.attrs.get("source_name") not in helpers
        self._inline_block(fn.body, mapping)
        self.mark_partials = marking
        self.stack.pop()
        self.done.add(fn.name)

    def _inline_block(self, block: Block, mapping: dict[Value, Value]) -> None:
        """Inline the calls of ``block``; ``mapping`` takes each inlined call's results to
        the values its body returned.  Uses come after definitions, so each instruction of
        the caller is renamed when reached (the inlined copies hold none of the results).
        An ``if`` whose condition is a constant by then is replaced by its taken region."""
        out: list[Instr] = []
        work: deque[Instr | tuple[Instr, Instr]] = deque(block.instrs)
        get = mapping.get
        while work:
            ins = work.popleft()
            if isinstance(ins, tuple):  # a folded `if` or a moved call: its results are
                folded, y = ins  # what its region yielded or its body returned
                for r, v in zip(folded.results, y.operands):
                    mapping[r] = mapping.get(v, v)
                continue
            if mapping:
                ins.operands = [get(v, v) for v in ins.operands]
            op = ins.op
            if op is Op.IF:
                taken = _taken(ins, ins.operands)
                if taken is not None:
                    work.appendleft((ins, taken.instrs[-1]))
                    work.extendleft(reversed(taken.instrs[:-1]))
                    continue
            for region in ins.regions:
                self._inline_block(region, mapping)
            if op is not Op.CALL:
                if op in _FOLDABLE:
                    _fold(ins)
                out.append(ins)
                continue
            callee = self.module.functions.get(ins.attrs["callee"])
            if callee is None:
                raise CompileError([Diagnostic(ins.loc,
                                               f"unknown function `{ins.attrs['callee']}`")])
            self._inline_function(callee, ins)
            if callee.name in self.keep:
                out.append(ins)
                continue
            args = ins.operands  # renamed above
            if callee.name in self.movable:  # its only call: move the body here, and fold
                # it as the caller's own instructions (its results: the return's, renamed)
                body, callee.body.instrs = callee.body.instrs, []
                mapping.update((p.value, a) for p, a in zip(callee.params, args))
                work.appendleft((ins, body[-1]))
                work.extendleft(reversed(body[:-1]))
                continue
            local = {p.value: a for p, a in zip(callee.params, args)}
            body = _Folder(local).clone(callee.body)
            ret = body.instrs.pop()
            assert ret.op is Op.RETURN, f"{callee.name}: body must end in return"
            out.extend(body.instrs)
            for res, val in zip(ins.results, ret.operands):
                mapping[res] = val
            if self.mark_partials:
                self._mark(callee, args, ins, mapping, out)
        block.instrs = out

    def _mark(self, callee: Function, args: list[Value], call: Instr,
              mapping: dict[Value, Value], out: list[Instr]) -> None:
        """After an inlined call of a function with declared partials: inline the partials
        too and wrap the result in an ``ad.rule`` (``ad_forward`` applies them)."""
        from .ad_forward import PARTIALS

        names = PARTIALS.get(callee.attrs.get("source_name", ""))
        if not names or len(names) != len(args) or len(call.results) != 1:
            return
        partials = []
        for name in names:
            helper = self.module.functions[name]
            self._inline_function(helper, call)
            body = clone_block(helper.body, {p.value: a for p, a in zip(helper.params, args)})
            ret = body.instrs.pop()
            out.extend(body.instrs)
            partials.append(ret.operands[0])
        y = mapping[call.results[0]]
        rule = Instr(Op.AD_RULE, [*args, y, *partials], [y.type], {}, loc=call.loc)
        out.append(rule)
        mapping[call.results[0]] = rule.result


def _called_once(module: Module) -> set[str]:
    """The functions, exported ones aside, with exactly one call site in the module.
    ``inline`` moves the body of such a function to its call instead of copying it:
    bottom-up, each function is inlined into once, so nothing else needs the body (70% of
    what a scene's kernel copied was the bodies of functions called once: a plugin's
    method, a dispatch).  Every function's calls count, reachable or not: the partials
    that ``_mark`` inlines are reached by no call."""
    sites: dict[str, int] = {}
    for fn in module.functions.values():
        for ins in fn.walk():
            if ins.op is Op.CALL:
                callee = ins.attrs["callee"]
                sites[callee] = sites.get(callee, 0) + 1
    return {n for n, k in sites.items()
            if k == 1 and n in module.functions and not module.functions[n].attrs.get("export")}


def _partials_and_helpers() -> set[str]:
    """The names of the math functions with declared partials and of their partials:
    ``_mark`` wraps the former's inlined body in an ``ad.rule`` and copies the latter,
    so they are always copied, never moved."""
    from .ad_forward import PARTIALS

    return {*PARTIALS, *(h for helpers in PARTIALS.values() for h in helpers)}


def _still_called(module: Module) -> set[str]:
    """The functions the calls left (to kept functions) reach, from the exported ones."""
    out: set[str] = set()
    todo = [f for f in module.functions.values() if f.attrs.get("export")]
    while todo:
        for ins in todo.pop().walk():
            name = ins.attrs["callee"] if ins.op is Op.CALL else None
            if name is not None and name not in out and name in module.functions:
                out.add(name)
                todo.append(module.functions[name])
    return out


# --------------------------------------------------------------------------------------
# Folding what constants decide, while copying

# ops whose constant operands make a constant of a boolean or integer result (conditions,
# kinds, flags); float arithmetic is left to `optimize`
_FOLDABLE = frozenset({Op.EQ, Op.NE, Op.LT, Op.LE, Op.GT, Op.GE, Op.AND, Op.OR, Op.XOR,
                       Op.NOT, Op.ADD, Op.SUB, Op.MUL, Op.SHL, Op.SHR, Op.SELECT})


def _constant(v: Value) -> Any:
    """The value of ``v`` if a plain ``const`` defines it, else None."""
    d = v._owner()
    if d is None or d.__class__ is not Instr or d.op is not Op.CONST:
        return None
    a = d.attrs
    return a.get("value") if "trait" not in a else None


def _taken(ins: Instr, operands: list[Value]) -> Block | None:
    """The region an ``if`` takes, if its condition (``operands[0]``, renamed) is a
    constant."""
    if ins.op is not Op.IF or len(ins.regions) != 2:
        return None
    c = _constant(operands[0])
    return None if c is None else ins.regions[0 if c else 1]


def _fold(ins: Instr) -> None:
    """Turn ``ins`` into a ``const`` if it is a foldable op of constants with a scalar
    boolean or integer result (as ``optimize`` would, with the interpreter's semantics)."""
    if ins.op not in _FOLDABLE or len(ins.results) != 1:
        return
    t = ins.results[0].type
    if t.__class__ is not ScalarType or t.lanes != 1 or t.is_float:
        return
    cs = [_constant(v) for v in ins.operands]
    if t == BOOL and ins.op in (Op.AND, Op.OR) and (ins.op is Op.OR) in cs:
        ins.op, ins.operands, ins.attrs = Op.CONST, [], {"value": ins.op is Op.OR}
        return  # false && x, true || x
    if any(c is None for c in cs) or any(v.type.lanes != 1 for v in ins.operands):
        return
    try:
        val = eval_pure(ins.op, t, [v.type for v in ins.operands], cs, ins.attrs)
    except (InterpError, IndexError, KeyError, TypeError, ValueError, OverflowError):
        return
    ins.op, ins.operands = Op.CONST, []
    ins.attrs = {"value": bool(val) if t == BOOL else int(val)}


class _Folder:
    """:func:`clone_block` that folds as it copies: a foldable op of constants is copied
    as a constant, and an ``if`` on a constant as its taken region's instructions."""

    def __init__(self, mapping: dict[Value, Value]) -> None:
        self.mapping = mapping

    def clone(self, block: Block) -> Block:
        new = Block([Value(a.type, a.name) for a in block.args])
        for old_arg, new_arg in zip(block.args, new.args):
            self.mapping.setdefault(old_arg, new_arg)
        self.copy(block.instrs, new.instrs)
        return new

    def copy(self, instrs: list[Instr], out: list[Instr]) -> None:
        mapping = self.mapping
        get = mapping.get
        for ins in instrs:
            operands = [get(v, v) for v in ins.operands]
            taken = _taken(ins, operands) if ins.op is Op.IF else None
            if taken is not None:  # the taken region, in place; the results: its yield's
                self.copy(taken.instrs[:-1], out)
                for r, v in zip(ins.results, taken.instrs[-1].operands):
                    mapping[r] = get(v, v)
                continue
            regions = [self.clone(r) for r in ins.regions] if ins.regions else []
            c = clone_instr(ins, operands, regions, mapping)
            if c.op in _FOLDABLE:
                _fold(c)
            out.append(c)
