"""``scalarize``: split every aggregate (vector, matrix, struct, tuple) into scalars.

Expects: a lifted module (no ``spectrum`` types, no calls).

Guarantees: every value is a scalar or a buffer.  ``make``/``extract``/``insert``/
``broadcast`` of aggregates are gone; elementwise ops on aggregates became one op per leaf;
``if``/``loop`` carry and yield leaves.  Parameters of aggregate type became one parameter
per leaf named by its path (``si.p.x``), and ``Function.attrs["abi_params"]`` /
``["abi_result"]`` record the source-level structure for kernel manifests.  Leaf order is
the one of :func:`rdsl.compiler.ir_abi.type_to_json`.
"""

from __future__ import annotations

from ..diagnostics import CompileError, Diagnostic
from ..ir import (
    Block,
    BufferType,
    Builder,
    Function,
    Instr,
    MatType,
    Module,
    Op,
    Param,
    ScalarType,
    StructType,
    TupleType,
    Type,
    Value,
    VecType,
    components,
)
from ..ir_abi import leaf_types, type_to_json
from . import Pass, register

_VEC_NAMES = "xyzw"


def leaf_names(t: Type, prefix: str) -> list[str]:
    """ABI names of the leaves of ``t``: ``wo.x``, ``si.p.y``, ``ret.0``..."""
    if isinstance(t, (ScalarType, BufferType)):
        return [prefix]
    if isinstance(t, VecType):
        return [f"{prefix}.{_VEC_NAMES[i]}" for i in range(t.n)]
    if isinstance(t, MatType):
        return [f"{prefix}.m{i}{j}" for i in range(t.n) for j in range(t.n)]
    if isinstance(t, StructType):
        return [n for fname, ft in t.fields for n in leaf_names(ft, f"{prefix}.{fname}")]
    if isinstance(t, TupleType):
        return [n for i, e in enumerate(t.elems) for n in leaf_names(e, f"{prefix}.{i}")]
    raise TypeError(t)


def _leaf_count(t: Type) -> int:
    return 1 if isinstance(t, (ScalarType, BufferType)) else len(leaf_types(t))


def _leaves_of(t: Type) -> list[Type]:
    return [t] if isinstance(t, (ScalarType, BufferType)) else list(leaf_types(t))


@register
class Scalarize(Pass):
    name = "scalarize"

    def run(self, module: Module) -> None:
        for fn in module.functions.values():
            self._function(fn)

    def _function(self, fn: Function) -> None:
        env: dict[Value, list[Value]] = {}
        params: list[Param] = []
        abi_params = []
        for p in fn.params:
            t = p.value.type
            name = p.value.name or f"arg{len(abi_params)}"
            leaves = [Value(lt, ln) for lt, ln in zip(_leaves_of(t), leaf_names(t, name))]
            env[p.value] = leaves
            defaults = _split_default(p.default, len(leaves))
            for leaf, d in zip(leaves, defaults):
                params.append(Param(leaf, p.uniform, d))
            abi_params.append({"name": name, "type": type_to_json(t), "uniform": p.uniform,
                               "default": p.default, "leaves": [v.name for v in leaves]})
        ret_names: list[str] = []
        ret_types: list[Type] = []
        for i, t in enumerate(fn.ret_types):
            base = "ret" if len(fn.ret_types) == 1 else f"ret{i}"
            ret_names += leaf_names(t, base)
            ret_types += _leaves_of(t)
        result_json = type_to_json(fn.ret_types[0]) if len(fn.ret_types) == 1 else None
        fn.attrs["abi_params"] = abi_params
        fn.attrs["abi_result"] = {"type": result_json, "leaves": ret_names}
        fn.body = self._block(fn.body, env, [])
        fn.params = params
        fn.ret_types = ret_types
        fn.ret_names = ret_names

    # -- blocks ------------------------------------------------------------------------
    def _block(self, block: Block, env: dict[Value, list[Value]],
               new_args: list[Value]) -> Block:
        out = Block(new_args)
        b = Builder(out)
        for ins in block.instrs:
            b.loc = ins.loc
            self._instr(ins, b, env)
        return out

    def _instr(self, ins: Instr, b: Builder, env: dict[Value, list[Value]]) -> None:
        ops = [env[v] for v in ins.operands]
        op = ins.op
        if op is Op.IF:
            self._if(ins, b, env, ops)
            return
        if op is Op.LOOP:
            self._loop(ins, b, env, ops)
            return
        if op in (Op.YIELD, Op.RETURN):
            b.emit(op, [v for leaves in ops for v in leaves], [])
            return
        if op is Op.CALL:
            raise CompileError([Diagnostic(ins.loc, "internal: call survived inlining")])
        if op in (Op.INTERSECT, Op.OCCLUDED):  # one instruction, leaves in and leaves out
            types = [t for r in ins.results for t in _leaves_of(r.type)]
            new = b.emit(op, [v for leaves in ops for v in leaves], types, ins.attrs)
            self._bind_results(ins, new, env)
            return
        if not ins.results:  # store
            b.emit(op, [leaves[0] for leaves in ops], [], ins.attrs)
            return
        rt = ins.result.type
        if not rt.is_aggregate and all(len(x) == 1 for x in ops) and op not in (
                Op.EXTRACT, Op.MAKE):
            env[ins.result] = [b.emit(op, [x[0] for x in ops], [rt], ins.attrs).result]
            return
        env[ins.result] = self._aggregate(ins, b, ops)

    def _aggregate(self, ins: Instr, b: Builder, ops: list[list[Value]]) -> list[Value]:
        op, rt = ins.op, ins.result.type
        if op is Op.MAKE:
            return [v for leaves in ops for v in leaves]
        if op is Op.EXTRACT:
            lo, hi = _slice(ins.operands[0].type, ins.attrs["index"])
            return ops[0][lo:hi]
        if op is Op.INSERT:
            lo, hi = _slice(ins.operands[0].type, ins.attrs["index"])
            return ops[0][:lo] + ops[1] + ops[0][hi:]
        if op is Op.BROADCAST:
            return ops[0] * _leaf_count(rt)
        if op is Op.CONST:
            leaves = _leaves_of(rt)
            vals = _split_default(ins.attrs["value"], len(leaves))
            return [b.const(v, t) for v, t in zip(vals, leaves)]
        if op is Op.SELECT:
            cond = ops[0][0]
            return [b.op(Op.SELECT, a.type, cond, a, c) for a, c in zip(ops[1], ops[2])]
        # elementwise: every operand has the result's leaf count
        n = _leaf_count(rt)
        if any(len(x) != n for x in ops):
            raise CompileError([Diagnostic(ins.loc, f"internal: `{op.value}` on mismatched "
                                           "aggregates")])
        leaf_t = _leaves_of(rt)
        return [b.emit(op, [x[i] for x in ops], [leaf_t[i]], ins.attrs).result
                for i in range(n)]

    def _if(self, ins: Instr, b: Builder, env: dict[Value, list[Value]],
            ops: list[list[Value]]) -> None:
        regions = [self._block(r, env, []) for r in ins.regions]
        types = [t for r in ins.results for t in _leaves_of(r.type)]
        new = b.emit(Op.IF, [ops[0][0]], types, ins.attrs, regions)
        self._bind_results(ins, new, env)

    def _loop(self, ins: Instr, b: Builder, env: dict[Value, list[Value]],
              ops: list[list[Value]]) -> None:
        body = ins.regions[0]
        args: list[Value] = []
        for a in body.args:
            leaves = [Value(t, a.name) for t in _leaves_of(a.type)]
            env[a] = leaves
            args += leaves
        region = self._block(body, env, args)
        inits = [v for leaves in ops for v in leaves]
        new = b.emit(Op.LOOP, inits, [v.type for v in inits], ins.attrs, [region])
        self._bind_results(ins, new, env)

    @staticmethod
    def _bind_results(old: Instr, new: Instr, env: dict[Value, list[Value]]) -> None:
        i = 0
        for r in old.results:
            n = _leaf_count(r.type)
            env[r] = new.results[i:i + n]
            i += n


def _slice(t: Type, index: int) -> tuple[int, int]:
    """The leaf range of component ``index`` of aggregate ``t``."""
    comps = components(t)
    lo = sum(_leaf_count(c) for c in comps[:index])
    return lo, lo + _leaf_count(comps[index])


def _split_default(value, n: int) -> list:
    """Spread a default (scalar, or nested tuple) over ``n`` leaves."""
    if value is None:
        return [None] * n
    if isinstance(value, (list, tuple)):
        flat: list = []
        for v in value:
            flat += list(v) if isinstance(v, (list, tuple)) else [v]
        if len(flat) == n:
            return flat
        if len(flat) == 1:
            return flat * n
        raise CompileError(f"default {value!r} does not fit {n} components")
    return [value] * n
