"""Facts the documents state about the code, checked against the code.

Pass order: README.md and docs/*.md state it on a line of its own,

    Pipeline: [specialize] → inline → optimize → lift → ...

pass names separated by `→`, a bracketed name being a pass that runs only sometimes
(`specialize`: when compiling for a scene).  Such a line must name the passes of
``pipeline()`` in its order: with brackets dropped, the pipeline for a scene, and without the
bracketed names, the one without.  A line with no brackets may state either.

IR listings and diagnostics: the examples of docs/ir.md are the printer's output for the
golden programs, and the diagnostic of docs/language.md is a golden one.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from rdsl.compiler.build import Build
from rdsl.compiler.driver import frontend, pipeline
from rdsl.compiler.printer import print_function
from rdsl.core.scene_spec import SceneSpec

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
# the documents that must state the order
REQUIRED = ["README.md", "docs/ir.md", "docs/renderer.md", "docs/walkthrough.md"]
PIPELINE_LINE = re.compile(r"^\s*Pipeline: (.+)$", re.MULTILINE)


def _stated(path: Path) -> list[str]:
    return PIPELINE_LINE.findall(path.read_text())


@pytest.mark.parametrize("name", REQUIRED)
def test_the_document_states_the_pass_order(name: str) -> None:
    assert _stated(ROOT / name), f"{name} has no `Pipeline: ...` line"


@pytest.mark.parametrize("path", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_stated_pass_order_is_pipeline(path: Path) -> None:
    with_scene = [p.name for p in pipeline(Build.of("sse4", "rgb"), SceneSpec())]
    without = [p.name for p in pipeline(Build.of("sse4", "rgb"))]
    for line in _stated(path):
        names = [n.strip() for n in line.split("→")]
        full = [n.strip("[]") for n in names]
        always = [n for n in names if not n.startswith("[")]
        if full != always:
            ok = full == with_scene and always == without
        else:
            ok = full in (with_scene, without)
        assert ok, (f"{path.name} states `{line}`, but pipeline() runs "
                    f"{' → '.join(with_scene)} (for a scene; without: {' → '.join(without)})")


def _listings(path: Path) -> list[str]:
    return [b for b in re.findall(r"^```\n(.*?)^```$", path.read_text(), re.MULTILINE | re.DOTALL)
            if b.startswith("func @")]


def test_ir_md_listings_are_printer_output() -> None:
    lerp, count = _listings(ROOT / "docs" / "ir.md")
    module = frontend(ROOT / "tests" / "golden" / "lerp.rdsl")
    printed = print_function(module.functions["lerp"]).replace(f"{ROOT}/", "")
    assert lerp == printed
    golden = (ROOT / "tests" / "golden" / "loop.expected").read_text()
    assert golden.startswith("// ----- after lower -----\n" + count)


def test_language_md_diagnostic_is_the_golden_one() -> None:
    text = (ROOT / "docs" / "language.md").read_text()
    golden = (ROOT / "tests" / "golden" / "diagnostics" / "type_error.expected").read_text()
    assert f"```\n{golden}```\n" in text
