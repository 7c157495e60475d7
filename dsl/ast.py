"""The rdsl abstract syntax tree.

Plain dataclasses produced by :mod:`rdsl.dsl.parser`.  Every node has a ``loc``.  The checker
annotates expressions in place: ``ty`` is the expression's IR type after checking, and some
nodes get resolution info (``Name.sym``, ``Call.target``, ...).  It may also wrap an
expression in :class:`Convert` where an implicit conversion applies.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ..compiler.ir import Loc

# --------------------------------------------------------------------------------------
# Types written in source


@dataclass
class TypeExpr:
    """Base class of source-level type expressions."""

    loc: Loc


@dataclass
class NamedType(TypeExpr):
    """``Float``, ``Vec3``, ``Surface``, ..."""

    name: str


@dataclass
class BufferTypeExpr(TypeExpr):
    """``[Float]``."""

    elem: TypeExpr


@dataclass
class TupleTypeExpr(TypeExpr):
    """``(A, B)``."""

    elems: list[TypeExpr]


# --------------------------------------------------------------------------------------
# Expressions


@dataclass
class Expr:
    """Base class of expressions.  ``ty`` is set by the checker."""

    loc: Loc

    def __post_init__(self) -> None:
        self.ty: Any = None


@dataclass
class IntLit(Expr):
    value: int
    suffix: str  # "", "u" or "ul"
    text: str = ""


@dataclass
class FloatLit(Expr):
    value: float
    text: str = ""


@dataclass
class BoolLit(Expr):
    value: bool


@dataclass
class Name(Expr):
    """A plain identifier; ``sym`` is its resolved symbol."""

    id: str

    def __post_init__(self) -> None:
        super().__post_init__()
        self.sym: Any = None


@dataclass
class Binary(Expr):
    op: str
    left: Expr
    right: Expr


@dataclass
class Unary(Expr):
    op: str
    operand: Expr


@dataclass
class Call(Expr):
    """``f(args)`` or, with ``func`` a :class:`Field`, a method call ``a.f(args)``.

    The checker sets ``target`` (what is called) and replaces ``args`` by the full,
    converted argument list (the receiver first for method calls)."""

    func: Expr
    args: list[Expr]

    def __post_init__(self) -> None:
        super().__post_init__()
        self.target: Any = None


@dataclass
class Field(Expr):
    """``a.name``; ``index`` is the component index (set by the checker)."""

    obj: Expr
    name: str
    name_loc: Loc | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        self.index: int = -1


@dataclass
class TupleField(Expr):
    """``t.0``."""

    obj: Expr
    index: int


@dataclass
class Index(Expr):
    """``b[i]`` on a buffer."""

    obj: Expr
    index: Expr


@dataclass
class TupleExpr(Expr):
    elems: list[Expr]


@dataclass
class FieldInit:
    name: str
    value: Expr
    loc: Loc


@dataclass
class StructLit(Expr):
    """``Name { f: e, ... }``; the checker sorts ``fields`` into declaration order."""

    name: str
    fields: list[FieldInit]


@dataclass
class Convert(Expr):
    """An implicit conversion inserted by the checker (Float -> Vec/Spectrum broadcast)."""

    expr: Expr
    to: Any = None


# --------------------------------------------------------------------------------------
# Statements


@dataclass
class Stmt:
    loc: Loc


@dataclass
class Block(Stmt):
    stmts: list[Stmt]


@dataclass
class PatName:
    name: str
    loc: Loc

    def __post_init__(self) -> None:
        self.sym: Any = None


@dataclass
class PatTuple:
    elems: list[PatName | PatTuple]
    loc: Loc


@dataclass
class Let(Stmt):
    pattern: PatName | PatTuple
    type: TypeExpr | None
    value: Expr


@dataclass
class Var(Stmt):
    name: str
    type: TypeExpr | None
    value: Expr
    name_loc: Loc | None = None

    def __post_init__(self) -> None:
        self.sym: Any = None


@dataclass
class Assign(Stmt):
    """``target op= value``; ``op`` is ``=``, ``+=``, ... ."""

    target: Expr
    op: str
    value: Expr


@dataclass
class If(Stmt):
    cond: Expr
    then: Block
    else_: Block | If | IfConst | None


@dataclass
class IfConst(Stmt):
    trait: str
    then: Block
    else_: Block | If | IfConst | None
    trait_loc: Loc | None = None


@dataclass
class For(Stmt):
    var: str
    start: Expr
    end: Expr
    body: Block
    var_loc: Loc | None = None

    def __post_init__(self) -> None:
        self.sym: Any = None


@dataclass
class While(Stmt):
    cond: Expr
    body: Block


@dataclass
class Break(Stmt):
    pass


@dataclass
class Continue(Stmt):
    pass


@dataclass
class Return(Stmt):
    value: Expr | None


@dataclass
class ExprStmt(Stmt):
    expr: Expr


# --------------------------------------------------------------------------------------
# Declarations


@dataclass
class ParamDecl:
    name: str
    type: TypeExpr
    loc: Loc

    def __post_init__(self) -> None:
        self.sym: Any = None


@dataclass
class FnDecl:
    name: str
    params: list[ParamDecl]
    ret: TypeExpr | None
    body: Block
    loc: Loc
    table: TableSpec | None = None  # a plugin's `table(...) fn`


@dataclass
class TableSpec:
    """The options of a ``table(n = 64, lo = 0.0, hi = 1.0, error = 1e-4) fn``: each given
    option by name, with its number and location (checked by the checker)."""

    options: dict[str, tuple[float | int, Loc]]
    loc: Loc


@dataclass
class StructField:
    name: str
    type: TypeExpr
    loc: Loc


@dataclass
class StructDecl:
    name: str
    fields: list[StructField]
    loc: Loc


@dataclass
class PluginParam:
    name: str
    type: TypeExpr
    default: Expr | None
    loc: Loc

    def __post_init__(self) -> None:
        self.sym: Any = None


@dataclass
class PluginDecl:
    kind: str
    name: str
    params: list[PluginParam]
    fns: list[FnDecl]
    loc: Loc  # of the plugin's name
    kind_loc: Loc | None = None


@dataclass
class Import:
    path: list[str]
    loc: Loc


@dataclass
class Program:
    """One parsed source file."""

    filename: str
    imports: list[Import] = field(default_factory=list)
    structs: list[StructDecl] = field(default_factory=list)
    fns: list[FnDecl] = field(default_factory=list)
    plugins: list[PluginDecl] = field(default_factory=list)


def always_returns(stmts: list[Stmt]) -> bool:
    """Whether every path through `stmts` ends in a `return` (a function's missing return)."""
    for s in stmts:
        if isinstance(s, Return):
            return True
        if isinstance(s, Block) and always_returns(s.stmts):
            return True
        if isinstance(s, (If, IfConst)) and s.else_ is not None:
            other = s.else_.stmts if isinstance(s.else_, Block) else [s.else_]
            if always_returns(s.then.stmts) and always_returns(other):
                return True
    return False
