"""``specialize(scene)``: fit the program to one scene.

Expects: a lowered module (before ``inline``) containing the scene placeholders of
``stdlib/render/scene.rdsl`` (``scene_bsdf_eval`` and friends) and the plugin functions of
every plugin type the scene uses (``diffuse.eval``...).

Guarantees: each placeholder's body is replaced by a dispatch over the plugin types the
scene's instances use (``if id == 0 || id == 2 { roughconductor.eval(...) } else {
diffuse.eval(...) }``): one call per type, whose parameters are constants, or selects of
constants by instance id when instances of a type differ.  ``optimize`` then folds what the
scene fixes (a parameter equal to 0 or 1, a branch on a flag).  Ids must be ones of the
scene's instances (the renderer guarantees it); a placeholder with no instances keeps its
own body.  Plugins the scene does not use are never called, so ``inline`` drops them.
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
        """Dispatch over the plugin *types* of ``instances``; the parameters of one type's
        instances are selected by id, so three diffuse materials cost one diffuse call."""
        if not instances:
            return  # the placeholder's own body stays
        ident, args = stub.params[0].value, [p.value for p in stub.params[1:]]
        groups: dict[str, list[int]] = {}
        for k, inst in enumerate(instances):
            groups.setdefault(inst.plugin, []).append(k)
        body = Block()
        b = Builder(body, stub.loc)
        tail: Block | None = None  # built from the last group backwards
        for plugin, ids in reversed(list(groups.items())):
            callee = module.functions.get(f"{plugin}.{method}")
            if callee is None:
                raise CompileError(f"plugin `{plugin}` has no function `{method}` "
                                   "(is its file imported?)")
            then = Block()
            tb = Builder(then, stub.loc)
            params = [self._param_value(tb, p, ident, [instances[k] for k in ids], ids)
                      for p in callee.params[len(args):]]
            call = tb.emit(Op.CALL, args + params, list(callee.ret_types),
                           {"callee": callee.name})
            tb.yield_(*call.results)
            if tail is None:
                tail = then  # the last type needs no test: ids come from the scene
                continue
            block = Block()
            bb = Builder(block, stub.loc)
            cond = None
            for k in ids:
                c = bb.op(Op.EQ, BOOL, ident, bb.const(k, I32))
                cond = c if cond is None else bb.op(Op.OR, BOOL, cond, c)
            res = bb.emit(Op.IF, [cond], list(stub.ret_types), regions=[then, tail])
            bb.yield_(*res.results)
            tail = block
        assert tail is not None
        body.instrs = tail.instrs
        last = body.instrs.pop()
        body.instrs.append(Instr(Op.RETURN, last.operands, [], loc=last.loc))
        stub.body = body

    def _param_value(self, b: Builder, p: Param, ident: Value, group: list[Instance],
                     ids: list[int]) -> Value:
        """The parameter's constant, or a select over the group's instances by id."""
        name = p.value.name or "?"
        values = []
        for inst in group:
            value = inst.params.get(name, p.default)
            if value is None:
                raise CompileError(f"{inst.name or inst.plugin}: parameter `{name}` of "
                                   f"`{inst.plugin}` has no value and no default")
            values.append(value)
        what = f"{group[0].plugin}.{name}"
        out = _constant(b, p.value.type, values[-1], what)
        for k, value in zip(reversed(ids[:-1]), reversed(values[:-1])):
            if value == values[-1]:
                continue
            c = b.op(Op.EQ, BOOL, ident, b.const(k, I32))
            out = b.op(Op.SELECT, p.value.type, c, _constant(b, p.value.type, value, what), out)
        return out


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
