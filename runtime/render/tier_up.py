"""Tiered compilation: a scene rendered again with quick-tier kernels has its full tier
built in the background, and switches to it when it is ready.

A small render whose kernels are not in the cache compiles the quick tier (LLVM O0,
``renderer.QUICK_SAMPLES``): the first image comes sooner, and its kernels run slower (15-30%
in docs/bench.md's table; 0.12 s against 0.060 s per Cornell-box render at 128x128 and 16
spp on an AMD EPYC host).  A one-off render should not pay the full tier's compile as
well; a loop of small renders (inverse rendering, a preview that is refined) should not
keep the slow kernels.  So the second render of a scene with
quick kernels starts :class:`TierUp`: another Python process compiles the full tier into
the kernel cache (a process, not a thread: the compiler's passes are Python and would hold
the interpreter lock, and llvmlite's LLVM is not safe to drive from two threads), and a
render that finds the job done loads the full tier from the cache and uses it from then on.
The results are the same bit for bit (neither tier uses fast-math: tests/test_quick_tier.py).

A job that fails leaves the quick tier in use and says why once (a warning).  A job still
running when this process exits goes on and fills the cache, so that the next run of the
script starts with the full tier; a job made stale (the scene's kernels were replaced) is
stopped (SIGTERM: the worker removes its partial entry; a complete entry is installed
atomically, so the cache never holds half a library).
"""

from __future__ import annotations

import pickle
import signal
import subprocess
import sys
import tempfile
import warnings
from typing import Any

# the renders of one scene with quick kernels after which the full tier is built
RENDERS_BEFORE_TIER_UP = 2


class TierUp:
    """One background build of a scene's full-tier kernels: ``jit(source, **options)``
    (``quick``: of its quick tier; runtime/render/prebuild.py's adjoint kernels)."""

    def __init__(self, source: str, options: dict[str, Any], quick: bool = False,
                 tables_for: Any = None) -> None:
        self.source, self.options, self.quick = source, options, quick
        # tables_for: a scene (its SceneSpec) whose values the generic kernels' tables are
        # then computed for, into the cache (runtime/tables.py)
        job = pickle.dumps((source, options, quick, tables_for))  # or none, if unpicklable
        # its messages go to a file: a pipe could fill up, or break when this process ends
        self.messages = tempfile.TemporaryFile()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", __name__], stdin=subprocess.PIPE,
            stdout=subprocess.DEVNULL, stderr=self.messages)
        try:
            self.proc.stdin.write(job)
            self.proc.stdin.close()
        except OSError:  # the worker died at start: done() reports it
            pass
        self.failure: str | None = None

    def done(self) -> bool:
        """Whether the build has ended (well or not)."""
        return self.proc.poll() is not None

    def load(self) -> Any | None:
        """The full-tier module, from the cache the worker filled; None if the build
        failed (with a warning saying why)."""
        from ..api import jit

        self.proc.wait()
        self.messages.seek(0)
        err = self.messages.read().decode(errors="replace").strip()
        self.messages.close()
        if self.proc.returncode != 0:
            self.failure = err.splitlines()[-1] if err else f"exit {self.proc.returncode}"
            warnings.warn("the background build of the full-tier kernels failed "
                          f"({self.failure}); rendering goes on with the quick tier",
                          stacklevel=3)
            return None
        return jit(self.source, quick=self.quick, **self.options)  # a cache hit

    def finish(self) -> bool:
        """Wait for the build to end; whether it succeeded (its kernels are in the cache)."""
        self.proc.wait()
        self.messages.close()
        return self.proc.returncode == 0

    def stop(self) -> None:
        """End the build now (its partial cache entry is removed)."""
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
        self.messages.close()


def _worker() -> int:
    """The background process: read ``(source, options, quick, tables_for)``, build that
    tier into the kernel cache (and the tables of a generic build for ``tables_for``).  SIGTERM raises SystemExit, so jit's cleanup removes a partial entry."""
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    source, options, quick, tables_for = pickle.load(sys.stdin.buffer)
    from ..api import jit

    try:
        mod = jit(source, quick=quick, **options)
        if tables_for is not None:
            import numpy as np

            from ..tables import fill_tables

            fill_tables(mod, tables_for, np.zeros(1, np.float32), source,
                        options.get("filename"), options.get("search_paths") or ())
    except Exception as e:  # one line for the warning: what failed, where
        lines = str(e).strip().splitlines()
        print(f"{type(e).__name__}: {lines[0] if lines else ''}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(_worker())
