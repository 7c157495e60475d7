"""``inline``: replace every call by the callee's body.

Expects: a verified module straight from lowering, with ``call`` ops naming functions in the
module, and function bodies whose only ``return`` is the last instruction of the body (the
frontend turns early returns into flags).

Guarantees: exported functions contain no ``call``; only exported functions remain (the
library functions they used have been copied into them).  Recursion, direct or mutual, is a
diagnostic at the call site that closes the cycle.

``Inline(keep=evaluable)`` (the first of the pipeline's two) leaves the calls to the functions
``keep(module)`` names, and those of them still called, for ``evaluate`` to fold; their own
bodies are inlined all the same.
"""

from __future__ import annotations

from collections.abc import Callable

from ..diagnostics import CompileError, Diagnostic
from ..ir import Block, Function, Instr, Module, Op, Value, clone_block
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
        the caller is renamed when reached (the inlined copies hold none of the results)."""
        out: list[Instr] = []
        for ins in block.instrs:
            for region in ins.regions:
                self._inline_block(region, mapping)
            if mapping:
                ins.operands = [mapping.get(v, v) for v in ins.operands]
            if ins.op is not Op.CALL:
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
            local = {p.value: a for p, a in zip(callee.params, args)}
            body = clone_block(callee.body, local)
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
