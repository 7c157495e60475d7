"""Parse the textual IR written by ``printer.py`` back into a :class:`Module`.

A hand-written recursive-descent parser: ``print_module(parse_module(text)) == text`` for
any printed module.  Errors raise :class:`CompileError` at the offending ``line:col`` of the
IR text (file name ``<ir>`` unless given).
"""

from __future__ import annotations

import json
import re
import struct
from dataclasses import dataclass
from typing import Any

from .diagnostics import CompileError
from .ir import (
    UNKNOWN_LOC,
    Block,
    BufferType,
    Function,
    Instr,
    Loc,
    MatType,
    Module,
    Op,
    Param,
    ScalarType,
    SpectrumType,
    StructType,
    TupleType,
    Type,
    UnpolarizedType,
    Value,
    VecType,
)

_TOKEN_RE = re.compile(
    r"""
    (?P<ws>[ \t\r]+|//[^\n]*)
  | (?P<nl>\n)
  | (?P<str>"(?:[^"\\\n]|\\.)*")
  | (?P<val>%[A-Za-z0-9_.$]+(?:\#[0-9]+)?)
  | (?P<glob>@[A-Za-z0-9_.$]+)
  | (?P<arrow>->)
  | (?P<hex>0x[0-9a-fA-F]+)
  | (?P<num>-?[0-9]+(?:\.[0-9]*)?(?:[eE][+-]?[0-9]+)?|-inf)
  | (?P<ident>[A-Za-z_][A-Za-z0-9_.]*)
  | (?P<punct>[(){}\[\],:=<>])
    """,
    re.VERBOSE,
)

_OPS = {op.value: op for op in Op}
_SCALAR_RE = re.compile(r"(f32|i32|u32|u64|bool)(?:x([0-9]+))?")


@dataclass
class Tok:
    kind: str
    text: str
    line: int
    col: int


def _tokenize(text: str, file: str) -> list[Tok]:
    toks: list[Tok] = []
    line, line_start, pos = 1, 0, 0
    while pos < len(text):
        m = _TOKEN_RE.match(text, pos)
        if m is None:
            raise CompileError(f"unexpected character {text[pos]!r} in IR",
                               Loc(file, line, pos - line_start + 1))
        kind = m.lastgroup
        if kind == "nl":
            line, line_start = line + 1, m.end()
        elif kind != "ws":
            toks.append(Tok(kind, m.group(), line, pos - line_start + 1))
        pos = m.end()
    toks.append(Tok("eof", "", line, pos - line_start + 1))
    return toks


class _Parser:
    def __init__(self, text: str, file: str) -> None:
        self.file = file
        self.toks = _tokenize(text, file)
        self.i = 0
        self.module = Module()
        # per function: textual name -> Value, and operands to patch at the end
        self.defs: dict[str, Value] = {}
        self.uses: list[tuple[Instr, int, Tok]] = []

    # ---- token helpers

    @property
    def tok(self) -> Tok:
        return self.toks[self.i]

    def error(self, msg: str, tok: Tok | None = None) -> CompileError:
        tok = tok or self.tok
        return CompileError(msg, Loc(self.file, tok.line, tok.col))

    def next(self) -> Tok:
        t = self.toks[self.i]
        self.i += 1
        return t

    def at(self, text: str) -> bool:
        return self.tok.text == text and self.tok.kind in ("punct", "ident", "arrow")

    def accept(self, text: str) -> bool:
        if self.at(text):
            self.i += 1
            return True
        return False

    def expect(self, text: str) -> Tok:
        if not self.at(text):
            raise self.error(f"expected '{text}', found {self._desc()}")
        return self.next()

    def expect_kind(self, kind: str, what: str) -> Tok:
        if self.tok.kind != kind:
            raise self.error(f"expected {what}, found {self._desc()}")
        return self.next()

    def _desc(self) -> str:
        return "end of input" if self.tok.kind == "eof" else f"'{self.tok.text}'"

    def int_(self) -> int:
        t = self.expect_kind("num", "an integer")
        if not re.fullmatch(r"-?[0-9]+", t.text):
            raise self.error("expected an integer", t)
        return int(t.text)

    # ---- module

    def module_(self) -> Module:
        if self.accept("module"):
            self.expect("attrs")
            self.module.attrs = self.value()
        while self.at("struct"):
            self.struct()
        while self.at("func"):
            fn = self.function()
            if fn.name in self.module.functions:
                raise self.error(f"duplicate function @{fn.name}")
            self.module.add(fn)
        if self.tok.kind != "eof":
            raise self.error(f"expected 'func', found {self._desc()}")
        return self.module

    def struct(self) -> None:
        self.expect("struct")
        t = self.expect_kind("val", "a struct name")
        name = t.text[1:]
        self.expect("{")
        fields = []
        while not self.at("}"):
            if fields:
                self.expect(",")
            fname = self.expect_kind("ident", "a field name").text
            self.expect(":")
            fields.append((fname, self.type_()))
        self.expect("}")
        if name in self.module.structs:
            raise self.error(f"duplicate struct %{name}", t)
        self.module.structs[name] = StructType(name, tuple(fields))

    # ---- types and values

    def type_(self) -> Type:
        t = self.tok
        if t.kind == "val":
            self.next()
            st = self.module.structs.get(t.text[1:])
            if st is None:
                raise self.error(f"unknown struct {t.text}", t)
            return st
        name = self.expect_kind("ident", "a type").text
        m = _SCALAR_RE.fullmatch(name)
        if m:
            return ScalarType(m.group(1), lanes=int(m.group(2) or 1))
        if re.fullmatch(r"vec[0-9]+", name):
            elem = ScalarType("f32")
            if self.accept("<"):
                elem = self._scalar_type()
                self.expect(">")
            return VecType(int(name[3:]), elem)
        if re.fullmatch(r"mat[0-9]+", name):
            return MatType(int(name[3:]))
        if name == "spectrum":
            return SpectrumType()
        if name == "unpolarized":
            return UnpolarizedType()
        if name == "buffer":
            self.expect("<")
            elem = self._scalar_type()
            self.expect(">")
            return BufferType(elem)
        if name == "tuple":
            self.expect("<")
            elems = []
            while not self.at(">"):
                if elems:
                    self.expect(",")
                elems.append(self.type_())
            self.expect(">")
            return TupleType(tuple(elems))
        if name == "varying":
            self.expect("<")
            lanes = self.int_()
            self.expect(",")
            inner = self.type_()
            self.expect(">")
            return inner.with_lanes(lanes)
        raise self.error(f"unknown type '{name}'", t)

    def _scalar_type(self) -> ScalarType:
        t = self.type_()
        if not isinstance(t, ScalarType):
            raise self.error(f"expected a scalar type, found {t}")
        return t

    def type_list(self) -> list[Type]:
        self.expect("(")
        ts: list[Type] = []
        while not self.at(")"):
            if ts:
                self.expect(",")
            ts.append(self.type_())
        self.expect(")")
        return ts

    def value(self) -> Any:
        t = self.next()
        if t.kind == "str":
            return json.loads(t.text)
        if t.kind == "num":
            if t.text == "-inf":
                return float("-inf")
            if re.fullmatch(r"-?[0-9]+", t.text):
                return int(t.text)
            return float(t.text)
        if t.kind == "ident":
            simple = {"true": True, "false": False, "null": None, "inf": float("inf")}
            if t.text in simple:
                return simple[t.text]
            if t.text == "nan":
                if self.accept("("):
                    bits = int(self.expect_kind("hex", "NaN bits").text, 16)
                    self.expect(")")
                    return struct.unpack("<d", struct.pack("<Q", bits))[0]
                return float("nan")
        if t.text == "[" and t.kind == "punct":
            items = []
            while not self.at("]"):
                if items:
                    self.expect(",")
                items.append(self.value())
            self.expect("]")
            return items
        if t.text == "{" and t.kind == "punct":
            d = {}
            while not self.at("}"):
                if d:
                    self.expect(",")
                k = self.expect_kind("str", "a string key")
                self.expect(":")
                d[json.loads(k.text)] = self.value()
            self.expect("}")
            return d
        raise self.error(f"expected a value, found '{t.text}'", t)

    def loc(self, default: Loc = UNKNOWN_LOC) -> Loc:
        if not self.accept("loc"):
            return default
        self.expect("(")
        file = json.loads(self.expect_kind("str", "a file name").text)
        self.expect(":")
        line = self.int_()
        self.expect(":")
        col = self.int_()
        self.expect(")")
        return Loc(file, line, col)

    # ---- functions

    def define(self, name_tok: Tok, v: Value, key: str | None = None) -> None:
        key = key or name_tok.text[1:]
        if key in self.defs:
            raise self.error(f"value %{key} is defined twice", name_tok)
        self.defs[key] = v

    def arg_value(self, tok: Tok, t: Type) -> Value:
        """A parameter or block argument: named unless it printed as a number."""
        name = tok.text[1:]
        if "#" in name:
            raise self.error(f"invalid argument name {tok.text}", tok)
        v = Value(t, None if name.isdigit() else name)
        self.define(tok, v)
        return v

    def function(self) -> Function:
        self.defs, self.uses = {}, []
        self.expect("func")
        name = self.expect_kind("glob", "a function name").text[1:]
        self.expect("(")
        params: list[Param] = []
        while not self.at(")"):
            if params:
                self.expect(",")
            uniform = self.accept("uniform")
            vt = self.expect_kind("val", "a parameter")
            self.expect(":")
            v = self.arg_value(vt, self.type_())
            default = self.value() if self.accept("=") else None
            params.append(Param(v, uniform, default))
        self.expect(")")
        self.expect("->")
        ret_types = self.type_list()
        ret_names = attrs = None
        if self.accept("ret_names"):
            ret_names = self.value()
        if self.accept("attrs"):
            attrs = self.value()
        loc = self.loc()
        self.expect("{")
        body = self.block([])
        fn = Function(name, params, ret_types, body, loc, attrs or {}, ret_names)
        for ins, i, t in self.uses:
            v = self.defs.get(t.text[1:])
            if v is None:
                raise self.error(f"use of undefined value {t.text}", t)
            ins.operands[i] = v
        return fn

    def block(self, args: list[Value]) -> Block:
        """Instructions up to and including the closing '}'."""
        block = Block(args)
        while not self.accept("}"):
            if self.tok.kind == "eof":
                raise self.error("expected '}', found end of input")
            block.instrs.append(self.instr())
        return block

    def operand(self, ins_operands: list) -> None:
        t = self.expect_kind("val", "a value")
        ins_operands.append(t)

    def instr(self) -> Instr:
        start = self.tok
        res_tok, nres = None, 0
        if start.kind == "val":
            res_tok = self.next()
            nres = 1
            if self.accept(":"):
                nres = self.int_()
            self.expect("=")
        op_tok = self.expect_kind("ident", "an instruction")
        op = _OPS.get(op_tok.text)
        if op is None:
            raise self.error(f"unknown op '{op_tok.text}'", op_tok)
        line = op_tok.line
        operands: list[Tok] = []
        attrs: dict[str, Any] = {}
        loop_args: list[Tok] = []
        if op is Op.CONST:
            if self.tok.line == line and not self.at(":") and not self.at("trait") \
                    and not self.at("loc") and not (self.at("{") and self._dict_ahead()):
                attrs["value"] = self.value()
            if self.accept("trait"):
                attrs["trait"] = json.loads(self.expect_kind("str", "a trait name").text)
        elif op is Op.CALL and self.tok.kind == "glob":
            attrs["callee"] = self.next().text[1:]
            self.expect("(")
            while not self.at(")"):
                if operands:
                    self.expect(",")
                operands.append(self.expect_kind("val", "a value"))
            self.expect(")")
        elif op is Op.LOOP:
            self.expect("(")
            while not self.at(")"):
                if loop_args:
                    self.expect(",")
                loop_args.append(self.expect_kind("val", "a loop variable"))
                self.expect("=")
                operands.append(self.expect_kind("val", "a value"))
            self.expect(")")
        elif self.tok.kind == "val" and self.tok.line == line:
            operands.append(self.next())
            while self.accept(","):
                operands.append(self.expect_kind("val", "a value"))
        if op in (Op.EXTRACT, Op.INSERT) and self.accept("["):
            attrs["index"] = self.int_()
            self.expect("]")
        if self.at("{") and self.tok.line == line and self._dict_ahead():
            attrs.update(self.value())
        types: list[Type] = []
        if self.accept(":"):
            types = self.type_list() if self.at("(") else [self.type_()]
        if len(types) != nres:
            raise self.error(f"'{op.value}' has {nres} results but {len(types)} types", op_tok)
        loc = self.loc()
        ins = Instr(op, [None] * len(operands), types, attrs, [], loc)  # type: ignore[list-item]
        regions = ins.regions
        for i, t in enumerate(operands):
            self.uses.append((ins, i, t))
        if op is Op.LOOP:
            self.expect("{")
            if len(loop_args) != len(types):
                raise self.error("loop has a different number of variables and results", op_tok)
            args = [self.arg_value(t, ty) for t, ty in zip(loop_args, types)]
            regions.append(self.block(args))
        elif op is Op.IF or (self.at("{") and self.tok.line == line):
            self.expect("{")
            regions.append(self.block([]))
            while self.accept("else"):
                self.expect("{")
                regions.append(self.block([]))
        if res_tok is not None:
            if nres == 1:
                self.define(res_tok, ins.results[0])
            else:
                base = res_tok.text[1:]
                for i, r in enumerate(ins.results):
                    self.define(res_tok, r, f"{base}#{i}")
        return ins

    def _dict_ahead(self) -> bool:
        nxt = self.toks[self.i + 1]
        return nxt.kind == "str" or nxt.text == "}"


def parse_module(text: str, file: str = "<ir>") -> Module:
    """Parse a module printed by :func:`rdsl.compiler.printer.print_module`."""
    return _Parser(text, file).module_()


__all__ = ["parse_module"]
