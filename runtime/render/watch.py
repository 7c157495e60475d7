"""``rdsl render --watch``: after the first image, poll the files the scene is made of and
render again when one of them changes, until Ctrl-C.

What is watched is what the last load and compile read: the scene XML and its includes,
the meshes, images and spectra it loaded, the places a file was looked for and not found
(runtime/scene/reads.py), and every ``.rdsl`` file the render kernel was compiled from
(``Module.source_files``: the files the kernel cache key hashes), so a plugin the kernel
imports is watched as soon as a scene uses it.

An update does no more than the change needs.  A file whose modification time changed but
whose content did not is ignored.  When only ``.rdsl`` sources changed, the loaded scene is
kept (buffers, Embree scene) and the kernels are compiled again: the cache key tells
whether they did change.  When a scene file changed, the scene is reloaded, taking unchanged
meshes and images from the previous load and its Embree scene when the geometry is the
same; the kernels come from the cache unless what they are compiled from changed (in the
generic build, the CLI's default with --watch, a parameter value is read at run time, so
editing one never compiles).  A quick low-sample image is written first, then the full one;
an edit during a render cancels it.  A broken scene or plugin prints its diagnostic and
the last good image stays until a fix.
"""

from __future__ import annotations

import hashlib
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

from ...compiler.diagnostics import CompileError
from ..scene.reads import Stamp, recording, stamp
from .image import write_render
from .renderer import RenderCancelled, Scene

POLL_SECONDS = 0.2
SETTLE_SECONDS = 0.03  # an editor's save can be several writes (or a write and a rename)
PREVIEW_SECONDS = 0.3  # what the first, low-sample image after a change may take to render


@dataclass
class WatchJob:
    """What each render of the loop does: the ``rdsl render`` options."""

    out: Path  # the EXR; the PNG goes beside it
    spp: int | None = None  # None: the scene's sampler
    seed: int | None = None
    threads: int | None = None
    seconds_per_spp: float = 0.0  # of the last full render: sizes the first image


def _digest(path: Path) -> str | None:
    """A file's content, or a plugin folder's list of ``.rdsl`` files (a plugin file added
    or removed there may change which plugin a scene's name resolves to)."""
    try:
        if path.is_dir():
            names = "\n".join(sorted(p.name for p in path.glob("*.rdsl")))
            return hashlib.sha256(names.encode()).hexdigest()
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return None


class WatchedFiles:
    """The files watched: each one's stamp (size, mtime, inode) and content digest."""

    def __init__(self) -> None:
        self.stamps: dict[Path, Stamp] = {}
        self.digests: dict[Path, str | None] = {}

    def track(self, paths: Iterable[Path]) -> None:
        """Watch exactly ``paths``; those watched already keep their recorded state, so an
        edit made while they were being read is still seen."""
        paths = list(dict.fromkeys(paths))
        self.stamps = {p: self.stamps[p] if p in self.stamps else stamp(p) for p in paths}
        self.digests = {p: self.digests[p] if p in self.digests else _digest(p)
                        for p in paths}

    def changed(self) -> list[Path]:
        """The files whose stamp is not the recorded one."""
        return [p for p, s in self.stamps.items() if stamp(p) != s]

    def settle(self, changed: list[Path]) -> list[Path]:
        """Wait until ``changed`` stop changing, record their new state and return those
        whose content differs (a file touched but not edited is not among them)."""
        now = {p: stamp(p) for p in changed}
        while True:
            time.sleep(SETTLE_SECONDS)
            later = {p: stamp(p) for p in changed}
            if later == now:
                break
            now = later
        edited = []
        for p in changed:
            digest = _digest(p)
            if digest != self.digests[p]:
                edited.append(p)
            self.stamps[p], self.digests[p] = now[p], digest
        return edited


def preview_spp(spp: int, seconds_per_spp: float) -> int:
    """Samples per pixel of the quick first image after a change: a power of two that
    renders in about PREVIEW_SECONDS, at most a quarter of ``spp``; 0 when the full image
    takes little longer than that anyway."""
    if spp * seconds_per_spp <= 2 * PREVIEW_SECONDS:
        return 0
    n = 1
    while 2 * n * seconds_per_spp <= PREVIEW_SECONDS and 2 * n <= spp // 4:
        n *= 2
    return n


def _names(paths: list[Path], folder: Path) -> str:
    def name(p: Path) -> str:
        try:
            return str(p.relative_to(folder))
        except ValueError:
            return p.name
    shown = ", ".join(name(p) for p in paths[:3])
    return shown + (f" and {len(paths) - 3} more" if len(paths) > 3 else "")


def _message(e: Exception) -> str:
    """A diagnostic as the CLI prints it; an unexpected error as one line, no traceback
    (the loop goes on: the next edit may fix it)."""
    if isinstance(e, CompileError):
        return e.format()
    return "error: " + "".join(traceback.format_exception_only(type(e), e)).strip()


class Watcher:
    """The watch loop over one scene (see the module's docstring)."""

    def __init__(self, scene: Scene, job: WatchJob, out: TextIO | None = None,
                 err: TextIO | None = None) -> None:
        self.scene = scene
        self.job = job
        self.out = out or sys.stdout
        self.err = err or sys.stderr
        self.files = WatchedFiles()
        self.files.track(self._sources(scene))
        self.updates = 0  # changes handled, rendered or failed
        self.scene_stale = False  # the scene's files changed but did not load

    @staticmethod
    def _sources(scene: Scene) -> list[Path]:
        module = scene.compile()
        folders = [scene.path.parent.resolve(),
                   *(Path(p).resolve() for p in scene.plugins if Path(p).is_dir())]
        return [*scene.reads.files, *module.source_files, *folders]

    def run(self, poll: float = POLL_SECONDS, max_updates: int | None = None,
            stop: threading.Event | None = None,
            on_poll: Callable[[int], None] | None = None) -> int:
        """Watch until Ctrl-C (or, for tests and embedding: ``stop`` is set or
        ``max_updates`` changes were handled; ``on_poll(i)`` runs before the i-th poll).
        Returns the exit status: 0."""
        print(f"watching {len(self.files.stamps)} files for changes (Ctrl-C to stop)",
              file=self.out, flush=True)
        i = 0
        try:
            while not (stop is not None and stop.is_set()) and \
                    (max_updates is None or self.updates < max_updates):
                if on_poll is not None:
                    on_poll(i)
                i += 1
                changed = self.files.changed()
                if not changed:
                    if stop is not None:
                        stop.wait(poll)
                    else:
                        time.sleep(poll)
                    continue
                detected = time.perf_counter()
                edited = self.files.settle(changed)
                if not edited:
                    print(f"{_names(changed, self.scene.path.parent)}: touched, content "
                          "unchanged; image kept", file=self.out, flush=True)
                    continue
                self.updates += 1
                self.update(edited, detected)
        except KeyboardInterrupt:
            print("\nwatch: stopped", file=self.out, flush=True)
        return 0

    def update(self, edited: list[Path], detected: float) -> None:
        """Bring the image up to date after ``edited`` changed (detected at ``detected``,
        a ``time.perf_counter()``)."""
        old = self.scene
        what = _names(edited, old.path.parent)
        kernel_files = set(old.compile().source_files)
        # only kernel sources changed (and the scene loaded last time): keep the scene
        reload = self.scene_stale or any(p not in kernel_files for p in edited)
        with recording() as attempt:
            try:
                if reload:
                    new = old.reload()
                    new.compile()
                else:
                    new = old
                    new.compile(again=True)
            except Exception as e:  # noqa: BLE001 - any broken edit: say why, keep the image
                self.scene_stale = self.scene_stale or reload
                self.files.track([*self.files.stamps, *attempt.files,
                                  *_kernel_sources(old)])
                print(f"{what} changed: {_message(e)}\nwatch: the image is unchanged; "
                      "waiting for a fix", file=self.err, flush=True)
                return
        self.scene, self.scene_stale = new, False
        self.files.track(self._sources(new))
        how = []
        if reload:
            how.append("scene reloaded" + (", geometry reused" if new.geometry_reused else ""))
        how.append("kernels from cache" if new.from_cache
                   else f"kernels compiled in {new.compile_seconds:.2f} s")
        print(f"{what} changed: {'; '.join(how)}", end="", file=self.out, flush=True)
        self.render(new, detected)

    def render(self, scene: Scene, detected: float) -> None:
        """A quick image then the full one, each written as soon as it is done; an edit
        seen during a render cancels it (the loop handles the edit next)."""
        job = self.job
        spp = int(job.spp or scene.spp)
        first = preview_spp(spp, job.seconds_per_spp)
        try:
            if first:
                self._write(scene, scene.render(spp=first, seed=job.seed, threads=job.threads,
                                                cancel=self._stale))
                print(f"; first image ({first} spp) in {time.perf_counter() - detected:.2f} s",
                      end="", file=self.out, flush=True)
            t0 = time.perf_counter()
            img = scene.render(spp=spp, seed=job.seed, threads=job.threads,
                               cancel=self._stale)
        except RenderCancelled:
            print("; cancelled by a newer edit", file=self.out, flush=True)
            return
        job.seconds_per_spp = (time.perf_counter() - t0) / spp
        self._write(scene, img)
        print(f"; {spp} spp in {time.perf_counter() - detected:.2f} s; wrote {job.out}",
              file=self.out, flush=True)

    def _stale(self) -> bool:
        return bool(self.files.changed())

    def _write(self, scene: Scene, img: Any) -> None:
        try:
            write_render(self.job.out, img, scene.channel_names)
        except OSError as e:
            raise CompileError(f"{self.job.out}: cannot write the image: "
                               f"{e.strerror or e}") from None


def _kernel_sources(scene: Scene) -> list[Path]:
    """The .rdsl files of the scene's kernel as last generated, for a compile that failed
    before ``jit`` could say which files it read."""
    from ...compiler.sources import source_files

    text = getattr(scene, "kernel_src", None)
    if text is None:
        return []
    return source_files(text, getattr(scene, "search_paths", ()),
                        filename=str(scene.path.with_suffix(".rdsl")))


def watch(scene: Scene, job: WatchJob, **options: Any) -> int:
    """Watch ``scene`` (rendered once already, to ``job.out``) and render it again on each
    change; ``options`` go to :meth:`Watcher.run`.  Returns the exit status."""
    return Watcher(scene, job).run(**options)
