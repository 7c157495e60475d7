"""``evaluate``: compile-time evaluation of pure calls whose arguments are constants.

Expects: a module after ``specialize`` and a first ``inline(keep=evaluable)``, so that the
only calls left are to the functions :func:`evaluable` picked (pure, free of ``Spectrum``
and buffers, and running a loop), and after an ``optimize``, so that arguments the scene
fixes (a roughness, an IOR and what the program computes from them) are ``const``.

Guarantees: each such call whose arguments are all ``const`` is replaced by ``const``
results holding the values the reference interpreter (:mod:`rdsl.compiler.interp`, the
exact f32 semantics of the compiled code) computes for it.  A call with a non-constant
argument, or whose evaluation takes more than ``step_limit`` interpreter steps or an op the
interpreter lacks, stays a call for the next ``inline``.  Only calls with scalar results
are folded (a call with several scalar results gets one ``const`` each).  The
callees themselves are left in place; the next ``inline`` and ``optimize`` drop them.

Functions without a loop are not picked: ``optimize`` folds their inlined bodies with the
same semantics, so this pass only does what ``optimize`` cannot, run a loop (a quadrature,
a Newton iteration) once per scene instead of once per sample.
"""

from __future__ import annotations

from typing import Any

from ..interp import InterpError, run_function
from ..ir import (
    PURE_OPS,
    Block,
    BufferType,
    Instr,
    Module,
    Op,
    ScalarType,
    SpectrumType,
    Type,
    Value,
    components,
    replace_uses,
)
from . import Pass, register

STEP_LIMIT = 2_000_000  # about a second of interpreter time
_CONTROL = {Op.IF, Op.LOOP, Op.YIELD, Op.RETURN, Op.CALL}


def _plain(t: Type) -> bool:
    """Whether the interpreter takes values of type ``t`` (no spectra, no buffers)."""
    if isinstance(t, (SpectrumType, BufferType)):
        return False
    return isinstance(t, ScalarType) or all(_plain(c) for c in components(t))


def evaluable(module: Module) -> set[str]:
    """The functions whose calls ``evaluate`` may fold: pure (only pure ops, control flow and
    calls to such functions), with plain parameter and result types, that run a loop
    themselves or through a callee."""
    pure: dict[str, bool] = {}
    loops: dict[str, bool] = {}
    return {name for name in module.functions
            if _pure(module, name, (), pure, loops) and loops[name]}


def _pure(module: Module, name: str, stack: tuple[str, ...], pure: dict[str, bool],
          loops: dict[str, bool]) -> bool:
    """Whether function ``name`` is pure (memoized in ``pure``; ``loops``: whether it runs
    a loop).  A function, not a recursive closure: that would be a reference cycle holding
    the module until Python's cycle collector ran."""
    if name in pure:
        return pure[name]
    fn = module.functions.get(name)
    if fn is None or name in stack:  # unknown or recursive: `inline` reports it
        return False
    ok = all(_plain(p.value.type) for p in fn.params) and all(map(_plain, fn.ret_types))
    has_loop = False
    for ins in fn.walk():
        if not ok:
            break
        if ins.op is Op.CALL:
            callee = ins.attrs["callee"]
            ok = _pure(module, callee, (*stack, name), pure, loops)
            has_loop = has_loop or loops.get(callee, False)
            continue
        ok = (ins.op in PURE_OPS or ins.op in _CONTROL) and all(
            _plain(r.type) for r in ins.results)
        has_loop = has_loop or ins.op is Op.LOOP
    pure[name], loops[name] = ok, has_loop
    return ok


@register
class Evaluate(Pass):
    name = "evaluate"

    def __init__(self, step_limit: int = STEP_LIMIT, report: list[str] | None = None) -> None:
        self.step_limit = step_limit
        self.report = report

    def run(self, module: Module) -> None:
        folded = 0
        for fn in module.functions.values():
            mapping: dict[Value, Value] = {}
            folded += self._fold_block(module, fn.body, mapping)
            replace_uses(fn.body, mapping)
        if self.report is not None and folded:
            self.report.append(f"evaluate: {folded} call(s) evaluated at compile time")

    def _fold_block(self, module: Module, block: Block, mapping: dict[Value, Value]) -> int:
        """Fold the foldable calls of ``block`` (and its regions); their results map to the
        new constants in ``mapping``."""
        folded = 0
        out: list[Instr] = []
        for ins in block.instrs:
            for region in ins.regions:
                folded += self._fold_block(module, region, mapping)
            values = self._evaluate(module, ins, mapping)
            if values is None:
                out.append(ins)
                continue
            for r, v in zip(ins.results, values):
                c = Instr(Op.CONST, [], [r.type], {"value": v.item() if hasattr(v, "item")
                                                   else v}, None, ins.loc)
                out.append(c)
                mapping[r] = c.result
            folded += 1
        block.instrs = out
        return folded

    def _evaluate(self, module: Module, ins: Instr, mapping: dict[Value, Value]
                  ) -> list[Any] | None:
        """The results of call ``ins`` if it can be folded, else None."""
        if ins.op is not Op.CALL or not all(isinstance(r.type, ScalarType)
                                              for r in ins.results):
            return None
        args = []
        for v in ins.operands:
            owner = mapping.get(v, v).owner
            if not isinstance(owner, Instr) or owner.op is not Op.CONST \
                    or "value" not in owner.attrs:
                return None
            args.append(owner.attrs["value"])
        try:
            return run_function(module, ins.attrs["callee"], args, self.step_limit)
        except InterpError:
            return None  # too long, or an op the interpreter lacks: computed at run time
