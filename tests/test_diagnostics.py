"""Diagnostics: malformed or ill-typed programs give `file:line:col: error: message`.

Each case asserts a distinctive part of the message, the line and the column.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from rdsl.compiler.diagnostics import CompileError
from rdsl.dsl import check, compile_to_ir

# (name, source, line, col, message substring)
CASES = [
    ('missing_semi',
     'fn f() -> Float {\n    let x = 1.0\n    return x;\n}\n',
     2, 16, 'expected `;` after expression, found `return`'),
    ('missing_semi_same_line',
     'fn f() -> Float { let x = 1.0 return x; }\n',
     1, 31, 'expected `;` after expression, found `return`'),
    ('unexpected_rbrace',
     'fn f() {\n    let x = ;\n}\n',
     2, 13, 'expected an expression, found `;`'),
    ('unclosed_paren',
     'fn f() -> Float {\n    return (1.0 + 2.0;\n}\n',
     2, 22, 'expected `)`, found `;`'),
    ('eof',
     'fn f() -> Float {\n    return 1.0;\n',
     2, 16, 'unexpected end of file, expected `}`'),
    ('bad_char',
     'fn f() {\n    let x = 1.0 $ 2.0;\n}\n',
     2, 17, 'unexpected character `$`'),
    ('missing_param_type',
     'fn f(x) -> Float { return 1.0; }\n',
     1, 7, 'expected `:`, found `)`'),
    ('stray_else',
     'fn f() {\n    else { }\n}\n',
     2, 5, 'unexpected `else`'),
    ('unterminated_comment',
     'fn f() {\n    /* never closed\n}\n',
     2, 5, 'unterminated block comment'),
    ('double_op',
     'fn f() -> Float {\n    return 1.0 + * 2.0;\n}\n',
     2, 18, 'expected an expression, found `*`'),
    ('missing_brace_if',
     'fn f(x: Float) {\n    if x > 0.0 return;\n}\n',
     2, 16, 'expected `{`, found `return`'),
    ('bad_top_level',
     'let x = 1.0;\n',
     1, 1, 'unexpected `let`'),
    ('missing_arrow_type',
     'fn f() -> { }\n',
     1, 11, 'expected `(`, `[` or an identifier, found `{`'),
    ('bad_struct_field',
     'struct S { a Float }\n',
     1, 14, 'expected `:`, found `Float`'),
    ('assign_to_call',
     'fn g() -> Float { return 1.0; }\nfn f() {\n    g() = 2.0;\n}\n',
     3, 5, 'cannot assign to this expression'),
    ('bad_tuple_index',
     'fn f(t: (Float, Float)) -> Float {\n    return t.5;\n}\n',
     2, 12, 'tuple index 5 is out of range for `(Float, Float)`'),
    ('unknown_ident',
     'fn f() -> Float {\n    return y + 1.0;\n}\n',
     2, 12, 'unknown identifier `y`'),
    ('unknown_type',
     'fn f(x: Flaot) -> Float {\n    return 1.0;\n}\n',
     1, 9, 'unknown type `Flaot`'),
    ('unknown_field',
     'fn f(s: Surface) -> Float {\n    return s.q;\n}\n',
     2, 14, 'struct `Surface` has no field `q`'),
    ('unknown_vec_field',
     'fn f(v: Vec2) -> Float {\n    return v.z;\n}\n',
     2, 14, '`Vec2` has no field `z`'),
    ('unknown_function',
     'fn f() -> Float {\n    return frobnicate(1.0);\n}\n',
     2, 12, 'unknown function `frobnicate`'),
    ('wrong_arg_count',
     'fn g(a: Float, b: Float) -> Float { return a + b; }\nfn f() -> Float {\n    return g(1.0);\n}\n',
     3, 12, '`g` takes 2 arguments, found 1 (expected `g(Float, Float) -> Float`)'),
    ('wrong_arg_type',
     'fn g(a: Float, b: Float) -> Float { return a + b; }\nfn f(v: Vec3) -> Float {\n    return g(1.0, v);\n}\n',
     3, 19, 'argument 2 of `g`: expected `Float`, found `Vec3`'),
    ('no_overload',
     'fn g(a: Float) -> Float { return a; }\nfn g(a: Vec3) -> Float { return a.x; }\nfn f() -> Float {\n    return g(true);\n}\n',
     4, 12, 'no matching overload for `g(Bool)`; candidates are: `g(Float) -> Float`; `g(Vec3) -> Float'),
    ('assign_let',
     'fn f() -> Float {\n    let x = 1.0;\n    x = 2.0;\n    return x;\n}\n',
     3, 5, 'cannot assign to `x`: it is declared with `let`'),
    ('assign_param',
     'fn f(x: Float) -> Float {\n    x += 2.0;\n    return x;\n}\n',
     2, 5, 'cannot assign to parameter `x`'),
    ('assign_mismatch',
     'fn f(v: Vec3) -> Float {\n    var x = 1.0;\n    x = v;\n    return x;\n}\n',
     3, 9, 'mismatched types in assignment: expected `Float`, found `Vec3`'),
    ('non_bool_cond',
     'fn f(x: Float) -> Float {\n    if x { return 1.0; }\n    return 0.0;\n}\n',
     2, 8, 'condition must be `Bool`, found `Float`'),
    ('non_bool_while',
     'fn f() {\n    var i = 0;\n    while i { i += 1; }\n}\n',
     3, 11, 'condition must be `Bool`, found `Int`'),
    ('return_mismatch',
     'fn f(v: Vec3) -> Float {\n    return v;\n}\n',
     2, 12, 'return type mismatch: expected `Float`, found `Vec3`'),
    ('missing_return_value',
     'fn f() -> Float {\n    return;\n}\n',
     2, 5, 'missing return value: function `f` returns `Float`'),
    ('missing_return',
     'fn f(x: Float) -> Float {\n    if x > 0.0 { return 1.0; }\n}\n',
     1, 4, 'missing return: function `f` must return a `Float` on every path'),
    ('return_value_void',
     'fn f() {\n    return 1.0;\n}\n',
     2, 12, 'function `f` returns nothing, but this `return` has a value'),
    ('break_outside',
     'fn f() {\n    break;\n}\n',
     2, 5, '`break` outside of a loop'),
    ('continue_outside',
     'fn f() {\n    if true { continue; }\n}\n',
     2, 15, '`continue` outside of a loop'),
    ('add_vec_bool',
     'fn f(v: Vec3, b: Bool) {\n    let y = v + b;\n}\n',
     2, 13, 'cannot add `Vec3` and `Bool`'),
    ('spec_plus_vec',
     'fn f(s: Spectrum, v: Vec3) -> Spectrum {\n    return s * v;\n}\n',
     2, 12, 'cannot multiply `Spectrum` and `Vec3`'),
    ('compare_vectors',
     'fn f(a: Vec3, b: Vec3) -> Bool {\n    return a < b;\n}\n',
     2, 12, 'cannot compare `Vec3` and `Vec3`: comparisons are on scalars only'),
    ('and_non_bool',
     'fn f(a: Float) -> Bool {\n    return a && true;\n}\n',
     2, 12, 'operands of `&&` must be `Bool`, found `Float`'),
    ('not_float',
     'fn f(a: Float) -> Bool {\n    return !a;\n}\n',
     2, 12, 'cannot apply unary `!` to `Float`'),
    ('call_non_function',
     'fn f(x: Float) -> Float {\n    return x(2.0);\n}\n',
     2, 12, '`x` is not a function (it has type `Float`)'),
    ('fn_as_value',
     'fn g() -> Float { return 1.0; }\nfn f() -> Float {\n    let h = g;\n    return 1.0;\n}\n',
     3, 13, '`g` is a function; call it with `g(...)`'),
    ('void_value',
     'fn g() { }\nfn f() {\n    let x = g();\n}\n',
     3, 13, 'this expression has no value (the function returns nothing)'),
    ('dup_fn',
     'fn g(a: Float) -> Float { return a; }\nfn g(b: Float) -> Float { return b; }\n',
     2, 4, 'duplicate definition of `g(Float) -> Float`'),
    ('dup_struct',
     'struct S { a: Float }\nstruct S { b: Float }\n',
     2, 8, 'duplicate definition of struct `S`'),
    ('redefine_builtin_struct',
     'struct Ray { a: Float }\n',
     1, 8, 'duplicate definition of struct `Ray`'),
    ('dup_param',
     'fn g(a: Float, a: Float) -> Float { return a; }\n',
     1, 16, 'duplicate parameter `a`'),
    ('dup_field',
     'struct S { a: Float, a: Vec3 }\n',
     1, 22, 'duplicate field `a` in struct `S`'),
    ('struct_missing_field',
     'struct S { a: Float, b: Float }\nfn f() -> S {\n    return S { a: 1.0 };\n}\n',
     3, 12, 'missing field `b` in `S` literal'),
    ('struct_unknown_field',
     'struct S { a: Float }\nfn f() -> S {\n    return S { a: 1.0, c: 2.0 };\n}\n',
     3, 24, 'struct `S` has no field `c`'),
    ('struct_field_type',
     'struct S { a: Float }\nfn f() -> S {\n    return S { a: true };\n}\n',
     3, 19, 'field `a`: expected `Float`, found `Bool`'),
    ('tuple_destructure_arity',
     'fn f() -> Float {\n    let (a, b, c) = (1.0, 2.0);\n    return a;\n}\n',
     2, 9, 'expected a tuple of 3 elements, found `(Float, Float)`'),
    ('destructure_non_tuple',
     'fn f() -> Float {\n    let (a, b) = 1.0;\n    return a;\n}\n',
     2, 9, 'cannot destructure a value of type `Float`: it is not a tuple'),
    ('tuple_index_range',
     'fn f() -> Float {\n    let t = (1.0, 2.0);\n    return t.2;\n}\n',
     3, 12, 'tuple index 2 is out of range for `(Float, Float)`'),
    ('index_non_buffer',
     'fn f(v: Vec3) -> Float {\n    return v[0];\n}\n',
     2, 12, 'cannot index a value of type `Vec3`; only buffers can be indexed'),
    ('texture_outside_param',
     'fn f(t: Texture) -> Float {\n    return 1.0;\n}\n',
     1, 9, '`Texture` is only allowed as the type of a plugin `param`'),
    ('buffer_in_plugin',
     'texture checker {\n    param data: [Float];\n    fn eval(si: Surface) -> Spectrum { return Spectrum(1.0); }\n}\n',
     2, 17, 'buffers cannot be used in plugins; a buffer type is only allowed as a parameter of a top-l'),
    ('buffer_in_plugin_fn',
     'texture checker {\n    fn eval(si: Surface) -> Spectrum { return Spectrum(1.0); }\n    fn helper(b: [Float]) -> Float { return b[0]; }\n}\n',
     3, 18, 'buffers cannot be used in plugins; a buffer type is only allowed as a parameter of a top-l'),
    ('buffer_in_let',
     'fn f() {\n    let x: [Float] = 1.0;\n}\n',
     2, 12, 'a buffer type is only allowed as a parameter of a top-level `fn`'),
    ('plugin_missing_fn',
     'bsdf nothing {\n    fn eval(si: Surface, wo: Vec3) -> Spectrum { return Spectrum(0.0); }\n    fn pdf(si: Surface, wo: Vec3) -> Float { return 0.0; }\n}\n',
     1, 6, 'bsdf `nothing` is missing the required function `fn sample(si: Surface, u1: Float, u2: Vec'),
    ('plugin_wrong_sig',
     'texture tex {\n    fn eval(si: Surface, uv: Vec2) -> Spectrum {\n        return Spectrum(0.0);\n    }\n}\n',
     2, 8, '`tex.eval` has the wrong signature: expected `fn eval(si: Surface) -> Spectrum`, found `ev'),
    ('plugin_wrong_ret',
     'import render.integrator;\nintegrator path {\n    fn sample(scene: Scene, ray: Ray, sampler: Sampler) -> Float {\n        return 0.0;\n    }\n}\n',
     3, 8, '`path.sample` has the wrong signature: expected `fn sample(scene: Scene, ray: Ray, sampler: Sampler) -> Spectrum`'),
    ('unknown_plugin_kind',
     'shader foo {\n    fn eval(si: Surface) -> Spectrum { return Spectrum(0.0); }\n}\n',
     1, 1, 'unknown plugin kind `shader`; expected one of `bsdf`, `emitter`, `texture`, `integrator`'),
    ('plugin_param_unknown_type',
     'texture tex {\n    param scale: Flot = 1.0;\n    fn eval(si: Surface) -> Spectrum { return Spectrum(scale); }\n}\n',
     2, 18, 'unknown type `Flot`'),
    ('plugin_param_struct',
     'texture tex {\n    param r: Ray;\n    fn eval(si: Surface) -> Spectrum { return Spectrum(0.0); }\n}\n',
     2, 14, 'plugin param `r` cannot have type `Ray`; expected `Float`, `Int`, `UInt`, `UInt64`, `Bool`'),
    ('plugin_param_bad_default',
     'texture tex {\n    param scale: Float = true;\n    fn eval(si: Surface) -> Spectrum { return Spectrum(scale); }\n}\n',
     2, 26, 'the default of plugin param `scale` must be a constant of type `Float`'),
    ('assign_plugin_param',
     'texture tex {\n    param scale: Float = 1.0;\n    fn eval(si: Surface) -> Spectrum {\n        scale = 2.0;\n        return Spectrum(scale);\n    }\n}\n',
     4, 9, 'cannot assign to plugin param `scale`'),
    ('texture_as_value',
     'texture tex {\n    param t: Texture = 0.5;\n    fn eval(si: Surface) -> Spectrum {\n        let x = t;\n        return x;\n    }\n}\n',
     4, 17, 'texture `t` must be called with a `Surface`: `t(si)`'),
    ('texture_bad_arg',
     'texture tex {\n    param t: Texture = 0.5;\n    fn eval(si: Surface) -> Spectrum {\n        return t(1.0);\n    }\n}\n',
     4, 18, 'texture `t` must be called with a `Surface`, found `Float`'),
    ('unknown_trait',
     'fn f() {\n    if const hyperspectral { }\n}\n',
     2, 14, 'unknown trait `hyperspectral`; expected one of `mono`, `rgb`, `spectral`, `polarized`'),
    ('range_float',
     'fn f() {\n    for i in 0..2.5 { }\n}\n',
     2, 17, 'range bounds must be `Int`, found `Float`'),
    ('assign_loop_var',
     'fn f() {\n    for i in 0..4 {\n        i = 2;\n    }\n}\n',
     3, 9, 'cannot assign to loop variable `i`'),
    ('int_overflow',
     'fn f() -> Int {\n    return 3000000000;\n}\n',
     2, 12, 'integer literal `3000000000` is out of range for `Int`'),
    ('recursion',
     'fn f(x: Float) -> Float {\n    return f(x);\n}\n',
     2, 12, 'recursion is not supported: `f` -> `f`'),
    ('mutual_recursion',
     'fn f(x: Float) -> Float {\n    return g(x);\n}\nfn g(x: Float) -> Float {\n    return f(x);\n}\n',
     5, 12, 'recursion is not supported: `f` -> `g` -> `f`'),
    ('sqrt_bool',
     'fn f(b: Bool) -> Float {\n    return sqrt(b);\n}\n',
     2, 17, '`sqrt` expects `Float`, a vector or `Spectrum`, found `Bool`'),
    ('vec_ctor_count',
     'fn f() -> Vec3 {\n    return Vec3(1.0, 2.0);\n}\n',
     2, 12, '`Vec3` needs 3 components, found 2'),
    ('select_cond',
     'fn f(x: Float) -> Float {\n    return select(x, 1.0, 2.0);\n}\n',
     2, 19, 'argument 1 of `select`: expected `Bool`, found `Float`'),
    ('int_float_mix',
     'fn f(i: Int, x: Float) -> Float {\n    return i * x;\n}\n',
     2, 12, 'cannot multiply `Int` and `Float`'),
    ('method_unknown',
     'fn f(v: Vec3) -> Float {\n    return v.lenght();\n}\n',
     2, 14, 'unknown function `lenght`'),
    ('shift_float',
     'fn f(x: Float) -> Float {\n    return x << 2;\n}\n',
     2, 12, 'cannot shift `Float` by `Int`'),
    ('type_as_value',
     'fn f() -> Float {\n    return Float;\n}\n',
     2, 12, '`Float` is a type, not a value'),
    ('dup_plugin',
     'texture a {\n    fn eval(si: Surface) -> Spectrum { return Spectrum(0.0); }\n}\ntexture a {\n    fn eval(si: Surface) -> Spectrum { return Spectrum(0.0); }\n}\n',
     4, 9, 'duplicate definition of plugin `a`'),
]


@pytest.mark.parametrize("name,src,line,col,message", CASES, ids=[c[0] for c in CASES])
def test_diagnostic(name: str, src: str, line: int, col: int, message: str) -> None:
    filename = f"{name}.rdsl"
    with pytest.raises(CompileError) as info:
        compile_to_ir(src, filename=filename)
    diag = info.value.diagnostics[0]
    assert message in diag.message
    assert (diag.loc.file, diag.loc.line, diag.loc.col) == (filename, line, col), diag.format()
    text = str(info.value)
    assert text.startswith(f"{filename}:{line}:{col}: error: ")
    # the source line is quoted with a caret under the column
    lines = text.splitlines()
    assert len(lines) == 3 and lines[2].index("^") == 4 + col - 1


def test_check_raises_the_same_error() -> None:
    with pytest.raises(CompileError, match="unknown identifier `y`"):
        check("fn f() -> Float { return y; }\n", filename="c.rdsl")


def test_import_missing_file(tmp_path: Path) -> None:
    main = tmp_path / "main.rdsl"
    main.write_text("import nothere;\nfn f() -> Float { return 1.0; }\n")
    with pytest.raises(CompileError) as info:
        compile_to_ir(main)
    d = info.value.diagnostics[0]
    assert "cannot find module `nothere`" in d.message
    assert (d.loc.file, d.loc.line, d.loc.col) == (str(main), 1, 1)


def test_import_missing_nested(tmp_path: Path) -> None:
    main = tmp_path / "main.rdsl"
    main.write_text("// header\n  import bsdf.nothere;\n")
    with pytest.raises(CompileError) as info:
        compile_to_ir(main)
    d = info.value.diagnostics[0]
    assert "cannot find module `bsdf.nothere`" in d.message and "bsdf/nothere.rdsl" in d.message
    assert (d.loc.line, d.loc.col) == (2, 3)


def test_import_cycle(tmp_path: Path) -> None:
    (tmp_path / "a.rdsl").write_text("import b;\nfn fa() -> Float { return 1.0; }\n")
    (tmp_path / "b.rdsl").write_text("fn fb() -> Float { return 2.0; }\nimport a;\n")
    with pytest.raises(CompileError) as info:
        compile_to_ir(tmp_path / "a.rdsl")
    d = info.value.diagnostics[0]
    assert "import cycle: a.rdsl -> b.rdsl -> a.rdsl" in d.message
    assert (d.loc.file, d.loc.line, d.loc.col) == (str(tmp_path / "b.rdsl"), 2, 1)


def test_error_in_imported_file_points_there(tmp_path: Path) -> None:
    (tmp_path / "lib.rdsl").write_text("fn g() -> Float {\n    return true;\n}\n")
    main = tmp_path / "main.rdsl"
    main.write_text("import lib;\nfn f() -> Float { return g(); }\n")
    with pytest.raises(CompileError) as info:
        compile_to_ir(main)
    d = info.value.diagnostics[0]
    assert "expected `Float`, found `Bool`" in d.message
    assert (d.loc.file, d.loc.line, d.loc.col) == (str(tmp_path / "lib.rdsl"), 2, 12)


def test_duplicate_across_files(tmp_path: Path) -> None:
    (tmp_path / "lib.rdsl").write_text("fn g(x: Float) -> Float { return x; }\n")
    main = tmp_path / "main.rdsl"
    main.write_text("import lib;\nfn g(y: Float) -> Float { return y; }\n")
    with pytest.raises(CompileError) as info:
        compile_to_ir(main)
    d = info.value.diagnostics[0]
    assert "duplicate definition of `g(Float) -> Float`" in d.message
    assert d.loc.line == 2 and d.loc.col == 4
