"""The textual form of the IR (see ``docs/ir.md``); ``irparse.py`` is its exact inverse.

Output is deterministic so that golden files are stable: values are numbered per function in
order of definition (``%0, %1, ...``; an instruction with several results is ``%4:2`` and
its results are used as ``%4#0, %4#1``).  Parameters and loop-carried block arguments print
by name (``%alpha``) when they have a name that is unique in the function.

Attribute values (constants, defaults, ``attrs {...}``) use JSON extended with ``inf``,
``-inf``, ``nan`` and ``nan(0x<f64 bits>)``; floats always print with a ``.``/``e`` (Python
``repr``) so that ints and floats stay distinct.
"""

from __future__ import annotations

import json
import math
import re
import struct
from collections import Counter
from typing import Any

import numpy as np

from .ir import (
    UNKNOWN_LOC,
    Block,
    Function,
    Instr,
    Loc,
    Module,
    Op,
    ScalarType,
    StructType,
    TupleType,
    Type,
    Value,
)

NAME_RE = re.compile(r"[A-Za-z_][A-Za-z0-9_.$]*")
_CANONICAL_NAN = 0x7FF8_0000_0000_0000

# --------------------------------------------------------------------------------------
# Types and attribute values


def type_str(t: Type) -> str:
    """``str(t)``, except that a varying aggregate (which ``str`` can't show) prints as
    ``varying<W, T>``."""
    if t.lanes != 1 and not isinstance(t, ScalarType):
        return f"varying<{t.lanes}, {t.with_lanes(1)}>"
    return str(t)


def types_str(ts: list[Type]) -> str:
    return "(" + ", ".join(type_str(t) for t in ts) + ")"


def float_str(x: float) -> str:
    if math.isnan(x):
        bits = struct.unpack("<Q", struct.pack("<d", x))[0]
        return "nan" if bits == _CANONICAL_NAN else f"nan(0x{bits:016x})"
    return repr(x)  # 'inf', '-inf', or always with '.' or 'e'


def value_str(v: Any) -> str:
    """An attribute value: bool, int, float, str, None, list/tuple, dict (nested)."""
    if v is None:
        return "null"
    if isinstance(v, (bool, np.bool_)):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return float_str(float(v))
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(value_str(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{json.dumps(str(k))}: {value_str(x)}" for k, x in v.items()) + "}"
    return json.dumps(repr(v))


def loc_str(loc: Loc) -> str:
    return f"loc({json.dumps(loc.file)}:{loc.line}:{loc.col})"


# --------------------------------------------------------------------------------------
# Value naming


def _walk_defs(block: Block):
    """(kind, value-or-instr) for every definition in a block, in textual order."""
    for a in block.args:
        yield "arg", a
    for ins in block.instrs:
        if ins.results:
            yield "instr", ins
        for r in ins.regions:
            yield from _walk_defs(r)


class Namer:
    """The printed name (without ``%``) of every value of one function."""

    def __init__(self, fn: Function) -> None:
        self.names: dict[Value, str] = {}
        self.next = 0
        counts = Counter(p.value.name for p in fn.params)
        for kind, d in _walk_defs(fn.body):
            if kind == "arg":
                counts[d.name] += 1
        self._unique = {n for n, c in counts.items()
                        if n is not None and c == 1 and NAME_RE.fullmatch(n)}
        for p in fn.params:
            self._name_arg(p.value)
        for kind, d in _walk_defs(fn.body):
            if kind == "arg":
                self._name_arg(d)
            else:
                self._name_results(d)

    def _name_arg(self, v: Value) -> None:
        if v.name in self._unique:
            self.names[v] = v.name
        else:
            self.names[v] = str(self.next)
            self.next += 1

    def _name_results(self, ins: Instr) -> None:
        n = str(self.next)
        self.next += 1
        if len(ins.results) == 1:
            self.names[ins.results[0]] = n
        else:
            for i, r in enumerate(ins.results):
                self.names[r] = f"{n}#{i}"

    def __call__(self, v: Value) -> str:
        if v not in self.names:  # not defined in this function (invalid IR)
            self.names[v] = str(self.next)
            self.next += 1
        return "%" + self.names[v]


# --------------------------------------------------------------------------------------
# Printing


class _Printer:
    def __init__(self, fn: Function, locs: bool) -> None:
        self.fn = fn
        self.locs = locs
        self.name = Namer(fn)
        self.lines: list[str] = []

    def loc(self, loc: Loc) -> str:
        return f" {loc_str(loc)}" if self.locs and loc != UNKNOWN_LOC else ""

    def header(self) -> str:
        fn = self.fn
        params = []
        for p in fn.params:
            s = ("uniform " if p.uniform else "") + f"{self.name(p.value)}: {type_str(p.value.type)}"
            if p.default is not None:
                s += f" = {value_str(p.default)}"
            params.append(s)
        s = f"func @{fn.name}(" + ", ".join(params) + f") -> {types_str(fn.ret_types)}"
        if fn.ret_names is not None:
            s += f" ret_names {value_str(fn.ret_names)}"
        if fn.attrs:
            s += f" attrs {value_str(fn.attrs)}"
        return s + self.loc(fn.loc) + " {"

    def block(self, block: Block, depth: int) -> None:
        for ins in block.instrs:
            self.instr(ins, depth)

    def instr(self, ins: Instr, depth: int) -> None:
        ind = "  " * depth
        res = ""
        if len(ins.results) == 1:
            res = f"{self.name(ins.results[0])} = "
        elif ins.results:
            res = f"{self.name(ins.results[0]).split('#')[0]}:{len(ins.results)} = "
        attrs = dict(ins.attrs)
        s = ins.op.value
        ops = [self.name(v) for v in ins.operands]
        if ins.op is Op.CONST:
            if "value" in attrs:
                s += " " + value_str(attrs.pop("value"))
            if isinstance(attrs.get("trait"), str):
                s += " trait " + json.dumps(attrs.pop("trait"))
        elif ins.op is Op.CALL and isinstance(attrs.get("callee"), str):
            s += f" @{attrs.pop('callee')}(" + ", ".join(ops) + ")"
            ops = []
        elif ins.op is Op.LOOP:
            args = ins.regions[0].args if ins.regions else []
            pairs = [f"{self.name(a)} = {o}" for a, o in zip(args, ops)]
            s += "(" + ", ".join(pairs) + ")"
            ops = []
        if ops:
            s += " " + ", ".join(ops)
        if ins.op in (Op.EXTRACT, Op.INSERT) and _is_int(attrs.get("index")):
            s += f" [{int(attrs.pop('index'))}]"
        if attrs:
            s += " " + value_str(attrs)
        types = [r.type for r in ins.results]
        if ins.op in (Op.IF, Op.LOOP):
            s += " : " + types_str(types)
        elif len(types) == 1:
            s += " : " + type_str(types[0])
        elif types:
            s += " : " + types_str(types)
        s += self.loc(ins.loc)
        if not ins.regions:
            self.lines.append(ind + res + s)
            return
        self.lines.append(ind + res + s + " {")
        for i, r in enumerate(ins.regions):
            if i:
                self.lines.append(ind + "} else {")
            self.block(r, depth + 1)
        self.lines.append(ind + "}")


def _is_int(v: Any) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))


def print_function(fn: Function, locs: bool = True) -> str:
    """The textual form of one function (ends with a newline)."""
    p = _Printer(fn, locs)
    p.lines.append(p.header())
    p.block(fn.body, 1)
    p.lines.append("}")
    return "\n".join(p.lines) + "\n"


def _all_structs(m: Module) -> list[StructType]:
    """Module structs plus any struct type used in the functions, dependencies first."""
    found: dict[str, StructType] = {}

    def visit(t: Type) -> None:
        if isinstance(t, StructType):
            if t.name in found:
                return
            for _, ft in t.fields:
                visit(ft)
            found[t.name] = t.with_lanes(1)
        elif isinstance(t, TupleType):
            for e in t.elems:
                visit(e)
        elif hasattr(t, "elem") and isinstance(t.elem, Type):
            visit(t.elem)

    for st in m.structs.values():
        visit(st)
    for fn in m.functions.values():
        for p in fn.params:
            visit(p.value.type)
        for t in fn.ret_types:
            visit(t)
        for kind, d in _walk_defs(fn.body):
            for v in [d] if kind == "arg" else d.results:
                visit(v.type)
    return list(found.values())


def print_struct(st: StructType) -> str:
    fields = ", ".join(f"{n}: {type_str(t)}" for n, t in st.fields)
    return f"struct %{st.name} {{ {fields} }}" if fields else f"struct %{st.name} {{}}"


def print_module(m: Module, locs: bool = True) -> str:
    """The textual form of a module: module attrs, struct definitions, then functions."""
    parts = []
    if m.attrs:
        parts.append(f"module attrs {value_str(m.attrs)}\n")
    structs = _all_structs(m)
    if structs:
        parts.append("".join(print_struct(st) + "\n" for st in structs))
    parts.extend(print_function(fn, locs) for fn in m.functions.values())
    return "\n".join(parts)


__all__ = ["Namer", "print_function", "print_module", "type_str", "value_str"]
