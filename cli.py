"""The ``rdsl`` command line: the compiler's ``check``, ``ir`` and ``compile`` and the
runtime's ``render`` and ``test-plugin``, on one parser.

It sits above both layers, so that the compiler never imports the runtime.  User mistakes
print diagnostics and exit with status 1; they never show a traceback.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from collections.abc import Callable
from typing import Any

from .compiler import cli as compiler_cli
from .compiler.diagnostics import CompileError, InternalError
from .runtime.render import bench as bench_cli
from .runtime.render import cli as render_cli
from .runtime.testkit import cli as testkit_cli


def parser() -> tuple[argparse.ArgumentParser, dict[str, Callable[[Any], int]]]:
    """The ``rdsl`` argument parser and each subcommand's handler by name."""
    p = argparse.ArgumentParser(prog="rdsl", description="A compiler for physically based "
                                "rendering.")
    sub = p.add_subparsers(dest="cmd", required=True)
    commands = {**compiler_cli.add_commands(sub), **render_cli.add_commands(sub),
                **testkit_cli.add_commands(sub), **bench_cli.add_commands(sub)}
    return p, commands


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """A warning about the user's input (a UserWarning: its message names their file and
    line) prints as ``warning: ...``, not with the line of rdsl's code that raised it."""
    if not issubclass(category, UserWarning):
        return _default_show_warning(message, category, filename, lineno, file, line)
    text = str(message)  # `file:line: warning: ...` already says what it is
    print(text if ": warning: " in text else f"warning: {text}",
          file=sys.stderr if file is None else file)


_default_show_warning = warnings.showwarning


def main(argv: list[str] | None = None) -> int:
    """Run one ``rdsl`` subcommand; returns the exit status."""
    p, commands = parser()
    args = p.parse_args(argv)
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _show_warning
            return commands[args.cmd](args)
    except CompileError as e:
        print(e.format(), file=sys.stderr)
        return 1
    except InternalError as e:
        print(f"rdsl: {e}\nThis is a bug in rdsl; please report it with the input file.",
              file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    finally:
        sys.stdout.flush()


if __name__ == "__main__":
    sys.exit(main())
