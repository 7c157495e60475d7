"""Name resolution, imports, type checking, overload resolution and plugin interface checks.

:func:`check_program` loads the implicit prelude (``stdlib/types.rdsl``, ``stdlib/math.rdsl``),
the main file and everything it imports, and returns a :class:`CheckedProgram`.  The AST is
annotated in place (``Expr.ty``, ``Name.sym``, ``Call.target``, implicit :class:`ast.Convert`
nodes) so that :mod:`rdsl.dsl.lower` needs no type logic of its own.

Semantic types are the IR types of :mod:`rdsl.compiler.ir` (``F32``, ``VecType(3)``,
``StructType``...) plus :data:`TEXTURE` for texture params.  Void is ``None``.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..compiler.diagnostics import CompileError, Diagnostic
from ..compiler.ir import (
    BOOL,
    F32,
    I32,
    SPECTRUM,
    U32,
    U64,
    BufferType,
    Loc,
    MatType,
    ScalarType,
    SpectrumType,
    StructType,
    TupleType,
    Type,
    VecType,
)
from . import ast as A
from .parser import parse

STDLIB = Path(__file__).resolve().parent.parent / "stdlib"


@dataclass(frozen=True)
class TextureType(Type):
    """The type of a ``Texture`` plugin param (an IR ``spectrum`` once lowered)."""

    def with_lanes(self, lanes: int) -> TextureType:
        return self

    def __str__(self) -> str:
        return "texture"


TEXTURE = TextureType()

BUILTIN_TYPES: dict[str, Type] = {
    "Float": F32, "Int": I32, "UInt": U32, "UInt64": U64, "Bool": BOOL,
    "Vec2": VecType(2), "Vec3": VecType(3), "Vec4": VecType(4), "Mat3": MatType(3),
    "Mat4": MatType(4), "Spectrum": SPECTRUM, "Texture": TEXTURE,
}
_SCALAR_NAMES = {"f32": "Float", "i32": "Int", "u32": "UInt", "u64": "UInt64", "bool": "Bool"}
TRAITS = ("mono", "rgb", "spectral", "polarized")

PLUGIN_INTERFACES: dict[str, list[tuple[str, list[tuple[str, str]], str]]] = {
    "bsdf": [("eval", [("si", "Surface"), ("wo", "Vec3")], "Spectrum"),
             ("pdf", [("si", "Surface"), ("wo", "Vec3")], "Float"),
             ("sample", [("si", "Surface"), ("u1", "Float"), ("u2", "Vec2")], "BsdfSample")],
    "emitter": [("eval", [("si", "Surface")], "Spectrum"),
                ("sample", [("p", "Vec3"), ("u", "Vec2")], "EmitterSample"),
                ("pdf", [("p", "Vec3"), ("y", "Vec3"), ("n", "Vec3")], "Float")],
    "texture": [("eval", [("si", "Surface")], "Spectrum")],
    "integrator": [("li", [("ray", "Ray"), ("seed", "UInt")], "Spectrum")],
}


def type_name(t: Type | None) -> str:
    """The source spelling of a type, for messages."""
    if t is None:
        return "()"
    if isinstance(t, ScalarType):
        return _SCALAR_NAMES[t.name]
    if isinstance(t, VecType):
        return f"Vec{t.n}"
    if isinstance(t, MatType):
        return f"Mat{t.n}"
    if isinstance(t, SpectrumType):
        return "Spectrum"
    if isinstance(t, TextureType):
        return "Texture"
    if isinstance(t, StructType):
        return t.name
    if isinstance(t, TupleType):
        return "(" + ", ".join(type_name(e) for e in t.elems) + ")"
    if isinstance(t, BufferType):
        return f"[{type_name(t.elem)}]"
    return str(t)


def _q(t: Type | None) -> str:
    return f"`{type_name(t)}`"


def err(message: str, loc: Loc | None) -> CompileError:
    return CompileError([Diagnostic(loc, message)])


def is_float_agg(t: Type | None) -> bool:
    return (isinstance(t, VecType) and t.elem == F32) or isinstance(t, (SpectrumType, MatType))


def is_int_scalar(t: Type | None) -> bool:
    return isinstance(t, ScalarType) and t.is_int


def is_numeric(t: Type | None) -> bool:
    return (isinstance(t, ScalarType) and t != BOOL) or is_float_agg(t)


def is_int_literal(e: A.Expr) -> bool:
    """An unsuffixed integer literal, possibly negated: convertible to Float/UInt/UInt64."""
    if isinstance(e, A.IntLit):
        return e.suffix == ""
    return isinstance(e, A.Unary) and e.op == "-" and is_int_literal(e.operand)


def _retype_literal(e: A.Expr, t: Type) -> None:
    e.ty = t
    if isinstance(e, A.Unary):
        _retype_literal(e.operand, t)


def mangle(t: Type) -> str:
    """A C-identifier-safe spelling of a type for overloaded function names."""
    if isinstance(t, ScalarType):
        return t.name
    if isinstance(t, VecType):
        return f"vec{t.n}"
    if isinstance(t, MatType):
        return f"mat{t.n}"
    if isinstance(t, SpectrumType):
        return "spectrum"
    if isinstance(t, StructType):
        return t.name
    if isinstance(t, TupleType):
        return "tup" + "".join("_" + mangle(e) for e in t.elems) + "_end"
    if isinstance(t, BufferType):
        return "buf" + t.elem.name
    return "t"


# --------------------------------------------------------------------------------------
# Program entities


@dataclass(eq=False)
class Symbol:
    """A local name: ``let``/``var`` binding, parameter, plugin param or loop variable."""

    name: str
    type: Type
    kind: str  # "let" | "var" | "param" | "plugin_param" | "loop"
    loc: Loc

    def __repr__(self) -> str:
        return f"<{self.kind} {self.name}: {type_name(self.type)}>"


@dataclass(eq=False)
class ModuleInfo:
    """One loaded source file."""

    key: str
    program: A.Program
    is_main: bool = False
    prelude: bool = False


@dataclass(eq=False)
class FnInfo:
    """A checked function (top-level or plugin member)."""

    name: str
    decl: A.FnDecl
    params: list[Symbol]
    ret: Type | None
    module: ModuleInfo
    plugin: PluginInfo | None = None
    ir_name: str = ""

    @property
    def param_types(self) -> list[Type]:
        return [p.type for p in self.params]

    def signature(self) -> str:
        args = ", ".join(type_name(t) for t in self.param_types)
        ret = f" -> {type_name(self.ret)}" if self.ret is not None else ""
        return f"{self.name}({args}){ret}"


@dataclass(eq=False)
class PluginInfo:
    """A checked plugin: its params (with python default values) and functions."""

    kind: str
    name: str
    decl: A.PluginDecl
    module: ModuleInfo
    params: list[Symbol] = field(default_factory=list)
    defaults: list[Any] = field(default_factory=list)
    fns: dict[str, FnInfo] = field(default_factory=dict)


@dataclass
class CheckedProgram:
    """The result of :func:`check_program`: typed AST plus resolved entities."""

    main_file: str
    modules: list[ModuleInfo]
    structs: dict[str, StructType]
    functions: list[FnInfo]  # top-level functions of every module
    plugins: list[PluginInfo]


# --------------------------------------------------------------------------------------
# Loading


class _Loader:
    """Parses the main file and, depth first, everything it imports."""

    def __init__(self, search_paths: list[Path]) -> None:
        self.search_paths = search_paths
        self.modules: dict[str, ModuleInfo] = {}
        self.order: list[ModuleInfo] = []
        self.stack: list[str] = []

    def load_path(self, path: Path, is_main: bool = False) -> ModuleInfo:
        key = str(path.resolve())
        try:
            text = path.read_text()
        except (OSError, UnicodeDecodeError) as e:
            raise err(f"cannot read `{path}`: {e}", None) from None
        return self.load_text(text, str(path), key, is_main)

    def load_text(self, text: str, filename: str, key: str, is_main: bool) -> ModuleInfo:
        if key in self.modules:
            mod = self.modules[key]
            mod.is_main = mod.is_main or is_main
            return mod
        prog = parse(text, filename)
        mod = ModuleInfo(key, prog, is_main)
        self.stack.append(key)
        for imp in prog.imports:
            self._import(imp, filename)
        self.stack.pop()
        self.modules[key] = mod
        self.order.append(mod)
        return mod

    def _import(self, imp: A.Import, importer: str) -> None:
        rel = Path(*imp.path).with_suffix(".rdsl")
        dirs: list[Path] = []
        if not importer.startswith("<"):
            dirs.append(Path(importer).parent)
        dirs += self.search_paths + [STDLIB]
        for d in dirs:
            cand = d / rel
            if cand.is_file():
                key = str(cand.resolve())
                if key in self.stack:
                    cycle = self.stack[self.stack.index(key):] + [key]
                    names = " -> ".join(Path(k).name for k in cycle)
                    raise err(f"import cycle: {names}", imp.loc)
                if key not in self.modules:
                    self.load_path(cand)
                return
        name = ".".join(imp.path)
        raise err(f"cannot find module `{name}` (looked for `{rel.as_posix()}` next to "
                  f"the importing file and in the stdlib)", imp.loc)



def _prelude() -> list[Path]:
    """The implicitly imported stdlib files."""
    types = STDLIB / "types.rdsl"
    math = STDLIB / "math.rdsl"
    # Both are part of the package; a broken prelude is an rdsl bug, and it is reported as
    # a diagnostic in the prelude file rather than skipped, so nothing half-works silently.
    return [p for p in (types, math) if p.is_file()]


def check_program(source: str, filename: str, search_paths: list[Path] | None = None,
                  path: Path | None = None) -> CheckedProgram:
    """Load the prelude, the main file (text ``source``) and its imports; check everything."""
    loader = _Loader([Path(p) for p in (search_paths or [])])
    for p in _prelude():
        loader.load_path(p).prelude = True
    key = str(path.resolve()) if path is not None else f"<main>{filename}"
    loader.load_text(source, filename, key, is_main=True)
    return _Checker(loader.order, filename).run()


# --------------------------------------------------------------------------------------
# Checking


class _Scope:
    def __init__(self, parent: _Scope | None = None) -> None:
        self.parent = parent
        self.vars: dict[str, Symbol] = {}

    def lookup(self, name: str) -> Symbol | None:
        s: _Scope | None = self
        while s is not None:
            if name in s.vars:
                return s.vars[name]
            s = s.parent
        return None


@dataclass
class _FnCtx:
    fn: FnInfo
    loops: int = 0


BUILTIN_FNS = {
    "sqrt", "floor", "ceil", "abs", "min", "max", "select", "bits", "from_bits", "Float", "Int",
    "UInt", "UInt64", "Bool", "Vec2", "Vec3", "Vec4", "Mat3", "Mat4", "Spectrum", "mean",
    "max_value", "intersect", "occluded",
}
_ARITH_VERB = {"+": "add", "-": "subtract", "*": "multiply", "/": "divide", "%": "take the "
               "remainder of"}


class _Checker:
    def __init__(self, modules: list[ModuleInfo], main_file: str) -> None:
        self.modules = modules
        self.main_file = main_file
        self.struct_decls: dict[str, tuple[A.StructDecl, ModuleInfo]] = {}
        self.structs: dict[str, StructType] = {}
        self.overloads: dict[str, list[FnInfo]] = {}
        self.functions: list[FnInfo] = []
        self.plugins: list[PluginInfo] = []
        self.calls: dict[FnInfo, list[tuple[FnInfo, Loc]]] = {}
        self.ctx: _FnCtx | None = None

    # ---------------------------------------------------------------- top level
    def run(self) -> CheckedProgram:
        for mod in self.modules:
            for sd in mod.program.structs:
                if sd.name in BUILTIN_TYPES:
                    raise err(f"`{sd.name}` is a builtin type and cannot be redefined", sd.loc)
                if sd.name in self.struct_decls:
                    raise err(f"duplicate definition of struct `{sd.name}` (first defined at "
                              f"{self.struct_decls[sd.name][0].loc})", sd.loc)
                self.struct_decls[sd.name] = (sd, mod)
        for name in self.struct_decls:
            self._struct(name, [])
        for mod in self.modules:
            for fd in mod.program.fns:
                self._declare_fn(fd, mod)
        for name, fns in self.overloads.items():
            # A kernel keeps its source name when the main file defines it once; library
            # overloads beside it are mangled.
            mains = [f for f in fns if f.module.is_main]
            for fn in fns:
                plain = len(fns) == 1 or (len(mains) == 1 and fn is mains[0])
                fn.ir_name = name if plain else (
                    f"{name}__" + ("_".join(mangle(t) for t in fn.param_types) or "void"))
        seen_plugins: dict[str, A.PluginDecl] = {}
        for mod in self.modules:
            for pd in mod.program.plugins:
                if pd.name in seen_plugins:
                    raise err(f"duplicate definition of plugin `{pd.name}` (first defined at "
                              f"{seen_plugins[pd.name].loc})", pd.loc)
                seen_plugins[pd.name] = pd
                self.plugins.append(self._declare_plugin(pd, mod))
        for fn in self.functions:
            self._check_fn(fn, None)
        for pl in self.plugins:
            for fn in pl.fns.values():
                self._check_fn(fn, pl)
        self._check_recursion()
        return CheckedProgram(self.main_file, self.modules, self.structs, self.functions,
                              self.plugins)

    def _struct(self, name: str, stack: list[str]) -> StructType:
        if name in self.structs:
            return self.structs[name]
        sd, _ = self.struct_decls[name]
        if name in stack:
            raise err(f"struct `{name}` contains itself", sd.loc)
        fields: list[tuple[str, Type]] = []
        seen: set[str] = set()
        for f in sd.fields:
            if f.name in seen:
                raise err(f"duplicate field `{f.name}` in struct `{name}`", f.loc)
            seen.add(f.name)
            fields.append((f.name, self._type(f.type, "field", stack + [name])))
        st = StructType(name, tuple(fields))
        self.structs[name] = st
        return st

    def _type(self, te: A.TypeExpr, ctx: str, stack: list[str] | None = None) -> Type:
        """Resolve a type expression.  ``ctx`` says where it is written: "top_param",
        "plugin_fn_param", "plugin_param", "field" or "other"."""
        if isinstance(te, A.NamedType):
            if te.name in BUILTIN_TYPES:
                t = BUILTIN_TYPES[te.name]
                if t is TEXTURE and ctx != "plugin_param":
                    raise err("`Texture` is only allowed as the type of a plugin `param`",
                              te.loc)
                return t
            if te.name in self.struct_decls:
                return self._struct(te.name, stack or [])
            raise err(f"unknown type `{te.name}`", te.loc)
        if isinstance(te, A.BufferTypeExpr):
            if ctx == "plugin_fn_param" or ctx == "plugin_param":
                raise err("buffers cannot be used in plugins; a buffer type is only allowed "
                          "as a parameter of a top-level `fn`", te.loc)
            if ctx != "top_param":
                raise err("a buffer type is only allowed as a parameter of a top-level `fn`",
                          te.loc)
            elem = self._type(te.elem, "other", stack)
            if not (isinstance(elem, ScalarType) and elem != BOOL):
                raise err(f"buffer elements must be `Float`, `Int`, `UInt` or `UInt64`, "
                          f"found {_q(elem)}", te.elem.loc)
            return BufferType(elem)
        if isinstance(te, A.TupleTypeExpr):
            return TupleType(tuple(self._type(e, "other", stack) for e in te.elems))
        raise err("invalid type", te.loc)  # pragma: no cover

    def _fn_info(self, fd: A.FnDecl, mod: ModuleInfo, plugin: PluginInfo | None) -> FnInfo:
        params: list[Symbol] = []
        seen: set[str] = set()
        for p in fd.params:
            if p.name in seen:
                raise err(f"duplicate parameter `{p.name}`", p.loc)
            seen.add(p.name)
            t = self._type(p.type, "plugin_fn_param" if plugin else "top_param")
            p.sym = Symbol(p.name, t, "param", p.loc)
            params.append(p.sym)
        ret = self._type(fd.ret, "other") if fd.ret is not None else None
        return FnInfo(fd.name, fd, params, ret, mod, plugin)

    def _declare_fn(self, fd: A.FnDecl, mod: ModuleInfo) -> None:
        fn = self._fn_info(fd, mod, None)
        for other in self.overloads.get(fd.name, []):
            if other.param_types == fn.param_types:
                if other.module.prelude and not mod.prelude:
                    # a user's definition shadows the implicitly imported one
                    self.overloads[fd.name].remove(other)
                    self.functions.remove(other)
                    break
                raise err(f"duplicate definition of `{fn.signature()}` (first defined at "
                          f"{other.decl.loc})", fd.loc)
        self.overloads.setdefault(fd.name, []).append(fn)
        self.functions.append(fn)

    def _declare_plugin(self, pd: A.PluginDecl, mod: ModuleInfo) -> PluginInfo:
        if pd.kind not in PLUGIN_INTERFACES:
            raise err(f"unknown plugin kind `{pd.kind}`; expected one of "
                      + ", ".join(f"`{k}`" for k in PLUGIN_INTERFACES), pd.kind_loc)
        pl = PluginInfo(pd.kind, pd.name, pd, mod)
        seen: set[str] = set()
        for pp in pd.params:
            if pp.name in seen:
                raise err(f"duplicate param `{pp.name}` in plugin `{pd.name}`", pp.loc)
            seen.add(pp.name)
            t = self._type(pp.type, "plugin_param")
            if not isinstance(t, (ScalarType, TextureType, SpectrumType, VecType)):
                raise err(f"plugin param `{pp.name}` cannot have type {_q(t)}; expected "
                          "`Float`, `Int`, `UInt`, `UInt64`, `Bool`, `VecN`, `Spectrum` or "
                          "`Texture`", pp.type.loc)
            pp.sym = Symbol(pp.name, t, "plugin_param", pp.loc)
            pl.params.append(pp.sym)
            pl.defaults.append(None if pp.default is None else self._const(pp, t))
        for fd in pd.fns:
            if fd.name in pl.fns:
                raise err(f"duplicate definition of `{fd.name}` in plugin `{pd.name}`", fd.loc)
            if fd.name in seen:
                raise err(f"`{fd.name}` is already a param of plugin `{pd.name}`", fd.loc)
            fn = self._fn_info(fd, mod, pl)
            fn.ir_name = f"{pd.name}.{fd.name}"
            pl.fns[fd.name] = fn
        for mname, params, ret in PLUGIN_INTERFACES[pd.kind]:
            sig = f"fn {mname}(" + ", ".join(f"{n}: {t}" for n, t in params) + f") -> {ret}"
            fn = pl.fns.get(mname)
            if fn is None:
                raise err(f"{pd.kind} `{pd.name}` is missing the required function `{sig}`",
                          pd.loc)
            want = [self._iface_type(t) for _, t in params]
            if fn.param_types != want or fn.ret != self._iface_type(ret):
                raise err(f"`{pd.name}.{mname}` has the wrong signature: expected `{sig}`, "
                          f"found `{fn.signature()}`", fn.decl.loc)
        return pl

    def _iface_type(self, name: str) -> Type | None:
        if name in BUILTIN_TYPES:
            return BUILTIN_TYPES[name]
        return self.structs.get(name)

    def _const(self, pp: A.PluginParam, t: Type) -> Any:
        """The python value of a plugin param default (a constant expression)."""
        e = pp.default
        bad = err(f"the default of plugin param `{pp.name}` must be a constant of type "
                  f"{_q(t)}", e.loc if e is not None else pp.loc)

        def num(x: A.Expr) -> float | int | None:
            if isinstance(x, (A.IntLit, A.FloatLit)):
                return x.value
            if isinstance(x, A.Unary) and x.op == "-":
                v = num(x.operand)
                return None if v is None else -v
            return None

        def f32(v: float) -> float:
            return float(np.float32(v))

        v = num(e)
        if t == F32 or isinstance(t, (SpectrumType, TextureType)):
            if v is not None and not (isinstance(e, A.IntLit) and e.suffix):
                return f32(v)
            if isinstance(e, A.Call) and isinstance(e.func, A.Name) and \
                    e.func.id == "Spectrum" and isinstance(t, (SpectrumType, TextureType)):
                vals = [num(a) for a in e.args]
                if len(vals) in (1, 3) and None not in vals:
                    return f32(vals[0]) if len(vals) == 1 else tuple(f32(x) for x in vals)
            raise bad
        if isinstance(t, VecType):
            if v is not None:
                return tuple([f32(v)] * t.n)
            if isinstance(e, A.Call) and isinstance(e.func, A.Name) and e.func.id == f"Vec{t.n}":
                vals = [num(a) for a in e.args]
                if len(vals) in (1, t.n) and None not in vals:
                    return tuple(f32(x) for x in (vals * t.n if len(vals) == 1 else vals))
            raise bad
        if t == BOOL:
            if isinstance(e, A.BoolLit):
                return e.value
            raise bad
        if is_int_scalar(t):
            lit = e.operand if isinstance(e, A.Unary) else e
            if isinstance(v, int) and isinstance(lit, A.IntLit) and \
                    lit.suffix in ("", {U32: "u", U64: "ul"}.get(t, "")):
                lo, hi = {I32: (-2**31, 2**31 - 1), U32: (0, 2**32 - 1),
                          U64: (0, 2**64 - 1)}[t]
                if lo <= v <= hi:
                    return v
            raise bad
        raise bad

    def _check_recursion(self) -> None:
        done: set[FnInfo] = set()
        stack: list[FnInfo] = []

        def visit(fn: FnInfo) -> None:
            stack.append(fn)
            for callee, loc in self.calls.get(fn, []):
                if callee in stack:
                    cycle = stack[stack.index(callee):] + [callee]
                    chain = " -> ".join(f"`{f.name}`" for f in cycle)
                    raise err(f"recursion is not supported: {chain}", loc)
                if callee not in done:
                    visit(callee)
            stack.pop()
            done.add(fn)

        for fn in self.functions + [f for p in self.plugins for f in p.fns.values()]:
            if fn not in done:
                visit(fn)

    # ---------------------------------------------------------------- functions
    def _check_fn(self, fn: FnInfo, plugin: PluginInfo | None) -> None:
        root = _Scope()
        if plugin is not None:
            for s in plugin.params:
                root.vars[s.name] = s
        scope = _Scope(root)
        for s in fn.params:
            scope.vars[s.name] = s
        self.ctx = _FnCtx(fn)
        self.calls.setdefault(fn, [])
        self._block(fn.decl.body.stmts, _Scope(scope))
        if fn.ret is not None and not _always_returns(fn.decl.body.stmts):
            raise err(f"missing return: function `{fn.name}` must return a {_q(fn.ret)} on "
                      "every path", fn.decl.loc)
        _check_literals(fn.decl.body)
        self.ctx = None

    def _block(self, stmts: list[A.Stmt], scope: _Scope) -> None:
        for s in stmts:
            self._stmt(s, scope)

    def _stmt(self, s: A.Stmt, scope: _Scope) -> None:
        ctx = self.ctx
        assert ctx is not None
        if isinstance(s, A.Block):
            self._block(s.stmts, _Scope(scope))
        elif isinstance(s, A.Let):
            t = self._init_value(s, s.type, scope)
            self._bind(s.pattern, t, scope)
        elif isinstance(s, A.Var):
            t = self._init_value(s, s.type, scope)
            s.sym = Symbol(s.name, t, "var", s.name_loc or s.loc)
            scope.vars[s.name] = s.sym
        elif isinstance(s, A.Assign):
            self._assign(s, scope)
        elif isinstance(s, A.If):
            s.cond = self._cond(s.cond, scope)
            self._block(s.then.stmts, _Scope(scope))
            if s.else_ is not None:
                self._stmt(s.else_, scope)
        elif isinstance(s, A.IfConst):
            if s.trait not in TRAITS:
                raise err(f"unknown trait `{s.trait}`; expected one of "
                          + ", ".join(f"`{t}`" for t in TRAITS), s.trait_loc or s.loc)
            self._block(s.then.stmts, _Scope(scope))
            if s.else_ is not None:
                self._stmt(s.else_, scope)
        elif isinstance(s, A.For):
            for attr in ("start", "end"):
                e = getattr(s, attr)
                t = self._expr(e, scope)
                if t != I32:
                    raise err(f"range bounds must be `Int`, found {_q(t)}", e.loc)
            body = _Scope(scope)
            s.sym = Symbol(s.var, I32, "loop", s.var_loc or s.loc)
            body.vars[s.var] = s.sym
            ctx.loops += 1
            self._block(s.body.stmts, body)
            ctx.loops -= 1
        elif isinstance(s, A.While):
            s.cond = self._cond(s.cond, scope)
            ctx.loops += 1
            self._block(s.body.stmts, _Scope(scope))
            ctx.loops -= 1
        elif isinstance(s, (A.Break, A.Continue)):
            if ctx.loops == 0:
                word = "break" if isinstance(s, A.Break) else "continue"
                raise err(f"`{word}` outside of a loop", s.loc)
        elif isinstance(s, A.Return):
            ret = ctx.fn.ret
            if s.value is None:
                if ret is not None:
                    raise err(f"missing return value: function `{ctx.fn.name}` returns "
                              f"{_q(ret)}", s.loc)
            else:
                t = self._expr(s.value, scope)
                if ret is None:
                    raise err(f"function `{ctx.fn.name}` returns nothing, but this `return` "
                              "has a value", s.value.loc)
                s.value = self._coerce(s.value, t, ret, "return type mismatch")
        elif isinstance(s, A.ExprStmt):
            self._expr(s.expr, scope, allow_void=True)
        else:  # pragma: no cover
            raise err("unsupported statement", s.loc)

    def _init_value(self, s: A.Let | A.Var, te: A.TypeExpr | None, scope: _Scope) -> Type:
        t = self._expr(s.value, scope)
        if isinstance(t, BufferType):
            raise err("a buffer cannot be stored in a variable; index it directly", s.value.loc)
        if te is not None:
            want = self._type(te, "other")
            s.value = self._coerce(s.value, t, want, "mismatched types")
            return want
        return t

    def _bind(self, pat: A.PatName | A.PatTuple, t: Type, scope: _Scope) -> None:
        if isinstance(pat, A.PatName):
            pat.sym = Symbol(pat.name, t, "let", pat.loc)
            scope.vars[pat.name] = pat.sym
            return
        if not isinstance(t, TupleType):
            raise err(f"cannot destructure a value of type {_q(t)}: it is not a tuple", pat.loc)
        if len(t.elems) != len(pat.elems):
            raise err(f"expected a tuple of {len(pat.elems)} elements, found {_q(t)}", pat.loc)
        for p, et in zip(pat.elems, t.elems):
            self._bind(p, et, scope)

    def _assign(self, s: A.Assign, scope: _Scope) -> None:
        root = s.target
        while isinstance(root, (A.Field, A.TupleField)):
            root = root.obj
        if isinstance(s.target, A.Index):
            root = s.target.obj
            if not isinstance(root, A.Name):
                raise err("only a buffer parameter can be indexed on the left of `=`", root.loc)
        if not isinstance(root, A.Name):
            raise err("cannot assign to this expression", s.target.loc)
        sym = scope.lookup(root.id)
        if sym is None:
            raise err(f"unknown identifier `{root.id}`", root.loc)
        if not isinstance(s.target, A.Index):
            if sym.kind == "let":
                raise err(f"cannot assign to `{sym.name}`: it is declared with `let` "
                          "(use `var` for a mutable variable)", s.target.loc)
            if sym.kind == "param":
                raise err(f"cannot assign to parameter `{sym.name}`", s.target.loc)
            if sym.kind == "plugin_param":
                raise err(f"cannot assign to plugin param `{sym.name}`", s.target.loc)
            if sym.kind == "loop":
                raise err(f"cannot assign to loop variable `{sym.name}`", s.target.loc)
        if s.op != "=":
            s.value = A.Binary(s.loc, s.op[:-1], copy.deepcopy(s.target), s.value)
            s.op = "="
        tt = self._expr(s.target, scope)
        vt = self._expr(s.value, scope)
        s.value = self._coerce(s.value, vt, tt, "mismatched types in assignment")

    def _cond(self, e: A.Expr, scope: _Scope) -> A.Expr:
        t = self._expr(e, scope)
        if t != BOOL:
            raise err(f"condition must be `Bool`, found {_q(t)}", e.loc)
        return e

    # ---------------------------------------------------------------- conversions
    def _conv_cost(self, e: A.Expr, src: Type | None, dst: Type) -> int | None:
        """0: same type; 1: literal conversion; 2: broadcast; None: not convertible."""
        if src == dst:
            return 0
        if is_int_literal(e) and (dst in (F32, U32, U64) or dst == I32):
            return 1
        if is_int_literal(e) and (is_float_agg(dst) and not isinstance(dst, MatType)):
            return 2
        if src == F32 and (isinstance(dst, SpectrumType)
                           or (isinstance(dst, VecType) and dst.elem == F32)):
            return 2
        return None

    def _coerce(self, e: A.Expr, src: Type | None, dst: Type, what: str) -> A.Expr:
        """Convert ``e`` (of type ``src``) to ``dst`` or raise "what: expected .., found ..".
        """
        if src is None:
            raise err(f"{what}: expected {_q(dst)}, found no value", e.loc)
        cost = self._conv_cost(e, src, dst)
        if cost is None:
            raise err(f"{what}: expected {_q(dst)}, found {_q(src)}", e.loc)
        return self._apply(e, src, dst)

    def _apply(self, e: A.Expr, src: Type | None, dst: Type) -> A.Expr:
        if src == dst:
            return e
        if is_int_literal(e):
            if is_float_agg(dst):
                _retype_literal(e, F32)
                c = A.Convert(e.loc, e, dst)
                c.ty = dst
                return c
            _retype_literal(e, dst)
            return e
        c = A.Convert(e.loc, e, dst)
        c.ty = dst
        return c

    def _unify(self, a: A.Expr, ta: Type, b: A.Expr, tb: Type) -> tuple[A.Expr, A.Expr, Type] | None:
        """Bring two operands to a common type (literals, Float broadcast); None if none."""
        la, lb = is_int_literal(a), is_int_literal(b)
        if la and not lb and tb is not None:
            tgt = F32 if is_float_agg(tb) else tb
            if self._conv_cost(a, ta, tgt) is not None:
                a, ta = self._apply(a, ta, tgt), tgt
        elif lb and not la and ta is not None:
            tgt = F32 if is_float_agg(ta) else ta
            if self._conv_cost(b, tb, tgt) is not None:
                b, tb = self._apply(b, tb, tgt), tgt
        if ta == tb:
            return a, b, ta
        if ta == F32 and is_float_agg(tb) and not isinstance(tb, MatType):
            return self._apply(a, ta, tb), b, tb
        if tb == F32 and is_float_agg(ta) and not isinstance(ta, MatType):
            return a, self._apply(b, tb, ta), ta
        if ta == F32 and isinstance(tb, MatType):
            return self._apply(a, ta, tb), b, tb
        if tb == F32 and isinstance(ta, MatType):
            return a, self._apply(b, tb, ta), ta
        return None

    # ---------------------------------------------------------------- expressions
    def _expr(self, e: A.Expr, scope: _Scope, allow_void: bool = False) -> Type | None:
        t = self._expr_inner(e, scope)
        e.ty = t
        if t is None and not allow_void:
            raise err("this expression has no value (the function returns nothing)", e.loc)
        return t

    def _expr_inner(self, e: A.Expr, scope: _Scope) -> Type | None:
        if isinstance(e, A.IntLit):
            return {"": I32, "u": U32, "ul": U64}[e.suffix]
        if isinstance(e, A.FloatLit):
            return F32
        if isinstance(e, A.BoolLit):
            return BOOL
        if isinstance(e, A.Name):
            sym = scope.lookup(e.id)
            if sym is None:
                if e.id in BUILTIN_TYPES or e.id in self.structs:
                    raise err(f"`{e.id}` is a type, not a value", e.loc)
                if e.id in self.overloads or e.id in BUILTIN_FNS or (
                        self.ctx and self.ctx.fn.plugin and e.id in self.ctx.fn.plugin.fns):
                    raise err(f"`{e.id}` is a function; call it with `{e.id}(...)`", e.loc)
                raise err(f"unknown identifier `{e.id}`", e.loc)
            if sym.type is TEXTURE:
                raise err(f"texture `{e.id}` must be called with a `Surface`: `{e.id}(si)`",
                          e.loc)
            e.sym = sym
            return sym.type
        if isinstance(e, A.Unary):
            return self._unary(e, scope)
        if isinstance(e, A.Binary):
            return self._binary(e, scope)
        if isinstance(e, A.Call):
            return self._call(e, scope)
        if isinstance(e, A.Field):
            t = self._expr(e.obj, scope)
            if isinstance(t, VecType) and len(e.name) == 1 and e.name in "xyzw"[: t.n]:
                e.index = "xyzw".index(e.name)
                return t.elem
            if isinstance(t, StructType):
                try:
                    e.index = t.field_index(e.name)
                except KeyError:
                    raise err(f"struct `{t.name}` has no field `{e.name}`",
                              e.name_loc or e.loc) from None
                return t.fields[e.index][1]
            raise err(f"{_q(t)} has no field `{e.name}`", e.name_loc or e.loc)
        if isinstance(e, A.TupleField):
            t = self._expr(e.obj, scope)
            if not isinstance(t, TupleType):
                raise err(f"`.{e.index}` needs a tuple, found {_q(t)}", e.loc)
            if e.index >= len(t.elems):
                raise err(f"tuple index {e.index} is out of range for {_q(t)}", e.loc)
            return t.elems[e.index]
        if isinstance(e, A.Index):
            t = self._expr(e.obj, scope)
            if not isinstance(t, BufferType):
                raise err(f"cannot index a value of type {_q(t)}; only buffers can be indexed",
                          e.loc)
            it = self._expr(e.index, scope)
            if not is_int_scalar(it):
                raise err(f"buffer index must be an integer, found {_q(it)}", e.index.loc)
            return t.elem
        if isinstance(e, A.TupleExpr):
            return TupleType(tuple(self._expr(x, scope) for x in e.elems))
        if isinstance(e, A.StructLit):
            return self._struct_lit(e, scope)
        if isinstance(e, A.Convert):
            return e.to
        raise err("unsupported expression", e.loc)  # pragma: no cover

    def _struct_lit(self, e: A.StructLit, scope: _Scope) -> Type:
        st = self.structs.get(e.name)
        if st is None:
            raise err(f"unknown struct `{e.name}`", e.loc)
        given: dict[str, A.FieldInit] = {}
        for fi in e.fields:
            if fi.name in given:
                raise err(f"field `{fi.name}` is given twice", fi.loc)
            try:
                st.field_index(fi.name)
            except KeyError:
                raise err(f"struct `{st.name}` has no field `{fi.name}`", fi.loc) from None
            given[fi.name] = fi
        ordered = []
        for fname, ftype in st.fields:
            if fname not in given:
                raise err(f"missing field `{fname}` in `{st.name}` literal", e.loc)
            fi = given[fname]
            t = self._expr(fi.value, scope)
            fi.value = self._coerce(fi.value, t, ftype, f"field `{fname}`")
            ordered.append(fi)
        e.fields = ordered
        return st

    def _unary(self, e: A.Unary, scope: _Scope) -> Type:
        t = self._expr(e.operand, scope)
        ok = {"-": is_numeric(t), "!": t == BOOL, "~": is_int_scalar(t)}
        if ok.get(e.op):
            return t
        raise err(f"cannot apply unary `{e.op}` to {_q(t)}", e.loc)

    def _binary(self, e: A.Binary, scope: _Scope) -> Type:
        ta = self._expr(e.left, scope)
        tb = self._expr(e.right, scope)
        op = e.op
        if op in ("&&", "||"):
            for x, t in ((e.left, ta), (e.right, tb)):
                if t != BOOL:
                    raise err(f"operands of `{op}` must be `Bool`, found {_q(t)}", x.loc)
            return BOOL
        u = self._unify(e.left, ta, e.right, tb)
        if u is not None:
            e.left, e.right, t = u
        else:
            t = None
        if op in _ARITH_VERB:
            if t is not None and is_numeric(t) and not (
                    isinstance(t, MatType) and op in ("*", "/", "%")
                    and ta == tb):
                return t
            verb = _ARITH_VERB[op]
            raise err(f"cannot {verb} {_q(ta)} and {_q(tb)}", e.loc)
        if op in ("&", "|", "^"):
            if t is not None and (is_int_scalar(t) or t == BOOL):
                return t
            raise err(f"cannot apply `{op}` to {_q(ta)} and {_q(tb)}", e.loc)
        if op in ("<<", ">>"):
            if t is not None and is_int_scalar(t):
                return t
            raise err(f"cannot shift {_q(ta)} by {_q(tb)}", e.loc)
        if op in ("==", "!=", "<", "<=", ">", ">="):
            if ta is not None and tb is not None and (
                    ta.is_aggregate or tb.is_aggregate or isinstance(ta, BufferType)):
                raise err(f"cannot compare {_q(ta)} and {_q(tb)}: comparisons are on scalars "
                          "only", e.loc)
            if t is not None and isinstance(t, ScalarType) and (t != BOOL or op in ("==", "!=")):
                return BOOL
            raise err(f"cannot compare {_q(ta)} and {_q(tb)}", e.loc)
        raise err(f"unknown operator `{op}`", e.loc)  # pragma: no cover

    # ---------------------------------------------------------------- calls
    def _call(self, e: A.Call, scope: _Scope) -> Type | None:
        if isinstance(e.func, A.Name):
            name = e.func.id
            args = e.args
            sym = scope.lookup(name)
            if sym is not None:
                if sym.type is TEXTURE:
                    return self._texture_call(e, sym, scope)
                raise err(f"`{name}` is not a function (it has type {_q(sym.type)})", e.func.loc)
        elif isinstance(e.func, A.Field):
            name = e.func.name
            args = [e.func.obj] + e.args
        else:
            t = self._expr(e.func, scope)
            raise err(f"cannot call a value of type {_q(t)}", e.func.loc)
        types = [self._expr(a, scope) for a in args]
        ctx = self.ctx
        assert ctx is not None
        plugin = ctx.fn.plugin
        if plugin is not None and name in plugin.fns:
            return self._user_call(e, name, [plugin.fns[name]], args, types)
        user = self.overloads.get(name, [])
        if name in BUILTIN_FNS:
            try:
                return self._builtin(e, name, args, types)
            except CompileError:
                if not user:
                    raise
        if user:
            return self._user_call(e, name, user, args, types)
        if name in BUILTIN_TYPES or name in self.structs:
            raise err(f"`{name}` cannot be called; write a struct literal `{name} {{ ... }}`"
                      if name in self.structs else f"`{name}` is not a constructor",
                      e.func.loc)
        raise err(f"unknown function `{name}`", e.func.loc if isinstance(e.func, A.Name)
                  else e.func.name_loc or e.loc)

    def _texture_call(self, e: A.Call, sym: Symbol, scope: _Scope) -> Type:
        surf = self.structs.get("Surface")
        if len(e.args) != 1:
            raise err(f"texture `{sym.name}` takes one `Surface` argument, found "
                      f"{len(e.args)}", e.loc)
        t = self._expr(e.args[0], scope)
        if t != surf:
            raise err(f"texture `{sym.name}` must be called with a `Surface`, found {_q(t)}",
                      e.args[0].loc)
        e.func.sym = sym
        e.target = ("texture", sym)
        return SPECTRUM

    def _user_call(self, e: A.Call, name: str, cands: list[FnInfo], args: list[A.Expr],
                   types: list[Type | None]) -> Type | None:
        viable: list[tuple[int, FnInfo]] = []
        for fn in cands:
            if len(fn.params) != len(args):
                continue
            costs = [self._conv_cost(a, t, p) for a, t, p in zip(args, types, fn.param_types)]
            if all(c is not None for c in costs):
                viable.append((sum(costs), fn))  # type: ignore[arg-type]
        loc = e.func.loc if isinstance(e.func, A.Name) else (e.func.name_loc or e.loc)
        if not viable:
            if len(cands) == 1:
                fn = cands[0]
                if len(fn.params) != len(args):
                    raise err(f"`{name}` takes {len(fn.params)} argument"
                              f"{'s' if len(fn.params) != 1 else ''}, found {len(args)} "
                              f"(expected `{fn.signature()}`)", loc)
                for i, (a, t, p) in enumerate(zip(args, types, fn.param_types)):
                    if self._conv_cost(a, t, p) is None:
                        raise err(f"argument {i + 1} of `{name}`: expected {_q(p)}, found "
                                  f"{_q(t)}", a.loc)
            found = f"{name}(" + ", ".join(type_name(t) for t in types) + ")"
            cl = "; ".join(f"`{c.signature()}`" for c in cands)
            raise err(f"no matching overload for `{found}`; candidates are: {cl}", loc)
        best = min(c for c, _ in viable)
        winners = [fn for c, fn in viable if c == best]
        if len(winners) > 1:
            found = f"{name}(" + ", ".join(type_name(t) for t in types) + ")"
            cl = "; ".join(f"`{c.signature()}`" for c in winners)
            raise err(f"ambiguous call `{found}`; candidates are: {cl}", loc)
        fn = winners[0]
        e.args = [self._apply(a, t, p) for a, t, p in zip(args, types, fn.param_types)]
        e.target = fn
        assert self.ctx is not None
        self.calls.setdefault(self.ctx.fn, []).append((fn, e.loc))
        return fn.ret

    def _builtin(self, e: A.Call, name: str, args: list[A.Expr],
                 types: list[Type | None]) -> Type | None:
        loc = e.func.loc if isinstance(e.func, A.Name) else (e.func.name_loc or e.loc)

        def nargs(*counts: int) -> None:
            if len(args) not in counts:
                want = " or ".join(str(c) for c in counts)
                raise err(f"`{name}` takes {want} argument{'s' if counts != (1,) else ''}, "
                          f"found {len(args)}", loc)

        def arg(i: int, want: Type) -> None:
            if self._conv_cost(args[i], types[i], want) is None:
                raise err(f"argument {i + 1} of `{name}`: expected {_q(want)}, found "
                          f"{_q(types[i])}", args[i].loc)
            args[i] = self._apply(args[i], types[i], want)
            types[i] = want

        def finish(t: Type | None, kind: str = "op") -> Type | None:
            e.args = args
            e.target = ("builtin", name)
            return t

        float_like = lambda t: t == F32 or (is_float_agg(t) and not isinstance(t, MatType))
        if name in ("sqrt", "floor", "ceil", "abs"):
            nargs(1)
            if is_int_literal(args[0]):
                arg(0, F32)
            t = types[0]
            if float_like(t) or (name == "abs" and is_int_scalar(t)):
                return finish(t)
            raise err(f"`{name}` expects `Float`, a vector or `Spectrum`, found {_q(t)}",
                      args[0].loc)
        if name in ("min", "max"):
            nargs(2)
            u = self._unify(args[0], types[0], args[1], types[1])
            if u is not None and is_int_literal(u[0]) and is_int_literal(u[1]):
                u = (u[0], u[1], I32)
            if u is None or not (float_like(u[2]) or is_int_scalar(u[2])):
                raise err(f"no matching overload for `{name}({type_name(types[0])}, "
                          f"{type_name(types[1])})`", loc)
            args[0], args[1], t = u
            return finish(t)
        if name == "select":
            nargs(3)
            if types[0] != BOOL:
                raise err(f"argument 1 of `select`: expected `Bool`, found {_q(types[0])}",
                          args[0].loc)
            u = self._unify(args[1], types[1], args[2], types[2])
            if u is None:
                raise err(f"`select` needs two values of the same type, found {_q(types[1])} "
                          f"and {_q(types[2])}", loc)
            args[1], args[2], t = u
            return finish(t)
        if name == "bits":
            nargs(1)
            arg(0, F32)
            return finish(U32)
        if name == "from_bits":
            nargs(1)
            arg(0, U32)
            return finish(F32)
        if name in ("Float", "Int", "UInt", "UInt64", "Bool"):
            nargs(1)
            t = types[0]
            if not isinstance(t, ScalarType):
                raise err(f"cannot convert {_q(t)} to `{name}`", args[0].loc)
            return finish(BUILTIN_TYPES[name])
        if name in ("Vec2", "Vec3", "Vec4", "Mat3", "Mat4"):
            want = BUILTIN_TYPES[name]
            n = want.n if isinstance(want, VecType) else want.n * want.n  # type: ignore
            if len(args) == 1 and isinstance(want, VecType):
                arg(0, F32)
                return finish(want)
            total = 0
            for i, t in enumerate(types):
                if is_int_literal(args[i]):
                    arg(i, F32)
                    t = F32
                if t == F32:
                    total += 1
                elif isinstance(t, VecType):
                    total += t.n
                else:
                    raise err(f"argument {i + 1} of `{name}`: expected `Float` or a vector, "
                              f"found {_q(t)}", args[i].loc)
            if total != n:
                raise err(f"`{name}` needs {n} components, found {total}", loc)
            return finish(want)
        if name == "Spectrum":
            nargs(1, 3)
            for i in range(len(args)):
                arg(i, F32)
            return finish(SPECTRUM)
        if name in ("mean", "max_value"):
            nargs(1)
            arg(0, SPECTRUM)
            return finish(F32)
        if name == "intersect":
            nargs(1)
            arg(0, self.structs.get("Ray") or StructType("Ray"))
            return finish(self.structs.get("Surface"))
        if name == "occluded":
            nargs(1, 2)
            arg(0, self.structs.get("Ray") or StructType("Ray"))
            if len(args) == 2:
                arg(1, F32)
            return finish(BOOL)
        raise err(f"unknown function `{name}`", loc)  # pragma: no cover


# --------------------------------------------------------------------------------------
# Helpers


def _always_returns(stmts: list[A.Stmt]) -> bool:
    for s in stmts:
        if isinstance(s, A.Return):
            return True
        if isinstance(s, A.Block) and _always_returns(s.stmts):
            return True
        if isinstance(s, (A.If, A.IfConst)) and s.else_ is not None:
            other = s.else_.stmts if isinstance(s.else_, A.Block) else [s.else_]
            if _always_returns(s.then.stmts) and _always_returns(other):
                return True
    return False


_RANGES = {I32: (-2**31, 2**31 - 1), U32: (0, 2**32 - 1), U64: (0, 2**64 - 1)}


def _check_literals(node: Any) -> None:
    """Integer literals must fit their final type (known only after conversions)."""
    stack = [node]
    while stack:
        n = stack.pop()
        if isinstance(n, list):
            stack.extend(n)
            continue
        if not hasattr(n, "__dataclass_fields__"):
            continue
        if isinstance(n, A.Unary) and n.op == "-" and isinstance(n.operand, A.IntLit):
            _lit_range(n.operand, -n.operand.value, n.loc)
            continue
        if isinstance(n, A.IntLit):
            _lit_range(n, n.value, n.loc)
            continue
        for f in n.__dataclass_fields__:
            v = getattr(n, f)
            if isinstance(v, (list, A.Expr, A.Stmt, A.FieldInit, A.PatName, A.PatTuple)):
                stack.append(v)


def _lit_range(lit: A.IntLit, value: int, loc: Loc) -> None:
    rng = _RANGES.get(lit.ty)
    if rng is not None and not rng[0] <= value <= rng[1]:
        raise err(f"integer literal `{lit.text}` is out of range for {_q(lit.ty)}", loc)
