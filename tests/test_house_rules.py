"""The house rules that keep files readable (STYLE.md, issue 9): no Python file over 600
lines, and no function over 80 lines unless a comment right above it (``# long: why``)
gives the reason.  Tests, benchmarks, tools and examples count as well as the package."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAX_FILE_LINES = 600
MAX_FUNCTION_LINES = 80


def python_files() -> list[Path]:
    skip = {".git", "build", "out", "__pycache__"}
    return sorted(p for p in ROOT.rglob("*.py")
                  if not skip & set(p.relative_to(ROOT).parts) and ".egg-info" not in str(p))


def long_functions(path: Path) -> list[str]:
    """The functions of ``path`` over the limit with no ``# long:`` reason above them."""
    text = path.read_text()
    lines = text.splitlines()
    out = []
    for node in ast.walk(ast.parse(text)):
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        length = node.end_lineno - node.lineno + 1
        first = min([node.lineno] + [d.lineno for d in node.decorator_list])
        above = lines[first - 2].strip() if first >= 2 else ""
        if length > MAX_FUNCTION_LINES and not above.startswith("# long:"):
            out.append(f"{path.relative_to(ROOT)}:{node.lineno}: `{node.name}` is {length} "
                       f"lines (over {MAX_FUNCTION_LINES}: split it, or say why above it "
                       "with `# long: ...`)")
    return out


def test_no_file_is_over_600_lines():
    long = [f"{p.relative_to(ROOT)}: {n} lines" for p in python_files()
            if (n := len(p.read_text().splitlines())) > MAX_FILE_LINES]
    assert not long, "files over 600 lines (split them):\n" + "\n".join(long)


def test_no_function_is_over_80_lines_without_a_reason():
    found = [msg for p in python_files() for msg in long_functions(p)]
    assert not found, "\n".join(found)


def test_the_check_finds_a_long_function(tmp_path):
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_FUNCTION_LINES))
    plain = tmp_path / "plain.py"
    plain.write_text(f"def f():\n{body}\n")
    reasoned = tmp_path / "reasoned.py"
    reasoned.write_text(f"# long: a table of assignments\ndef f():\n{body}\n")
    global ROOT
    saved, ROOT = ROOT, tmp_path
    try:
        assert len(long_functions(plain)) == 1
        assert long_functions(reasoned) == []
    finally:
        ROOT = saved
