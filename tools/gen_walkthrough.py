"""Run the command blocks of docs/walkthrough.md and, with no options, rewrite their outputs.

The walkthrough shows real commands next to what they print, in fenced blocks tagged
``console``::

    ```console
    $ rdsl check stdlib/bsdf/roughconductor.rdsl
    stdlib/bsdf/roughconductor.rdsl: ok
    ```

A line starting with ``$ `` is a command (continued on the next line while it ends with a
backslash, as in the shell); the lines after it, up to the next command or the end of the
block, are what it prints (stdout and stderr together).  Commands run one after the other, in
the order of the document (a later one may read what an earlier one wrote under ``out/``),
in ``bash`` from the repository root, with this Python's ``bin`` folder first on ``PATH`` (so
``rdsl`` is the checkout's) and ``LC_ALL=C`` (so ``sort`` orders the same everywhere).

Volatile text: ``...`` in an expected line matches any text within that line (as doctest's
ELLIPSIS, but never across lines), e.g. ``16 spp: ... paths/s)`` for a render's timing.
Regenerating keeps such a line as written while it still matches the new output.

``tests/test_walkthrough.py`` compares the outputs with the document.  When the compiler
changes on purpose, regenerate them and review the diff::

    python tools/gen_walkthrough.py            # rewrite docs/walkthrough.md in place
    python tools/gen_walkthrough.py --check    # only report the commands whose output differs
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
WALKTHROUGH = ROOT / "docs" / "walkthrough.md"
ELLIPSIS = "..."
TIMEOUT_S = 300


@dataclass(frozen=True)
class Command:
    """One ``$`` command of a console block and the output the document gives for it."""

    line: int  # 1-based line of the `$` in the document
    text: str  # the command, continuation lines included
    expected: tuple[str, ...]
    start: int  # 0-based index of the first output line in the document
    end: int  # 0-based index one past the last output line


def parse(markdown: str) -> list[Command]:
    """The commands of every ```console block of ``markdown``, in order."""
    lines = markdown.split("\n")
    commands: list[Command] = []
    i = 0
    while i < len(lines):
        if lines[i].strip() != "```console":
            i += 1
            continue
        i += 1
        while i < len(lines) and lines[i].strip() != "```":
            if not lines[i].startswith("$ "):
                raise ValueError(f"line {i + 1}: a console block must start with `$ `")
            first = i
            parts = [lines[i][2:]]
            while parts[-1].endswith("\\") and i + 1 < len(lines):
                i += 1
                parts.append(lines[i])
            i += 1
            start = i
            while i < len(lines) and lines[i].strip() != "```" and \
                    not lines[i].startswith("$ "):
                i += 1
            commands.append(Command(first + 1, "\n".join(parts), tuple(lines[start:i]),
                                    start, i))
        i += 1
    return commands


def run(command: str, root: Path = ROOT) -> list[str]:
    """What ``command`` prints, stdout and stderr together, one string per line."""
    env = dict(os.environ, LC_ALL="C",
               PATH=os.pathsep.join([str(Path(sys.executable).parent),
                                     os.environ.get("PATH", "")]))
    env.pop("LANGUAGE", None)
    proc = subprocess.run(["bash", "-c", command], cwd=root, env=env, text=True,
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                          timeout=TIMEOUT_S, check=False)
    out = proc.stdout.rstrip("\n")
    return out.split("\n") if out else []


def run_all(commands: list[Command], root: Path = ROOT) -> list[list[str]]:
    """The outputs of ``commands``, run in order."""
    return [run(c.text, root) for c in commands]


def line_matches(expected: str, got: str) -> bool:
    """Whether ``got`` is ``expected``, where each ``...`` of it stands for any text."""
    if ELLIPSIS not in expected:
        return expected == got
    pattern = ".*".join(re.escape(part) for part in expected.split(ELLIPSIS))
    return re.fullmatch(pattern, got) is not None


def output_matches(expected: tuple[str, ...] | list[str], got: list[str]) -> bool:
    """Whether every line matches, and there are as many."""
    return len(expected) == len(got) and all(map(line_matches, expected, got))


def refreshed(expected: tuple[str, ...], got: list[str]) -> list[str]:
    """``got``, keeping each expected line with ``...`` that still matches its line."""
    kept = list(expected) + [""] * max(0, len(got) - len(expected))
    return [e if ELLIPSIS in e and line_matches(e, g) else g for e, g in zip(kept, got)]


def regenerate(path: Path = WALKTHROUGH, root: Path = ROOT) -> list[Command]:
    """Rewrite the outputs in ``path``; returns the commands whose output changed."""
    lines = path.read_text().split("\n")
    commands = parse("\n".join(lines))
    outputs = run_all(commands, root)
    changed = [c for c, got in zip(commands, outputs) if not output_matches(c.expected, got)]
    for c, got in reversed(list(zip(commands, outputs))):
        lines[c.start:c.end] = refreshed(c.expected, got)
    path.write_text("\n".join(lines))
    return changed


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--check", action="store_true",
                    help="do not write; exit 1 if an output differs")
    ap.add_argument("file", nargs="?", type=Path, default=WALKTHROUGH)
    args = ap.parse_args(argv)
    if args.check:
        commands = parse(args.file.read_text())
        changed = [c for c, got in zip(commands, run_all(commands))
                   if not output_matches(c.expected, got)]
    else:
        changed = regenerate(args.file)
    for c in changed:
        print(f"{args.file}:{c.line}: {c.text.splitlines()[0]}")
    verb = "differ" if args.check else "rewritten"
    print(f"{len(changed)} of {len(parse(args.file.read_text()))} outputs {verb}")
    return 1 if args.check and changed else 0


if __name__ == "__main__":
    sys.exit(main())
