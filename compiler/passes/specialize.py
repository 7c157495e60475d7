"""``specialize(scene)``: fit the program to one scene.

Expects: a lowered module (before ``inline``) containing the scene placeholders of
``stdlib/render/scene.rdsl`` (``scene_bsdf_eval`` and friends) and the plugin functions of
every plugin type the scene uses (``diffuse.eval``...).

Guarantees: each placeholder's body is replaced by a dispatch over the scene's instances
only (``if id == 0 { diffuse.eval(..., consts) } else if id == 1 { ... }``), falling
through to the placeholder's own body for an unknown id.  Every instance parameter becomes
a constant, so ``optimize`` folds what the scene fixes (a parameter equal to 0 or 1, a branch
on a flag).  Plugins the scene does not use are never called, so ``inline`` drops them.
``report`` collects what was specialized, for ``rdsl render --report``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ..diagnostics import CompileError
from ..ir import (BOOL, F32, I32, Block, Builder, Function, Instr, Module, Op, Param,
                  ScalarType, SpectrumType, Type, Value, VecType)
from . import Pass, register

# placeholder function -> (instance list, plugin method)
PLACEHOLDERS = {
    "scene_bsdf_eval": ("bsdfs", "eval"),
    "scene_bsdf_pdf": ("bsdfs", "pdf"),
    "scene_bsdf_sample": ("bsdfs", "sample"),
    "scene_emitter_eval": ("emitters", "eval"),
}


@dataclass
class Instance:
    """One plugin instance of the scene: its plugin type and parameter values (floats,
    ints, bools, or tuples for colors and vectors).  Missing parameters take the plugin's
    defaults."""

    plugin: str
    params: dict[str, Any] = field(default_factory=dict)
    name: str = ""


@dataclass
class SceneSpec:
    """What ``specialize`` needs to know about a scene."""

    bsdfs: list[Instance] = field(default_factory=list)
    emitters: list[Instance] = field(default_factory=list)


def describe(scene: SceneSpec, placeholders: list[str] | None = None) -> list[str]:
    """One line per placeholder: which instances its dispatch covers."""
    out = []
    for name in placeholders if placeholders is not None else list(PLACEHOLDERS):
        kind, _ = PLACEHOLDERS[name]
        instances: list[Instance] = getattr(scene, kind)
        used = sorted({i.plugin for i in instances})
        out.append(f"{name}: {len(instances)} instance(s) of {', '.join(used) or 'nothing'}")
    return out


@register
class Specialize(Pass):
    name = "specialize"

    def __init__(self, scene: SceneSpec | None = None, report: list[str] | None = None) -> None:
        self.scene = scene or SceneSpec()
        self.report = report if report is not None else []

    def run(self, module: Module) -> None:
        for stub_name, (kind, method) in PLACEHOLDERS.items():
            stub = module.functions.get(stub_name)
            if stub is None:
                continue
            self._dispatch(module, stub, getattr(self.scene, kind), method)
        self.report.extend(describe(self.scene, [n for n in PLACEHOLDERS
                                                 if n in module.functions]))

    def _dispatch(self, module: Module, stub: Function, instances: list[Instance],
                  method: str) -> None:
        ident, args = stub.params[0].value, [p.value for p in stub.params[1:]]
        fallback = stub.body
        ret = fallback.instrs.pop()
        fallback.instrs.append(Instr(Op.YIELD, ret.operands, [], loc=ret.loc))
        tail = fallback
        for k in reversed(range(len(instances))):
            inst = instances[k]
            callee = module.functions.get(f"{inst.plugin}.{method}")
            if callee is None:
                raise CompileError(f"plugin `{inst.plugin}` has no function `{method}` "
                                   "(is its file imported?)")
            then = Block()
            tb = Builder(then, stub.loc)
            consts = [self._param_value(tb, p, inst) for p in callee.params[len(args):]]
            call = tb.emit(Op.CALL, args + consts, list(callee.ret_types),
                           {"callee": callee.name})
            tb.yield_(*call.results)
            block = Block()
            bb = Builder(block, stub.loc)
            cond = bb.op(Op.EQ, BOOL, ident, bb.const(k, I32))
            res = bb.emit(Op.IF, [cond], list(stub.ret_types), regions=[then, tail])
            bb.yield_(*res.results)
            tail = block
        last = tail.instrs.pop()
        tail.instrs.append(Instr(Op.RETURN, last.operands, [], loc=last.loc))
        stub.body = tail

    def _param_value(self, b: Builder, p: Param, inst: Instance) -> Value:
        name = p.value.name or "?"
        value = inst.params.get(name, p.default)
        if value is None:
            raise CompileError(f"{inst.name or inst.plugin}: parameter `{name}` of "
                               f"`{inst.plugin}` has no value and no default")
        return _constant(b, p.value.type, value, f"{inst.plugin}.{name}")


def _constant(b: Builder, t: Type, value: Any, what: str) -> Value:
    """Build ``value`` as IR constants of type ``t`` (before lifting)."""
    if isinstance(t, ScalarType):
        if isinstance(value, (tuple, list)):
            raise CompileError(f"{what}: expected a single value, got {value!r}")
        py = {"f32": float, "i32": int, "u32": int, "u64": int, "bool": bool}[t.name]
        return b.const(py(value), t)
    if isinstance(t, SpectrumType):
        if isinstance(value, (tuple, list)):
            if len(value) == 1:
                value = value[0]
            elif len(value) == 3:
                return b.op(Op.SPEC_RGB, t, *[b.const(float(v), F32) for v in value])
            else:
                raise CompileError(f"{what}: expected 1 or 3 values, got {len(value)}")
        return b.op(Op.BROADCAST, t, b.const(float(value), F32))
    if isinstance(t, VecType):
        vals = list(value) if isinstance(value, (tuple, list)) else [value] * t.n
        if len(vals) != t.n:
            raise CompileError(f"{what}: expected {t.n} values, got {len(vals)}")
        return b.op(Op.MAKE, t, *[b.const(float(v), F32) for v in vals])
    raise CompileError(f"{what}: parameters of type `{t}` cannot be set from a scene yet")
