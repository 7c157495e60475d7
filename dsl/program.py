"""The entities the checker resolves: symbols, modules, functions, plugins, the program."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ..compiler.ir import Loc, StructType, Type
from . import ast as A
from .types import type_name


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
    summed: bool = False  # a `table(sum = N)`: called with no argument (its term's index)

    @property
    def param_types(self) -> list[Type]:
        return [p.type for p in self.params]

    @property
    def call_types(self) -> list[Type]:
        """What a call passes: the parameters, but a `sum` table's term index."""
        return self.param_types[1:] if self.summed else self.param_types

    def signature(self) -> str:
        args = ", ".join(type_name(t) for t in self.call_types)
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
    # the `table` functions: name -> {"n", "lo", "hi", "error"} (empty for a per-scene value)
    tables: dict[str, dict[str, Any]] = field(default_factory=dict)


@dataclass
class CheckedProgram:
    """The result of :func:`check_program`: typed AST plus resolved entities."""

    main_file: str
    modules: list[ModuleInfo]
    structs: dict[str, StructType]
    functions: list[FnInfo]  # top-level functions of every module
    plugins: list[PluginInfo]

    def release(self) -> None:
        """Cut the references between the checked entities and the AST (a call's
        ``target`` is its FnInfo, whose ``decl`` holds the call...), so that the program is
        freed by reference counting when the last reference goes, not by Python's cycle
        collector: a compile's AST is tens of thousands of objects, and collecting them
        took a tenth of a compile (0.1-0.2 s; the IR has no cycles, see Value.owner)."""
        for fn in [*self.functions, *(f for p in self.plugins for f in p.fns.values())]:
            fn.decl = fn.module = fn.plugin = None  # type: ignore[assignment]
        for pl in self.plugins:
            pl.decl = pl.module = None  # type: ignore[assignment]
            pl.fns = {}
        self.modules = []
