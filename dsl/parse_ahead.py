"""Parsing ahead on the other core: a cold compile parses its files in a forked helper too.

A compile with an empty cache parses every file it imports (a scene's kernel: ~30 stdlib
files, 0.8-1.3 s of lark in one process, the largest part of a cold first image after the
passes).  :func:`start` looks ahead, without parsing, at what a program will load (the
prelude, the main text and, depth first, the ``import`` lines of each file, found by a
regular expression and looked up as the loader does), and if enough of it is not in the
parse cache (``<cache>/ast/``) it forks a helper that parses those files in the *reverse*
of the loader's order and writes each one's AST to the cache.  The loader goes on as
before: :func:`rdsl.dsl.parser.parse` reads an entry the helper wrote instead of parsing,
so the two meet in the middle, and at most the file each is working on is parsed twice.
The result is the same AST (the cache holds what ``parse`` itself would store: the same
key and the same pickle); only who parsed it differs.

The guess can be wrong both ways (an import in a comment, a file not found): a file
guessed wrongly is one the helper parses for nothing, a file missed is one the loader
parses itself.  When the loader is done, :meth:`Helper.stop` ends the helper and collects
it (it finishes an entry it is writing, a millisecond), so nothing of it outlives the
compile; if the parent dies first, the helper stops after its file (it watches a pipe
whose other end the parent holds).  It takes its stdin/stdout/stderr from ``/dev/null``
(so that a caller reading the command's output sees its end when the command ends), and
gives up after ``DEADLINE_S``.  Off with
``RDSL_PARSE_AHEAD=0``, where ``os.fork`` is missing, with one CPU, or when the cache
cannot be written.
"""

from __future__ import annotations

import contextlib
import os
import re
import select
import warnings
from collections.abc import Callable
from pathlib import Path

ENV = "RDSL_PARSE_AHEAD"
MIN_FILES = 4  # fewer files to parse than this: not worth a fork
DEADLINE_S = 60  # the helper exits by then whatever happens (SIGALRM)
STOP_WAIT_S = 0.5  # how long :meth:`Helper.stop` waits for it to end

_IMPORT = re.compile(r"^[ \t]*import[ \t]+([A-Za-z_]\w*(?:[ \t]*\.[ \t]*[A-Za-z_]\w*)*)[ \t]*;",
                     re.MULTILINE)


class Helper:
    """A forked parser; :meth:`stop` ends it."""

    def __init__(self, pid: int, fd: int) -> None:
        self.pid, self.fd = pid, fd

    def stop(self) -> None:
        """End the helper now (it finishes an entry it is writing) and collect it, so
        that nothing of it runs or writes after the compile: up to ``STOP_WAIT_S``, then
        SIGKILL."""
        import signal
        import time

        if self.fd < 0:
            return
        os.close(self.fd)
        self.fd = -1
        with contextlib.suppress(ProcessLookupError):
            os.kill(self.pid, signal.SIGTERM)
        deadline = time.monotonic() + STOP_WAIT_S
        while True:
            try:
                done, _ = os.waitpid(self.pid, os.WNOHANG)
            except ChildProcessError:
                break
            if done:
                break
            if time.monotonic() > deadline:  # stuck: it may leave a temporary file
                with contextlib.suppress(ProcessLookupError):
                    os.kill(self.pid, signal.SIGKILL)
                with contextlib.suppress(ChildProcessError):
                    os.waitpid(self.pid, 0)
                break
            time.sleep(0.001)
        if self.pid in _children:
            _children.remove(self.pid)


_children: list[int] = []


def _reap() -> None:
    """Collect the helpers that have exited (no zombies left while the process runs)."""
    for pid in list(_children):
        try:
            done, _ = os.waitpid(pid, os.WNOHANG)
        except ChildProcessError:
            done = pid
        if done:
            _children.remove(pid)


def enabled() -> bool:
    return (os.environ.get(ENV, "1") != "0" and hasattr(os, "fork")
            and (os.cpu_count() or 1) > 1)


def planned_files(source: str, filename: str, prelude: list[Path],
                  import_dirs: Callable[[str], list[Path]]) -> list[tuple[str, str]]:
    """``(text, filename)`` of each file the loader will probably parse, in its order (the
    prelude, the main text, then depth first what each imports, looked up in
    ``import_dirs(importer)`` as the loader does); never raises.  Module-level helpers, not
    closures: a closure that calls itself is a reference cycle, which here would hold
    ``import_dirs`` and so the loader and every AST until the cycle collector ran
    (tests/test_compile_garbage.py)."""
    out: list[tuple[str, str]] = []
    seen: set[str] = set()
    for p in prelude:
        _read(p, import_dirs, out, seen)
    _visit(source, filename, f"<main>{filename}", import_dirs, out, seen)
    return out


def _visit(text: str, name: str, key: str, import_dirs: Callable[[str], list[Path]],
           out: list[tuple[str, str]], seen: set[str]) -> None:
    if key in seen:
        return
    seen.add(key)
    out.append((text, name))
    for m in _IMPORT.finditer(text):
        rel = Path(*re.split(r"[ \t]*\.[ \t]*", m.group(1))).with_suffix(".rdsl")
        found = next((d / rel for d in import_dirs(name) if (d / rel).is_file()), None)
        if found is not None:
            _read(found, import_dirs, out, seen)


def _read(path: Path, import_dirs: Callable[[str], list[Path]],
          out: list[tuple[str, str]], seen: set[str]) -> None:
    try:
        text, key = path.read_text(), str(path.resolve())
    except (OSError, RuntimeError, UnicodeDecodeError):
        return
    _visit(text, str(path), key, import_dirs, out, seen)


def start(source: str, filename: str, prelude: list[Path],
          import_dirs: Callable[[str], list[Path]]) -> Helper | None:
    """Fork a helper for the files of this program that the parse cache lacks, if there
    are at least ``MIN_FILES`` of them; None if not worth it or not possible."""
    from . import parser

    if not enabled():
        return None
    _reap()
    try:
        files = planned_files(source, filename, prelude, import_dirs)
        missing = [(t, n) for t, n in files if not parser.is_cached(t, n)]
        if len(missing) < MIN_FILES or not parser.cache_writable():
            return None
        parser.warm_up()  # lark's tables loaded before the fork: the helper starts parsing
        r, w = os.pipe()
    except (OSError, ValueError, RecursionError):
        return None
    try:
        with warnings.catch_warnings():  # Python 3.12+ warns of forking with threads; the
            # helper only parses and writes files (no lock of another thread's is needed)
            warnings.simplefilter("ignore", DeprecationWarning)
            pid = os.fork()
    except OSError:
        os.close(r)
        os.close(w)
        return None
    if pid == 0:  # the helper: never returns
        try:
            os.close(w)
            _detach(r)
            _help(r, reversed(missing))
        finally:
            os._exit(0)
    os.close(r)
    _children.append(pid)
    return Helper(pid, w)


def _help(fd: int, files) -> None:
    """Parse ``files`` into the cache until done or told to stop: SIGTERM ends the helper
    at once, unless it is writing an entry, which it finishes first (no half-written or
    stray temporary file); a closed pipe (the parent gone) stops it between files."""
    import signal

    from . import parser

    state = {"writing": False, "stop": False}

    def on_term(signum: int, frame: object) -> None:
        if not state["writing"]:
            os._exit(0)
        state["stop"] = True

    signal.signal(signal.SIGTERM, on_term)
    for text, name in files:
        if _stopped(fd):
            return
        entry = parser.parse_for_cache(text, name)
        if entry is not None:
            state["writing"] = True
            parser.store(*entry)
            state["writing"] = False
        if state["stop"]:
            return


def _detach(keep: int) -> None:
    """The helper's standard streams from /dev/null, its other descriptors closed (a
    pipe the caller reads to its end must not wait for the helper), and its deadline."""
    import signal

    signal.signal(signal.SIGALRM, signal.SIG_DFL)  # not a handler the caller set
    signal.alarm(DEADLINE_S)  # SIGALRM's default action ends the process
    null = os.open(os.devnull, os.O_RDWR)
    for fd in (0, 1, 2):
        os.dup2(null, fd)
    os.closerange(3, keep)
    os.closerange(keep + 1, 1 << 16)


def _stopped(fd: int) -> bool:
    """Whether the loader has finished (its end of the pipe closed: readable at EOF)."""
    ready, _, _ = select.select([fd], [], [], 0)
    return bool(ready)
