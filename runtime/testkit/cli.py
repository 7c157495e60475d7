"""``rdsl test-plugin FILE.rdsl``: find the plugin the file declares (a ``bsdf``, an
``emitter``, a ``texture`` or an ``integrator``), compile it as the renderer calls it in the chosen variant,
run the checks of its kind, print one row per check and case and a summary line; the exit
status is 1 when a check fails.

:func:`add_commands` declares the subcommand on the top-level parser of ``rdsl/cli.py``."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ...compiler.diagnostics import CompileError
from ...compiler.ir import Loc
from ...core.color import VARIANTS
from .common import Options
from .harness import KINDS, Declaration, Harness, declarations
from .report import Row, summary, table


def add_commands(sub: argparse._SubParsersAction) -> dict[str, Callable[[Any], int]]:
    """Add ``test-plugin`` to ``sub``; returns its handler by name."""
    t = sub.add_parser("test-plugin", help="check a BSDF, emitter, texture or integrator "
                       "plugin: chi-square of its sampling, energy, NaN/Inf sweeps")
    t.add_argument("file", help="the plugin's .rdsl file")
    t.add_argument("--variant", default="rgb", help=", ".join(VARIANTS) + " (default: rgb)")
    t.add_argument("--target", default="host")
    t.add_argument("-p", dest="params", action="append", default=[], metavar="NAME=VALUE",
                   help="a value for one of the plugin's params (colours and vectors as "
                        "x,y,z); the others take their defaults")
    t.add_argument("--plugin", default=None, help="which plugin, if the file declares several")
    t.add_argument("--samples", type=int, default=Options.samples,
                   help=f"samples per chi-square and energy case (default {Options.samples})")
    from .stress import add_command as add_stress

    return {"test-plugin": test_plugin_command, **add_stress(sub)}


def _at(path: Path | str, line: int = 0, col: int = 0) -> Loc:
    """A diagnostic's location: a file (line 0) or a line of it."""
    return Loc(str(path), line, col)


def choose(path: Path, wanted: str | None) -> Declaration:
    """The plugin of ``path`` to test: the only one it declares, or the one named."""
    if path.suffix != ".rdsl":
        raise CompileError("expected a plugin's .rdsl file", _at(path))
    if not path.is_file():
        raise CompileError("no such file", _at(path))
    found = declarations(path)
    if wanted is not None:
        named = [d for d in found if d.name == wanted]
        if not named:
            raise CompileError(f"no plugin `{wanted}` here (declared: "
                               f"{', '.join(d.name for d in found) or 'none'})", _at(path))
        found = named
    if not found:
        raise CompileError("the file declares no plugin; expected `bsdf NAME {`, "
                           "`emitter NAME {`, `texture NAME {` or `integrator NAME {`", _at(path))
    if len(found) > 1:
        raise CompileError(f"the file declares several plugins ("
                           f"{', '.join(d.name for d in found)}); choose one with --plugin",
                           _at(path))
    decl = found[0]
    if decl.kind not in KINDS and decl.kind != "integrator":
        raise CompileError(f"`rdsl test-plugin` tests {', '.join(KINDS)} and integrator "
                           "plugins, not "
                           f"{decl.kind} `{decl.name}`", _at(path, decl.line, 1))
    return decl


def _value(text: str, ptype: str) -> Any:
    parts = [x.strip() for x in text.split(",")]
    if ptype == "Bool":
        if text.lower() not in ("true", "false", "1", "0"):
            raise ValueError
        return text.lower() in ("true", "1")
    if ptype in ("Int", "UInt", "UInt64"):
        n = int(text)
        if n < 0 and ptype != "Int":
            raise ValueError
        return n
    if ptype == "Float":
        return float(text)
    if ptype in ("Spectrum", "Texture"):
        if len(parts) not in (1, 3):
            raise ValueError
        return float(parts[0]) if len(parts) == 1 else tuple(float(x) for x in parts)
    if ptype.startswith("Vec"):
        n = int(ptype[3:])
        vals = tuple(float(x) for x in parts)
        if len(vals) == 1:
            vals = vals * n
        if len(vals) != n:
            raise ValueError
        return vals
    raise ValueError


def parse_params(items: list[str], decl: Declaration) -> dict[str, Any]:
    """``-p NAME=VALUE`` options, typed by the plugin's params."""
    declared = {p.name: p for p in decl.params}
    out: dict[str, Any] = {}
    for item in items:
        name, eq, text = item.partition("=")
        name = name.strip()
        if not eq:
            raise CompileError(f"-p {item}: expected NAME=VALUE")
        if name not in declared:
            raise CompileError(f"-p {item}: {decl.kind} `{decl.name}` ({decl.where}) "
                               f"has no param `{name}` (its params: "
                               f"{', '.join(declared) or 'none'})")
        p = declared[name]
        try:
            out[name] = _value(text.strip(), p.type)
        except ValueError:
            raise CompileError(f"-p {item}: param `{name}` ({p.loc}) is declared "
                               f"`{p.type}`; `{text}` is not a `{p.type}` value") from None
    return out


def run_checks(h: Harness, opts: Options) -> list[Row]:
    """The rows of every check of ``h``'s kind."""
    from .bsdf_checks import check_bsdf
    from .emitter_checks import check_emitter
    from .texture_checks import check_texture

    check = {"bsdf": check_bsdf, "emitter": check_emitter, "texture": check_texture}
    return check[h.decl.kind](h, opts)


def test_plugin_command(args: Any) -> int:
    from ...compiler.build import Build

    build = Build.of(args.target, args.variant)  # a bad name fails before the file is read
    decl = choose(Path(args.file), args.plugin)
    if args.samples < 1000:
        raise CompileError(f"--samples {args.samples}: at least 1000 are needed")
    opts = Options(samples=args.samples, params=parse_params(args.params, decl))
    if decl.kind == "integrator":
        from .integrator_checks import check_integrator

        print(f"integrator `{decl.name}` ({decl.where}), variant {build.model.name}, "
              f"target {build.target.name}")
        rows = check_integrator(decl, build.model.name, build.target, opts)
        return _report(decl.name, build, rows)
    h = Harness(variant=build.model.name, target=build.target, decl=decl)
    t0 = time.perf_counter()
    h.module(opts.params)  # compile first: a mistake in the plugin is a diagnostic here
    print(f"{decl.kind} `{decl.name}` ({decl.where}), variant {build.model.name}, "
          f"target {build.target.name}: compiled in {time.perf_counter() - t0:.1f} s")
    return _report(decl.name, build, run_checks(h, opts))


def _report(name: str, build: Any, rows: list[Row]) -> int:
    """Print the table and the summary; the exit status."""
    print(table(rows))
    print(summary(f"{name} ({build.model.name})", rows))
    sys.stdout.flush()
    return 1 if any(r.failed for r in rows) else 0
