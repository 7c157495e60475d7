"""Declarations: the checker's first pass over all loaded modules.

Structs are laid out (fields resolved, self-containment rejected), type expressions are
resolved with the rules of where they are written, and top-level functions are declared into
overload sets and given their IR names.  Bodies are checked afterwards by
:mod:`rdsl.dsl.checker`.
"""

from __future__ import annotations

from ..compiler.ir import BOOL, BufferType, ScalarType, StructType, TupleType, Type
from . import ast as A
from .program import FnInfo, ModuleInfo, PluginInfo, Symbol
from .types import BUILTIN_TYPES, TEXTURE, err, mangle, quoted

# stdlib types a plugin commonly needs, and the module that declares each
STDLIB_TYPES = {"Scene": "render.integrator", "Sampler": "render.integrator",
                "Interaction": "render.geometry", "LightSample": "render.lights",
                "PCG32": "pcg32"}


class Declarations:
    """The first pass: struct layouts, type expressions and top-level function signatures.

    It fills ``structs`` (every struct, fields resolved), ``overloads`` (name -> the
    functions of that name) and ``functions`` (in declaration order, with their IR names).
    Function bodies are left to :class:`rdsl.dsl.checker._Checker`, which extends it.
    """

    def __init__(self, modules: list[ModuleInfo], main_file: str) -> None:
        self.modules = modules
        self.main_file = main_file
        self.struct_decls: dict[str, tuple[A.StructDecl, ModuleInfo]] = {}
        self.structs: dict[str, StructType] = {}
        self.overloads: dict[str, list[FnInfo]] = {}
        self.functions: list[FnInfo] = []

    def _declare_structs(self) -> None:
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

    def _declare_fns(self) -> None:
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
            hint = STDLIB_TYPES.get(te.name)
            raise err(f"unknown type `{te.name}`"
                      + (f"; it is declared in the stdlib: add `import {hint};`" if hint else ""),
                      te.loc)
        if isinstance(te, A.BufferTypeExpr):
            if ctx == "plugin_fn_param" or ctx == "plugin_param":
                raise err("buffers cannot be used in plugins; a buffer type is only allowed "
                          "as a parameter of a top-level `fn`", te.loc)
            if ctx not in ("top_param", "field"):
                raise err("a buffer type is only allowed as a parameter of a top-level `fn` "
                          "or as a struct field", te.loc)
            elem = self._type(te.elem, "other", stack)
            if not (isinstance(elem, ScalarType) and elem != BOOL):
                raise err(f"buffer elements must be `Float`, `Int`, `UInt` or `UInt64`, "
                          f"found {quoted(elem)}", te.elem.loc)
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
