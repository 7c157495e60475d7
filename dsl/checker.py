"""Name resolution, type checking, overload resolution and plugin interface checks.

:func:`check_program` loads the implicit prelude (``stdlib/types.rdsl``, ``stdlib/math.rdsl``,
``stdlib/special.rdsl``), the main file and everything it imports (:mod:`.imports`), and returns a
:class:`CheckedProgram`.  The AST is annotated in place (``Expr.ty``, ``Name.sym``,
``Call.target``, implicit :class:`ast.Convert` nodes) so that :mod:`rdsl.dsl.lower` needs no
type logic of its own.

The checker's first pass (struct layouts, type expressions, function signatures) is
:mod:`.declarations`; types, their names and the implicit conversions are in :mod:`.types`;
the builtin functions and operators in :mod:`.builtins`; the resolved entities
(:class:`FnInfo`, :class:`PluginInfo`...) in :mod:`.program`.  Their public names are
re-exported here.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from pathlib import Path

from ..compiler.diagnostics import CompileError
from ..compiler.ir import (
    BOOL,
    F32,
    I32,
    SPECTRUM,
    U32,
    U64,
    BufferType,
    Loc,
    ScalarType,
    SpectrumType,
    StructType,
    TupleType,
    Type,
    VecType,
)
from . import ast as A
from .builtins import BUILTIN_FNS, check_binary, check_builtin, check_unary
from .declarations import Declarations
from .imports import STDLIB, load_program
from .interfaces import OPTIONAL_INTERFACES, PLUGIN_INTERFACES, check_integrator
from .parser import parse
from .tables import check_sum_table_read, table_options as _table_options
from .program import CheckedProgram, FnInfo, ModuleInfo, PluginInfo, Symbol
from .types import (
    BUILTIN_TYPES,
    TEXTURE,
    TextureType,
    apply_conv,
    check_literals,
    coerce,
    conv_cost,
    err,
    is_float_agg,
    is_int_literal,
    is_int_scalar,
    is_numeric,
    mangle,
    plugin_default,
    quoted,
    type_name,
)

__all__ = [
    "BUILTIN_FNS", "BUILTIN_TYPES", "PLUGIN_INTERFACES", "STDLIB", "TEXTURE", "TRAITS",
    "CheckedProgram", "FnInfo", "ModuleInfo", "PluginInfo", "Symbol", "TextureType",
    "check_program", "err", "is_float_agg", "is_int_literal", "is_int_scalar", "is_numeric",
    "mangle", "parse", "type_name",
]


# `wavelengths`: a spectral build whose kernel sets its wavelengths (compiler/passes/lift/driver.py)
# `differentiated`: a build with derivatives (ad forward or reverse: compiler/build.py)
TRAITS = ("mono", "rgb", "spectral", "polarized", "wavelengths", "differentiated")



def check_program(source: str, filename: str, search_paths: list[Path] | None = None,
                  path: Path | None = None) -> CheckedProgram:
    """Load the prelude, the main file (text ``source``) and its imports; check everything."""
    return _Checker(load_program(source, filename, search_paths, path), filename).run()


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


class _Checker(Declarations):
    """The second pass: plugins and every function body, then the call graph."""

    def __init__(self, modules: list[ModuleInfo], main_file: str) -> None:
        super().__init__(modules, main_file)
        self.plugins: list[PluginInfo] = []
        self.calls: dict[FnInfo, list[tuple[FnInfo, Loc]]] = {}
        self.ctx: _FnCtx | None = None
        self.plugin_names: dict[str, PluginInfo] = {}

    # ---------------------------------------------------------------- top level
    def run(self) -> CheckedProgram:
        self._declare_structs()
        self._declare_fns()
        seen_plugins: dict[str, A.PluginDecl] = {}
        for mod in self.modules:
            for pd in mod.program.plugins:
                if pd.name in seen_plugins:
                    raise err(f"duplicate definition of plugin `{pd.name}` (first defined at "
                              f"{seen_plugins[pd.name].loc})", pd.loc)
                seen_plugins[pd.name] = pd
                self.plugins.append(self._declare_plugin(pd, mod))
                self.plugin_names[pd.name] = self.plugins[-1]
        for fn in self.functions:
            self._check_fn(fn, None)
        for pl in self.plugins:
            for fn in pl.fns.values():
                self._check_fn(fn, pl)
        self._check_recursion()
        return CheckedProgram(self.main_file, self.modules, self.structs, self.functions,
                              self.plugins)

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
                raise err(f"plugin param `{pp.name}` cannot have type {quoted(t)}; expected "
                          "`Float`, `Int`, `UInt`, `UInt64`, `Bool`, `VecN`, `Spectrum` or "
                          "`Texture`", pp.type.loc)
            pp.sym = Symbol(pp.name, t, "plugin_param", pp.loc)
            pl.params.append(pp.sym)
            pl.defaults.append(None if pp.default is None else plugin_default(pp, t))
        for fd in pd.fns:
            if fd.name in pl.fns:
                raise err(f"duplicate definition of `{fd.name}` in plugin `{pd.name}`", fd.loc)
            if fd.name in seen:
                raise err(f"`{fd.name}` is already a param of plugin `{pd.name}`", fd.loc)
            fn = self._fn_info(fd, mod, pl)
            fn.ir_name = f"{pd.name}.{fd.name}"
            pl.fns[fd.name] = fn
            if fd.table is not None:
                pl.tables[fd.name] = _table_options(
                    fn, pd, {m for m, _, _ in PLUGIN_INTERFACES[pd.kind]})
                fn.summed = "sum" in pl.tables[fd.name]
        for mname, params, ret in PLUGIN_INTERFACES[pd.kind]:
            sig = f"fn {mname}(" + ", ".join(f"{n}: {t}" for n, t in params) + f") -> {ret}"
            fn = pl.fns.get(mname)
            if fn is None:
                raise err(f"{pd.kind} `{pd.name}` is missing the required function `{sig}`",
                          pd.loc)
            self._check_signature(pd, fn, mname, params, ret)
        for mname, params, ret in OPTIONAL_INTERFACES.get(pd.kind, ()):
            fn = pl.fns.get(mname)
            if fn is not None:
                self._check_signature(pd, fn, mname, params, ret)
        if pd.kind == "integrator":
            check_integrator(pl, self.structs)
        return pl

    def _check_signature(self, pd: A.PluginDecl, fn: FnInfo, mname: str,
                         params: list[tuple[str, str]], ret: str) -> None:
        """``fn``, the plugin's ``mname``, has the interface's parameter and return types."""
        want = [self._iface_type(t) for _, t in params]
        if fn.param_types != want or fn.ret != self._iface_type(ret):
            sig = f"fn {mname}(" + ", ".join(f"{n}: {t}" for n, t in params) + f") -> {ret}"
            raise err(f"`{pd.name}.{mname}` has the wrong signature: expected `{sig}`, "
                      f"found `{fn.signature()}`", fn.decl.loc)

    def _iface_type(self, name: str) -> Type | None:
        if name in BUILTIN_TYPES:
            return BUILTIN_TYPES[name]
        return self.structs.get(name)

    def _check_recursion(self) -> None:
        done: set[FnInfo] = set()
        for fn in self.functions + [f for p in self.plugins for f in p.fns.values()]:
            if fn not in done:
                self._visit_calls(fn, done, [])

    def _visit_calls(self, fn: FnInfo, done: set[FnInfo], stack: list[FnInfo]) -> None:
        """Depth first through the calls from ``fn``; a call back into ``stack`` is a
        diagnostic.  (A method, not a closure: a recursive closure is a reference cycle,
        which kept the whole checker and its AST alive until Python's cycle collector ran.)"""
        stack.append(fn)
        for callee, loc in self.calls.get(fn, []):
            if callee in stack:
                cycle = stack[stack.index(callee):] + [callee]
                chain = " -> ".join(f"`{f.name}`" for f in cycle)
                raise err(f"recursion is not supported: {chain}", loc)
            if callee not in done:
                self._visit_calls(callee, done, stack)
        stack.pop()
        done.add(fn)

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
        if fn.ret is not None and not A.always_returns(fn.decl.body.stmts):
            raise err(f"missing return: function `{fn.name}` must return a {quoted(fn.ret)} on "
                      "every path", fn.decl.loc)
        check_literals(fn.decl.body)
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
                    raise err(f"range bounds must be `Int`, found {quoted(t)}", e.loc)
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
                              f"{quoted(ret)}", s.loc)
            else:
                t = self._expr(s.value, scope)
                if ret is None:
                    raise err(f"function `{ctx.fn.name}` returns nothing, but this `return` "
                              "has a value", s.value.loc)
                s.value = coerce(s.value, t, ret, "return type mismatch")
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
            s.value = coerce(s.value, t, want, "mismatched types")
            return want
        return t

    def _bind(self, pat: A.PatName | A.PatTuple, t: Type, scope: _Scope) -> None:
        if isinstance(pat, A.PatName):
            pat.sym = Symbol(pat.name, t, "let", pat.loc)
            scope.vars[pat.name] = pat.sym
            return
        if not isinstance(t, TupleType):
            raise err(f"cannot destructure a value of type {quoted(t)}: it is not a tuple", pat.loc)
        if len(t.elems) != len(pat.elems):
            raise err(f"expected a tuple of {len(pat.elems)} elements, found {quoted(t)}", pat.loc)
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
        s.value = coerce(s.value, vt, tt, "mismatched types in assignment")

    def _cond(self, e: A.Expr, scope: _Scope) -> A.Expr:
        t = self._expr(e, scope)
        if t != BOOL:
            raise err(f"condition must be `Bool`, found {quoted(t)}", e.loc)
        return e

    # ---------------------------------------------------------------- conversions

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
            return check_unary(e, self._expr(e.operand, scope))
        if isinstance(e, A.Binary):
            return check_binary(e, self._expr(e.left, scope), self._expr(e.right, scope))
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
                ft = t.fields[e.index][1]
                self._check_private(t, e, ft)
                return ft
            raise err(f"{quoted(t)} has no field `{e.name}`", e.name_loc or e.loc)
        if isinstance(e, A.TupleField):
            t = self._expr(e.obj, scope)
            if not isinstance(t, TupleType):
                raise err(f"`.{e.index}` needs a tuple, found {quoted(t)}", e.loc)
            if e.index >= len(t.elems):
                raise err(f"tuple index {e.index} is out of range for {quoted(t)}", e.loc)
            return t.elems[e.index]
        if isinstance(e, A.Index):
            t = self._expr(e.obj, scope)
            if not isinstance(t, BufferType):
                raise err(f"cannot index a value of type {quoted(t)}; only buffers can be indexed",
                          e.loc)
            it = self._expr(e.index, scope)
            if not is_int_scalar(it):
                raise err(f"buffer index must be an integer, found {quoted(it)}", e.index.loc)
            return t.elem
        if isinstance(e, A.TupleExpr):
            return TupleType(tuple(self._expr(x, scope) for x in e.elems))
        if isinstance(e, A.StructLit):
            return self._struct_lit(e, scope)
        if isinstance(e, A.Convert):
            return e.to
        raise err("unsupported expression", e.loc)  # pragma: no cover

    def _check_private(self, t: StructType, e: A.Field, ft: Type) -> None:
        """A struct's buffer fields are private to the module that declares the struct:
        elsewhere the struct is a handle used through its functions (``Scene``)."""
        decl = self.struct_decls.get(t.name)
        assert self.ctx is not None
        if isinstance(ft, BufferType) and decl is not None and \
                decl[1] is not self.ctx.fn.module:
            raise err(f"field `{e.name}` of `{t.name}` is a buffer, private to "
                      f"{decl[1].key} where `{t.name}` is declared; use the functions that "
                      f"take a `{t.name}` instead", e.name_loc or e.loc)

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
            fi.value = coerce(fi.value, t, ftype, f"field `{fname}`")
            ordered.append(fi)
        e.fields = ordered
        return st

    # ---------------------------------------------------------------- calls
    def _call(self, e: A.Call, scope: _Scope) -> Type | None:
        if isinstance(e.func, A.Name):
            name = e.func.id
            args = e.args
            sym = scope.lookup(name)
            if sym is not None:
                if sym.type is TEXTURE:
                    return self._texture_call(e, sym, scope)
                raise err(f"`{name}` is not a function (it has type {quoted(sym.type)})",
                          e.func.loc)
        elif isinstance(e.func, A.Field):
            obj = e.func.obj
            if isinstance(obj, A.Name) and scope.lookup(obj.id) is None and \
                    obj.id in self.plugin_names:
                return self._plugin_call(e, self.plugin_names[obj.id], scope)
            name = e.func.name
            args = [e.func.obj] + e.args
        else:
            t = self._expr(e.func, scope)
            raise err(f"cannot call a value of type {quoted(t)}", e.func.loc)
        types = [self._expr(a, scope) for a in args]
        ctx = self.ctx
        assert ctx is not None
        plugin = ctx.fn.plugin
        if plugin is not None and name in plugin.fns:
            return self._user_call(e, name, [plugin.fns[name]], args, types)
        user = self.overloads.get(name, [])
        if name in BUILTIN_FNS:
            try:
                return check_builtin(e, name, args, types, self.structs)
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

    def _plugin_call(self, e: A.Call, plugin: PluginInfo, scope: _Scope) -> Type | None:
        """``plugin.fn(args)``: a plugin's function called by name.  Outside the plugin, its
        ``param``s are those of the scene's instance of it (``specialize``) or its
        defaults."""
        assert isinstance(e.func, A.Field)
        fn = plugin.fns.get(e.func.name)
        if fn is None:
            have = ", ".join(f"`{f}`" for f in plugin.fns)
            raise err(f"{plugin.kind} `{plugin.name}` has no function `{e.func.name}` "
                      f"(it has {have})", e.func.name_loc or e.loc)
        types = [self._expr(a, scope) for a in e.args]
        return self._user_call(e, f"{plugin.name}.{fn.name}", [fn], e.args, types)

    def _texture_call(self, e: A.Call, sym: Symbol, scope: _Scope) -> Type:
        surf = self.structs.get("Surface")
        if len(e.args) != 1:
            raise err(f"texture `{sym.name}` takes one `Surface` argument, found "
                      f"{len(e.args)}", e.loc)
        t = self._expr(e.args[0], scope)
        if t != surf:
            raise err(f"texture `{sym.name}` must be called with a `Surface`, found {quoted(t)}",
                      e.args[0].loc)
        e.func.sym = sym
        e.target = ("texture", sym)
        return SPECTRUM

    def _user_call(self, e: A.Call, name: str, cands: list[FnInfo], args: list[A.Expr],
                   types: list[Type | None]) -> Type | None:
        viable: list[tuple[int, FnInfo]] = []
        for fn in cands:
            if len(fn.call_types) != len(args):
                continue
            costs = [conv_cost(a, t, p) for a, t, p in zip(args, types, fn.call_types)]
            if all(c is not None for c in costs):
                viable.append((sum(costs), fn))  # type: ignore[arg-type]
        loc = e.func.loc if isinstance(e.func, A.Name) else (e.func.name_loc or e.loc)
        if not viable:
            if len(cands) == 1:
                fn = cands[0]
                want = len(fn.call_types)
                if want != len(args):
                    raise err(f"`{name}` takes {want} argument"
                              f"{'s' if want != 1 else ''}, found {len(args)} "
                              f"(expected `{fn.signature()}`"
                              + ("; a `sum` table is one value" if fn.summed else "") + ")",
                              loc)
                for i, (a, t, p) in enumerate(zip(args, types, fn.call_types)):
                    if conv_cost(a, t, p) is None:
                        raise err(f"argument {i + 1} of `{name}`: expected {quoted(p)}, found "
                                  f"{quoted(t)}", a.loc)
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
        e.args = [apply_conv(a, t, p) for a, t, p in zip(args, types, fn.call_types)]
        e.target = fn
        assert self.ctx is not None
        check_sum_table_read(fn, self.ctx.fn, loc)
        self.calls.setdefault(self.ctx.fn, []).append((fn, e.loc))
        return fn.ret
