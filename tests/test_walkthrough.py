"""docs/walkthrough.md cannot drift: the commands of its ```console blocks are run, in order,
from the repository root, and what they print is compared with the text under them.

The format (parsed by ``tools/gen_walkthrough.py``, which holds the details): a line
``$ command`` (continued on the next line while it ends with a backslash) is followed by its
expected output, stdout and stderr together.  Volatile text is marked by ``...`` in an
expected line: it matches any text within that line (a render's time, whether its kernels
came from the cache), never a whole line or more.

When the compiler changes on purpose, run ``python tools/gen_walkthrough.py`` to rewrite the
outputs in place, and review the diff.  All commands run in one test, so that pytest-xdist
cannot split them (later commands read files that earlier ones wrote under ``out/``).
"""

from __future__ import annotations

import difflib
import re

import pytest
from rdsl.compiler.build import Build
from rdsl.compiler.driver import pipeline
from rdsl.core.scene_spec import SceneSpec
from rdsl.tools.gen_walkthrough import (
    WALKTHROUGH,
    Command,
    line_matches,
    output_matches,
    parse,
    refreshed,
    run_all,
)

REGENERATE = "If the change is intended, run `python tools/gen_walkthrough.py` and review the diff."


def test_walkthrough_commands_print_what_the_document_says() -> None:
    commands = parse(WALKTHROUGH.read_text())
    failures = []
    for c, got in zip(commands, run_all(commands)):
        if not output_matches(c.expected, got):
            diff = difflib.unified_diff(list(c.expected), got, "in the document", "printed now",
                                        lineterm="")
            failures.append(f"docs/walkthrough.md:{c.line}: $ {c.text}\n" + "\n".join(diff))
    if failures:
        pytest.fail("\n\n".join(failures) + f"\n\n{REGENERATE}", pytrace=False)


def test_walkthrough_covers_every_stage() -> None:
    text = WALKTHROUGH.read_text()
    commands = " ".join(c.text for c in parse(text))
    for needed in ("rdsl check", "--print-after all", "--emit llvm", "--emit asm",
                   "rdsl render"):
        assert needed in commands, f"the walkthrough no longer runs `{needed}`"
    headings = re.findall(r"^## .*$", text, re.MULTILINE)
    for name in {p.name for p in pipeline(Build.of("sse4", "rgb"), SceneSpec())}:
        assert any(f"`{name}`" in h for h in headings), f"no section for the pass `{name}`"


# -- the format itself -----------------------------------------------------------------------

DOC = """\
Text.

```console
$ echo one \\
    two
one two
$ printf 'a\\nb\\n'
a
b
```

```sh
$ not run
```
"""


def test_parse_reads_commands_continuations_and_outputs() -> None:
    commands = parse(DOC)
    assert [c.text for c in commands] == ["echo one \\\n    two", "printf 'a\\nb\\n'"]
    assert [c.expected for c in commands] == [("one two",), ("a", "b")]
    assert [c.line for c in commands] == [4, 7]
    lines = DOC.split("\n")
    assert lines[commands[1].start:commands[1].end] == ["a", "b"]


def test_commands_run_in_bash_from_the_root() -> None:
    assert run_all(parse(DOC)) == [["one two"], ["a", "b"]]


def test_ellipsis_matches_within_a_line_only() -> None:
    assert line_matches("16 spp: ... paths/s", "16 spp: 0.2 s (1.2 M paths/s")
    assert not line_matches("16 spp: ... paths/s", "32 spp: 0.2 s (1.2 M paths/s")
    assert not line_matches("a.c", "abc")  # everything but `...` is literal
    assert not output_matches(("x ...",), ["x 1", "x 2"])
    assert output_matches(("x ...", "y"), ["x 1", "y"])


def test_regeneration_keeps_matching_ellipsis_lines() -> None:
    c = Command(1, "true", ("took ... s", "3 lines"), 0, 0)
    assert refreshed(c.expected, ["took 2.5 s", "4 lines", "new"]) == \
        ["took ... s", "4 lines", "new"]
    assert refreshed(c.expected, ["failed"]) == ["failed"]
