"""Where a cold compile's CPU goes: the rdsl renders of compat sheets (tests/compat), each
phase's CPU seconds (``time.process_time``, nested phases subtracted from their callers).

    RDSL_CACHE_DIR=$(mktemp -d) python bench/compile_phases.py plastic,diffuse,textures,area

Run it from a checkout's root (with ``PYTHONPATH`` naming another checkout's package to time
that one); an empty cache folder makes every phase cold.
"""

from __future__ import annotations

import collections
import functools
import importlib
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("RDSL_QUICK", "1")  # the test suite's tier
sys.path.insert(0, str(Path.cwd() / "tests" / "compat"))

SELF: collections.Counter[str] = collections.Counter()
_stack: list[float] = []

PHASES = [("rdsl.compiler.driver", "frontend"), ("rdsl.compiler.driver", "run_passes"),
          ("rdsl.compiler.backends.llvm", "lower_module"),
          ("llvmlite.ir.module", "Module.__repr__"),
          ("llvmlite.binding", "parse_assembly"),
          ("llvmlite.binding.targets", "TargetMachine.emit_object"),
          ("rdsl.compiler.backends.clib", "link_shared"),
          ("rdsl.compiler.precompute", "tabulate"), ("rdsl.runtime.api", "jit"),
          ("rdsl.runtime.render.renderer", "load_scene"),
          ("rdsl.runtime.render.renderer", "Scene.render")]


def _timed(label: str, f):
    @functools.wraps(f)
    def g(*a, **k):
        t = time.process_time()
        _stack.append(0.0)
        try:
            return f(*a, **k)
        finally:
            dt = time.process_time() - t
            SELF[label] += dt - _stack.pop()
            if _stack:
                _stack[-1] += dt
    return g


def instrument() -> None:
    """Wrap each phase where its callers look it up (module attributes, methods)."""
    for modname, attr in PHASES:
        owner = importlib.import_module(modname)
        if "." in attr:
            cls, attr = attr.split(".")
            owner = getattr(owner, cls)
        setattr(owner, attr, _timed(f"{modname.rsplit('.', 1)[-1]}.{attr}",
                                    getattr(owner, attr)))


def main() -> None:
    from _suite import BY_NAME

    if len(sys.argv) != 2 or sys.argv[1] in ("-h", "--help"):
        sys.exit(f"usage: python bench/compile_phases.py SHEET[,SHEET...]\n"
                 f"sheets: {', '.join(sorted(BY_NAME))}")
    names = sys.argv[1].split(",")
    unknown = [n for n in names if n not in BY_NAME]
    if unknown:
        sys.exit(f"no compat sheet {', '.join(map(repr, unknown))}; the sheets: "
                 f"{', '.join(sorted(BY_NAME))}")
    instrument()
    from _sheet import rdsl_images

    t0 = time.process_time()
    for name in names:
        t = time.process_time()
        rdsl_images(BY_NAME[name])
        print(f"{name}: {time.process_time() - t:.2f} s", flush=True)
    total = time.process_time() - t0
    for label, s in SELF.most_common():
        print(f"{s:7.2f} {label}")
    print(f"{total - sum(SELF.values()):7.2f} the rest\n{total:7.2f} in all (CPU seconds)")


if __name__ == "__main__":
    main()
