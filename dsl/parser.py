"""Source text -> AST, with lark's LALR parser and plain-words syntax errors."""

from __future__ import annotations

import hashlib
import os
import pickle
from collections.abc import Iterator
from contextlib import suppress
from functools import lru_cache
from pathlib import Path
from typing import Any

from lark import Lark, Token, Transformer, v_args
from lark.exceptions import (
    LarkError,
    UnexpectedCharacters,
    UnexpectedEOF,
    UnexpectedInput,
    UnexpectedToken,
    VisitError,
)
from lark.lark import PostLex

from ..compiler.diagnostics import CompileError, Diagnostic, register_source
from ..compiler.ir import F32_OVERFLOW, Loc
from ..core.cachedir import cache_dir, compiler_fingerprint, write_atomically
from . import ast as A

_GRAMMAR = Path(__file__).with_name("grammar.lark")


# float32 rounds to infinity from F32_OVERFLOW (compiler/ir.py), and to zero below half the
# smallest subnormal (2^-150); a literal out there would change meaning silently, as C
# compilers warn
_F32_UNDERFLOW = 2.0**-150


def _nonzero_digits(text: str) -> bool:
    """Whether a literal's mantissa has a nonzero digit (``1e-400`` is 0.0 in float64 too)."""
    return any(c in "123456789" for c in text.lower().split("e")[0])


class _Remember(PostLex):
    """Pass tokens through, remembering the last one (to place "expected `;`" after it)."""

    always_accept = ()

    def __init__(self) -> None:
        self.tokens: list[Token] = []

    @property
    def last(self) -> Token | None:
        return self.tokens[-1] if self.tokens else None

    def process(self, stream: Iterator[Token]) -> Iterator[Token]:
        self.tokens = []
        for tok in stream:
            self.tokens.append(tok)
            yield tok


_POSTLEX = _Remember()


@lru_cache(maxsize=1)
def _lark() -> Lark:
    """The parser.  lark keeps its LALR tables on disk (its ``cache``, under ``<cache>/lark/``):
    analysing the grammar took 0.27 s of every process that parses anything, a new scene's
    kernel source included; loading the tables takes 0.02 s.  lark checks the file against
    the grammar and its options and analyses the grammar again when it is missing, stale or
    damaged (every writer writes the same bytes, so processes racing to write agree)."""
    options: dict[str, Any] = {"parser": "lalr", "lexer": "contextual",
                               "propagate_positions": True, "maybe_placeholders": True,
                               "postlex": _POSTLEX}
    folder = cache_dir() / "lark"
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:  # the cache cannot be written: no tables kept
        return Lark(_GRAMMAR.read_text(), **options)
    path = folder / f"grammar-{_grammar_hash()[:32]}.cache"
    return Lark(_GRAMMAR.read_text(), cache=str(path), **options)


def parse(source: str, filename: str) -> A.Program:
    """Parse ``source`` (the text of ``filename``) into an :class:`ast.Program`; a program
    parsed before (in this process or, through the cache on disk, in another) is read back
    rather than parsed again: every scene's compile parses the same stdlib files."""
    register_source(filename, source)
    key = _ast_key(source, filename)
    blob = _ASTS.get(key) or _read_cached(key)
    if blob is not None:
        with suppress(Exception):  # a damaged entry: parse again
            return pickle.loads(blob)  # a fresh copy: the checker annotates its AST
    program = _parse(source, filename)
    try:
        blob = pickle.dumps(program, protocol=pickle.HIGHEST_PROTOCOL)
    except Exception:  # noqa: BLE001 - not picklable: just not cached  # pragma: no cover
        return program
    if len(_ASTS) > 128:
        _ASTS.pop(next(iter(_ASTS)))
    _ASTS[key] = blob
    _write_cached(key, blob)
    return program


def is_cached(source: str, filename: str) -> bool:
    """Whether ``parse(source, filename)`` would read its AST back rather than parse."""
    return _is_cached(_ast_key(source, filename))


def _is_cached(key: str) -> bool:
    return key in _ASTS or (cache_dir() / "ast" / f"{key}.pickle").is_file()


def cache_writable() -> bool:
    """Whether parsed ASTs can be kept on disk (the folder exists or can be made, and
    is writable)."""
    folder = cache_dir() / "ast"
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return False
    return os.access(folder, os.W_OK)


def warm_up() -> None:
    """Load the parser (its tables, from lark's cache) now."""
    _lark()


def parse_for_cache(source: str, filename: str) -> tuple[str, bytes] | None:
    """The cache key and pickled AST of ``source``, what :func:`parse` keeps on disk
    (:func:`store` writes it), or None if it is there already or has a syntax error (left
    to :func:`parse` to report; dsl/parse_ahead.py's helper calls this)."""
    key = _ast_key(source, filename)
    if _is_cached(key):
        return None
    try:
        return key, pickle.dumps(_parse(source, filename), protocol=pickle.HIGHEST_PROTOCOL)
    except Exception:  # noqa: BLE001 - reported by the loader's own parse
        return None


def store(key: str, blob: bytes) -> None:
    """Keep a :func:`parse_for_cache` result on disk."""
    _write_cached(key, blob)


# Pickled ASTs by key, in this process; on disk under <cache>/ast/
_ASTS: dict[str, bytes] = {}


@lru_cache(maxsize=1)
def _grammar_hash() -> str:
    """What the ASTs depend on besides the text: the compiler's code (the grammar, this
    file, the AST's classes...) and lark's version."""
    from lark import __version__ as lark_version

    return hashlib.sha256(f"{compiler_fingerprint()}:{lark_version}".encode()).hexdigest()


def _ast_key(source: str, filename: str) -> str:
    h = hashlib.sha256(_grammar_hash().encode())
    for part in (filename, source):  # Locs hold the file name
        b = part.encode()
        h.update(f"{len(b)}:".encode())
        h.update(b)
    return h.hexdigest()


def _read_cached(key: str) -> bytes | None:
    try:
        return (cache_dir() / "ast" / f"{key}.pickle").read_bytes()
    except OSError:
        return None


def _write_cached(key: str, blob: bytes) -> None:
    write_atomically(cache_dir() / "ast" / f"{key}.pickle", lambda f: f.write(blob))


def _parse(source: str, filename: str) -> A.Program:
    """``source`` parsed by lark and turned into an AST."""
    parser = _lark()
    try:
        tree = parser.parse(source)
    except UnexpectedInput as e:
        raise _syntax_error(e, filename, source, parser) from None
    except LarkError as e:  # pragma: no cover - defensive
        raise CompileError(f"syntax error: {e}", Loc(filename, 1, 1)) from None
    try:
        return _ToAst(filename).transform(tree)
    except VisitError as e:
        if isinstance(e.orig_exc, CompileError):
            raise e.orig_exc from None
        raise


# --------------------------------------------------------------------------------------
# Syntax errors

_NAMES = {
    "NAME": "an identifier", "INT": "an integer", "FLOAT": "a number", "TRUE": "`true`",
    "FALSE": "`false`", "STRUCT_START": "a struct literal", "$END": "end of file",
}
_EXPR_FOLLOW = {"PLUS", "STAR", "SLASH", "LPAR", "DOT", "LSQB"}
_KEYWORDS = {"import", "struct", "fn", "param", "let", "var", "if", "else", "const", "for",
             "in", "while", "break", "continue", "return"}
_EXPR_START = {"NAME", "INT", "FLOAT", "LPAR"}
_EXPR_END = {"NAME", "INT", "FLOAT", "TRUE", "FALSE", "RPAR", "RSQB", "RBRACE"}


def _describe_terminal(name: str, parser: Lark) -> str:
    if name in _NAMES:
        return _NAMES[name]
    try:
        pat = parser.get_terminal(name).pattern
        if pat.type == "str":
            return f"`{pat.value}`"
    except KeyError:
        pass
    return name.lower()


def _describe_token(tok: Token) -> str:
    if tok.type == "$END":
        return "end of file"
    text = str(tok).split("{")[0].strip() if tok.type == "STRUCT_START" else str(tok)
    return f"`{text}`"


def _syntax_error(e: UnexpectedInput, filename: str, source: str, parser: Lark) -> CompileError:
    line = e.line if isinstance(e.line, int) and e.line > 0 else 1
    col = e.column if isinstance(e.column, int) and e.column > 0 else 1
    if isinstance(e, UnexpectedCharacters):
        ch = source[e.pos_in_stream] if e.pos_in_stream < len(source) else "?"
        if source.startswith("/*", e.pos_in_stream):
            msg = "unterminated block comment"
        else:
            msg = f"unexpected character `{ch}`"
        return CompileError(Diagnostic(Loc(filename, line, col), msg))
    if isinstance(e, UnexpectedToken):
        tok = e.token
        found = _describe_token(tok)
        # the tokens before the offending one (the postlexer may have yielded it already)
        before = list(_POSTLEX.tokens)
        if before and tok.type != "$END" and before[-1].start_pos == tok.start_pos:
            before.pop()
        prev = before[-1] if before else None
        expected = _accepts(parser, before) or set(e.expected)
        if tok.type == "$END":
            line, col = _end_of(prev) if prev is not None else (1, 1)
        ops = bool(expected & _EXPR_FOLLOW)
        if tok.type == "SLASH" and source.startswith("/*", tok.start_pos or 0):
            msg = "unterminated block comment"
        elif any(t.type == "NAME" and str(t) in _KEYWORDS for t in before[-2:]):
            kw = next(t for t in before[-2:] if t.type == "NAME" and str(t) in _KEYWORDS)
            msg = f"unexpected `{kw}`"
            line, col = kw.line, kw.column
        elif tok.type == "$END":
            msg = "unexpected end of file" + (", expected `}`" if "RBRACE" in expected else "")
        elif "SEMICOLON" in expected and (len(expected) <= 3 or ops):
            after_expr = prev is not None and prev.type in _EXPR_END
            msg = f"expected `;`{' after expression' if after_expr else ''}, found {found}"
            if prev is not None and prev.end_line < tok.line:
                line, col = _end_of(prev)
        elif "LBRACE" in expected and "RBRACE" not in expected:
            msg = f"expected `{{`, found {found}"
        elif ops and "RPAR" in expected:
            msg = f"expected `)`, found {found}"
        elif ops and "RSQB" in expected:
            msg = f"expected `]`, found {found}"
        elif _EXPR_START <= expected:
            msg = f"expected an expression, found {found}"
        elif len(expected) <= 4:
            words = sorted(_describe_terminal(t, parser) for t in expected)
            alts = words[0] if len(words) == 1 else ", ".join(words[:-1]) + " or " + words[-1]
            msg = f"expected {alts}, found {found}"
        else:
            msg = f"unexpected {found}"
        return CompileError(Diagnostic(Loc(filename, line, col), msg))
    if isinstance(e, UnexpectedEOF):
        last = _POSTLEX.last
        line, col = _end_of(last) if last is not None else (1, 1)
        return CompileError(Diagnostic(Loc(filename, line, col), "unexpected end of file"))
    return CompileError(Diagnostic(Loc(filename, line, col), "syntax error"))


def _accepts(parser: Lark, tokens: list[Token]) -> set[str]:
    """The terminals the parser can shift after ``tokens`` (exact, unlike LALR lookaheads)."""
    try:
        ip = parser.parse_interactive("")
        for t in tokens:
            ip.feed_token(t)
        return set(ip.accepts()) - {"$END"} if tokens else set(ip.accepts())
    except Exception:  # noqa: BLE001 - best effort; fall back to lark's own expectations
        return set()


def _end_of(tok: Token) -> tuple[int, int]:
    """The position just after ``tok``."""
    end_line = getattr(tok, "end_line", None) or tok.line
    end_col = getattr(tok, "end_column", None) or (tok.column + len(str(tok)))
    return end_line, end_col


# --------------------------------------------------------------------------------------
# Tree -> AST

@v_args(meta=True)
class _ToAst(Transformer):
    """Builds :mod:`ast` nodes from lark's parse tree."""

    def __init__(self, filename: str) -> None:
        super().__init__()
        self.file = filename

    def _loc(self, meta: Any) -> Loc:
        if getattr(meta, "empty", True):
            return Loc(self.file, 0, 0)
        return Loc(self.file, meta.line, meta.column)

    def _tloc(self, tok: Token) -> Loc:
        return Loc(self.file, tok.line, tok.column)

    # ---- items
    def start(self, meta, items):
        prog = A.Program(self.file)
        for it in items:
            if isinstance(it, A.Import):
                prog.imports.append(it)
            elif isinstance(it, A.StructDecl):
                prog.structs.append(it)
            elif isinstance(it, A.FnDecl):
                prog.fns.append(it)
            elif isinstance(it, A.PluginDecl):
                prog.plugins.append(it)
        return prog

    def import_decl(self, meta, names):
        return A.Import([str(n) for n in names], self._loc(meta))

    def struct_decl(self, meta, ch):
        name, *fields = ch
        return A.StructDecl(str(name), [f for f in fields if f is not None], self._tloc(name))

    def field_decl(self, meta, ch):
        return A.StructField(str(ch[0]), ch[1], self._tloc(ch[0]))

    def fn_decl(self, meta, ch):
        name = ch[0]
        body = ch[-1]
        ret = ch[-2]
        params = [p for p in ch[1:-2] if p is not None]
        return A.FnDecl(str(name), params, ret, body, self._tloc(name))

    def param(self, meta, ch):
        return A.ParamDecl(str(ch[0]), ch[1], self._tloc(ch[0]))

    def plugin_decl(self, meta, ch):
        kind, name, *members = ch
        params = [m for m in members if isinstance(m, A.PluginParam)]
        fns = [m for m in members if isinstance(m, A.FnDecl)]
        return A.PluginDecl(str(kind), str(name), params, fns, self._tloc(name),
                            self._tloc(kind))

    def table_decl(self, meta, ch):
        *opts, fn = ch
        options: dict[str, tuple[float | int, Loc]] = {}
        for name, value, loc in (o for o in opts if o is not None):
            if name in options:
                raise CompileError(Diagnostic(loc, f"duplicate table option `{name}`"))
            options[name] = (value, loc)
        fn.table = A.TableSpec(options, self._loc(meta))
        return fn

    def table_opt(self, meta, ch):
        return str(ch[0]), ch[1], self._tloc(ch[0])

    def table_value(self, meta, ch):
        tok = ch[0]
        return float(tok) if tok.type == "FLOAT" else int(str(tok).rstrip("ul"), 0)

    def table_neg(self, meta, ch):
        return -self.table_value(meta, ch)

    def plugin_param(self, meta, ch):
        return A.PluginParam(str(ch[0]), ch[1], ch[2], self._tloc(ch[0]))

    # ---- types
    def named_type(self, meta, ch):
        return A.NamedType(self._loc(meta), str(ch[0]))

    def buffer_type(self, meta, ch):
        return A.BufferTypeExpr(self._loc(meta), ch[0])

    def tuple_type(self, meta, ch):
        return A.TupleTypeExpr(self._loc(meta), [c for c in ch if c is not None])

    # ---- statements
    def block(self, meta, ch):
        return A.Block(self._loc(meta), list(ch))

    def let_stmt(self, meta, ch):
        return A.Let(self._loc(meta), ch[0], ch[1], ch[2])

    def pat_name(self, meta, ch):
        return A.PatName(str(ch[0]), self._tloc(ch[0]))

    def pat_tuple(self, meta, ch):
        return A.PatTuple([c for c in ch if c is not None], self._loc(meta))

    def var_stmt(self, meta, ch):
        return A.Var(self._loc(meta), str(ch[0]), ch[1], ch[2], self._tloc(ch[0]))

    def assign_stmt(self, meta, ch):
        target, op, value = ch
        return A.Assign(self._loc(meta), target, op, value)

    def assign_op(self, meta, ch):
        return str(ch[0])

    def if_stmt(self, meta, ch):
        return A.If(self._loc(meta), ch[0], ch[1], ch[2] if len(ch) > 2 else None)

    def if_const_stmt(self, meta, ch):
        return A.IfConst(self._loc(meta), str(ch[0]), ch[1], ch[2] if len(ch) > 2 else None,
                         self._tloc(ch[0]))

    def for_stmt(self, meta, ch):
        var, start, end, body = ch
        return A.For(self._loc(meta), str(var), start, end, body, self._tloc(var))

    def while_stmt(self, meta, ch):
        return A.While(self._loc(meta), ch[0], ch[1])

    def break_stmt(self, meta, ch):
        return A.Break(self._loc(meta))

    def continue_stmt(self, meta, ch):
        return A.Continue(self._loc(meta))

    def return_stmt(self, meta, ch):
        return A.Return(self._loc(meta), ch[0])

    def expr_stmt(self, meta, ch):
        return A.ExprStmt(self._loc(meta), ch[0])

    # ---- expressions
    def binop(self, meta, ch):
        left, op, right = ch
        return A.Binary(self._loc(meta), op, left, right)

    def unop(self, meta, ch):
        op, operand = ch
        return A.Unary(self._loc(meta), op, operand)

    def _op(self, meta, ch):
        return str(ch[0])

    or_op = and_op = eq_op = rel_op = bor_op = bxor_op = band_op = _op
    shift_op = add_op = mul_op = unary_op = _op

    def call(self, meta, ch):
        func, *args = ch
        args = [a for a in args if a is not None]
        return A.Call(self._loc(meta), func, args)

    def field(self, meta, ch):
        obj, name = ch
        return A.Field(self._loc(meta), obj, str(name), self._tloc(name))

    def tuple_field(self, meta, ch):
        obj, idx = ch
        text = str(idx)
        if not text.isdigit():
            raise CompileError(Diagnostic(self._tloc(idx), f"invalid tuple index `{text}`"))
        return A.TupleField(self._loc(meta), obj, int(text))

    def index(self, meta, ch):
        return A.Index(self._loc(meta), ch[0], ch[1])

    def int_lit(self, meta, ch):
        tok = ch[0]
        text = str(tok)
        suffix = ""
        body = text
        if body.endswith("ul"):
            suffix, body = "ul", body[:-2]
        elif body.endswith("u"):
            suffix, body = "u", body[:-1]
        value = int(body, 16) if body[:2].lower() == "0x" else int(body, 10)
        return A.IntLit(self._tloc(tok), value, suffix, text)

    def float_lit(self, meta, ch):
        tok = ch[0]
        value = float(str(tok))
        if abs(value) >= F32_OVERFLOW:
            raise CompileError(Diagnostic(self._tloc(tok), f"`{tok}` is too large for a Float "
                                          "(the largest is 3.4028235e+38)"))
        if 0.0 < abs(value) < _F32_UNDERFLOW or (value == 0.0 and _nonzero_digits(str(tok))):
            raise CompileError(Diagnostic(self._tloc(tok), f"`{tok}` is too small for a Float: "
                                          "it would be 0 (the smallest is 1.4e-45)"))
        return A.FloatLit(self._tloc(tok), value, str(tok))

    def bool_lit(self, meta, ch):
        return A.BoolLit(self._tloc(ch[0]), str(ch[0]) == "true")

    def name(self, meta, ch):
        return A.Name(self._tloc(ch[0]), str(ch[0]))

    def tuple_expr(self, meta, ch):
        return A.TupleExpr(self._loc(meta), [c for c in ch if c is not None])

    def struct_lit(self, meta, ch):
        start, *fields = ch
        name = str(start).split("{")[0].strip()
        return A.StructLit(self._tloc(start), name, [f for f in fields if f is not None])

    def field_init(self, meta, ch):
        return A.FieldInit(str(ch[0]), ch[1], self._tloc(ch[0]))


__all__ = ["UnexpectedEOF", "UnexpectedToken", "parse"]
