"""The Python API: ``rdsl.jit`` compiles (through the disk cache), ``rdsl.load`` loads what
``rdsl compile`` wrote.  Both return a :class:`Module` of callable :class:`Kernel` s."""

from __future__ import annotations

import atexit
import ctypes
import json
import os
import shutil
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..compiler.backends.base import ABI_VERSION
from ..compiler.diagnostics import CompileError
from ..compiler.sources import read_source
from ..core.color import MODELS, ColorModel
from .cache import STEM, cache_dir, cache_key, entry_complete
from .kernel import Kernel

if TYPE_CHECKING:
    from ..compiler.build import Build
    from ..compiler.targets import Target

__all__ = ["Kernel", "Module", "jit", "load"]

# path -> (inode, mtime) of every library dlopen'ed: dlopen returns the old handle for a
# path it has already loaded, so a rebuilt library is loaded through a private copy
_LOADED: dict[str, tuple[int, int]] = {}
_COPIES: list[tempfile.TemporaryDirectory] = []


def _dlopen(so: Path) -> ctypes.CDLL:
    key = str(so.resolve())
    st = so.stat()
    ident = (st.st_ino, st.st_mtime_ns)
    seen = _LOADED.get(key)
    if seen is None or seen == ident:
        _LOADED[key] = ident
        return ctypes.CDLL(key)
    tmp = tempfile.TemporaryDirectory(prefix="rdsl-lib-")
    _COPIES.append(tmp)
    copy = Path(tmp.name) / so.name
    shutil.copy2(so, copy)
    return ctypes.CDLL(str(copy))


class _Namespace:
    """``mod.roughconductor.eval`` for a kernel named ``roughconductor.eval``."""

    def __init__(self, module: Module, prefix: str) -> None:
        self._module, self._prefix = module, prefix

    def __getattr__(self, name: str) -> Any:
        return self._module._lookup(f"{self._prefix}.{name}")

    def __dir__(self) -> list[str]:
        p = self._prefix + "."
        return sorted({k[len(p):].split(".")[0] for k in self._module.kernels
                       if k.startswith(p)})


class Module:
    """A loaded library of kernels: ``mod["bsdf.eval"]``, ``mod.kernels``, ``mod.lerp``."""

    def __init__(self, manifest: dict[str, Any], lib: ctypes.CDLL, path: Path | None = None,
                 from_cache: bool = False, compile_seconds: float = 0.0) -> None:
        self.manifest = manifest
        self.path = path
        self.target: str = manifest["target"]
        self.width: int = int(manifest["width"])
        # the manifest names the variant; load() has checked that the name is known
        variant = manifest.get("variant")
        self.model: ColorModel | None = None if variant is None else MODELS[variant]
        self.from_cache = from_cache
        self.compile_seconds = compile_seconds
        # the .rdsl files the kernels were compiled from (set by jit: what its cache key
        # hashes), which `rdsl render --watch` watches
        self.source_files: list[Path] = []
        self.quick = False  # built by the quick tier (jit(quick=True))
        self._lib = lib
        self.kernels: dict[str, Kernel] = {k["name"]: self._make_kernel(k, lib)
                                           for k in manifest["kernels"]}

    def _make_kernel(self, info: dict[str, Any], lib: Any) -> Kernel:
        return Kernel(self, info, lib)

    @property
    def variant(self) -> str | None:
        """The name of the variant the kernels were compiled for (None: no colours)."""
        return None if self.model is None else self.model.name

    def __repr__(self) -> str:
        return (f"<rdsl.Module {self.path or ''} target={self.target} width={self.width} "
                f"kernels=[{', '.join(self.kernels)}]>")

    @property
    def traces_rays(self) -> bool:
        """Whether the kernels query rays (and so need :meth:`bind_scene`): specialization
        removes every query from, e.g., a path tracer with ``max_depth`` 0."""
        try:
            ctypes.c_void_p.in_dll(self._lib, "rdsl_embree_scene")
        except ValueError:
            return False
        return True

    def bind_scene(self, scene: Any) -> None:
        """Point the library's ray queries (`trace`, `occluded`) at an Embree scene (an
        :class:`rdsl.runtime.embree.EmbreeScene`); kept alive as long as this module or one of
        its kernels is."""
        try:
            slot = ctypes.c_void_p.in_dll(self._lib, "rdsl_embree_scene")
        except ValueError:
            raise ValueError("this library traces no rays, so it takes no scene") from None
        slot.value = scene.handle
        self._scene = scene
        for k in self.kernels.values():  # a kernel outlives its module: the scene too
            k._scene = scene

    def __getitem__(self, name: str) -> Kernel:
        try:
            return self.kernels[name]
        except KeyError:
            raise KeyError(f"no kernel named `{name}` (kernels: "
                           f"{', '.join(self.kernels) or 'none'})") from None

    def __contains__(self, name: str) -> bool:
        return name in self.kernels

    def __iter__(self):
        return iter(self.kernels)

    def _lookup(self, name: str) -> Any:
        if name in self.kernels:
            return self.kernels[name]
        if any(k.startswith(name + ".") for k in self.kernels):
            return _Namespace(self, name)
        raise AttributeError(f"module has no kernel `{name}` (kernels: "
                             f"{', '.join(self.kernels) or 'none'})")

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_") or "kernels" not in self.__dict__:
            raise AttributeError(name)
        return self._lookup(name)

    def __dir__(self) -> list[str]:
        return sorted(set(super().__dir__()) | {k.split(".")[0] for k in self.kernels})


def _resolve(path: str | os.PathLike) -> tuple[Path, Path]:
    p = Path(path)
    if p.suffix in (".so", ".json", ".h", ".cl", ".spv"):
        stem = p.with_suffix("")
    else:
        stem = p
    return stem.with_name(stem.name + ".so"), stem.with_name(stem.name + ".json")


def load(path: str | os.PathLike, *, from_cache: bool = False,
         compile_seconds: float = 0.0) -> Module:
    """Load a compiled library: ``path`` is the ``.so`` (the ``.cl`` of target opencl, the
    ``.spv`` of target spirv), the ``.json`` manifest or their stem."""
    from ..compiler.targets import get_target, host_supports

    so, man = _resolve(path)
    manifest: dict[str, Any] = {}
    if man.is_file():
        try:
            manifest = json.loads(man.read_text())
            target = manifest["target"]
            manifest["kernels"]
            variant = manifest.get("variant")
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as e:
            raise CompileError(f"{man}: not a valid rdsl manifest ({e})") from None
        if manifest.get("backend") == "opencl":  # an OpenCL C program, built at load
            so = so.with_suffix(".cl")
        if manifest.get("backend") == "spirv":  # shaders for Vulkan
            so = so.with_suffix(".spv")
    if not man.is_file() or not so.is_file():
        missing = man if not man.is_file() else so
        raise FileNotFoundError(f"no compiled rdsl module at `{path}` (missing {missing})")
    if variant is not None and variant not in MODELS:
        raise CompileError(f"{man}: not a valid rdsl manifest (unknown variant `{variant}`)")
    if manifest.get("abi", 1) != ABI_VERSION:
        raise CompileError(f"{man}: built by rdsl {manifest.get('rdsl_version', '?')} for C ABI "
                           f"{manifest.get('abi', 1)}; this rdsl calls ABI {ABI_VERSION} "
                           "(strided arrays): recompile it")
    try:
        runnable = host_supports(get_target(target))
    except CompileError:
        runnable = True  # a target this version does not know: let the loader decide
    if not runnable:
        raise RuntimeError(f"{so} was compiled for target `{target}`, which this CPU cannot "
                           "run; recompile with --target host")
    if manifest.get("backend") == "spirv":
        from .spirv_module import load_spirv

        return load_spirv(man, so, manifest, from_cache=from_cache,
                          compile_seconds=compile_seconds)
    if manifest.get("backend") == "opencl":
        from .opencl import load_opencl

        return load_opencl(so, manifest, from_cache, compile_seconds)
    try:
        lib = _dlopen(so)
    except OSError as e:
        raise CompileError(f"cannot load {so}: {e}") from None
    return Module(manifest, lib, so, from_cache=from_cache, compile_seconds=compile_seconds)


def _source_text(source_or_path: str | os.PathLike) -> str:
    return read_source(source_or_path)[0]


def _key(source_or_path: str | os.PathLike, build: Build, options: dict[str, Any],
         quick: bool) -> tuple[str, list[Path]]:
    """The cache key of a :func:`jit` compilation, and the source files it reads."""
    from ..compiler.sources import source_files

    text = _source_text(source_or_path)
    files = [Path(f) for f in source_files(source_or_path, options.get("search_paths") or (),
                                           filename=options.get("filename"))]
    # the file name only labels diagnostics, and a cached build had none: scenes copied to
    # another directory share their kernels; the search paths count through the files they
    # resolved (their paths and texts are keyed)
    keyed = {k: v for k, v in options.items() if k not in ("filename", "search_paths")}
    if quick:  # the full tier's key is the one it always had
        keyed["quick"] = True
    if build.target.backend == "c" and os.environ.get("RDSL_CFLAGS"):  # cc's extra flags
        keyed["cflags"] = os.environ["RDSL_CFLAGS"]
    return cache_key(text, files, build, keyed), files


def jit_cached(source_or_path: str | os.PathLike, build: Build, **options: Any) -> bool:
    """Whether :func:`jit` would load these kernels from the cache (``quick=True``: the
    quick tier's) without compiling."""
    quick = bool(options.pop("quick", False)) or quick_everywhere()
    return entry_complete(cache_dir() / _key(source_or_path, build, options, quick)[0])


def quick_everywhere() -> bool:
    """``RDSL_QUICK=1``: every kernel is built by the quick tier (LLVM O0), whatever the
    caller asked: the same results, compiled in about 60% of the time (the test suite's
    physics tests use it; its code-generation tests build the full tier)."""
    return os.environ.get("RDSL_QUICK", "") not in ("", "0")


def jit(source_or_path: str | os.PathLike, target: str | Target = "host",
        variant: str | ColorModel = "rgb", cache: bool = True, *, build: Build | None = None,
        width: int | None = None, **options: Any) -> Module:
    """Compile ``source_or_path`` (a ``.rdsl`` path or source text) for ``target`` and load it.

    ``width`` picks the SIMD width of target ``c`` (1, 4, 8 or 16; the C source is compiled
    by the machine's ``cc``).  ``build``, when given, replaces ``target``, ``variant`` and
    ``width``; a bad name of either is a
    diagnostic before any source is read.  The library is cached under
    :func:`rdsl.runtime.cache.cache_dir`; a second call with the same sources (imports
    included), target, variant and options loads it without compiling.  ``options`` are
    passed on to ``rdsl.compiler.driver.compile_kernels`` (``search_paths``: folders imports
    are looked up in, such as a scene's user plugin folders).  ``quick=True`` builds the
    quick tier (LLVM O0: compiled sooner, runs slower, the same results; cached apart)."""
    from ..compiler.build import Build

    t0 = time.perf_counter()
    build = build or Build.of(target, variant, width)
    quick = bool(options.pop("quick", False)) or quick_everywhere()
    if build.target.backend == "ptx":  # kernels on a CUDA GPU, not a CPU library
        from .cuda import jit_ptx

        return jit_ptx(source_or_path, build, **options)
    key, files = _key(source_or_path, build, options, quick)
    root = cache_dir()
    entry = root / key
    if cache and entry_complete(entry):
        mod = load(entry / STEM, from_cache=True, compile_seconds=time.perf_counter() - t0)
        mod.source_files, mod.quick = files, quick
        return mod

    from ..core.gcpause import gc_paused

    with gc_paused():  # one pause for the whole compile, which ends with its IR freed
        tmp = _compile_into(source_or_path, build, quick, options,
                            (root, key) if cache else None)
    if not cache:
        mod = load(tmp / STEM, compile_seconds=time.perf_counter() - t0)
        mod.source_files, mod.quick = files, quick
        return mod
    try:
        os.rename(tmp, entry)  # atomic: readers see a complete entry or none
    except OSError:
        # another process installed the same entry first (or a broken one is in the way)
        if not entry_complete(entry):
            shutil.rmtree(entry, ignore_errors=True)
            try:
                os.rename(tmp, entry)
            except OSError:
                pass
        if tmp.exists():
            if entry_complete(entry):
                shutil.rmtree(tmp, ignore_errors=True)
            else:
                entry = tmp
    mod = load(entry / STEM, compile_seconds=time.perf_counter() - t0)
    mod.source_files, mod.quick = files, quick
    return mod


def _compile_into(source_or_path: str | os.PathLike, build: Build, quick: bool,
                  options: dict[str, Any], cache: tuple[Path, str] | None) -> Path:
    """Compile and write the library into a new folder: one in the cache folder (``cache``:
    the folder and the entry's key; the new folder is removed again if the build fails) or,
    with ``cache`` None, a temporary one removed at exit."""
    from ..compiler import driver  # only now: a cache hit never imports the compiler
    from ..compiler.backends.clib import build_library

    module, _ = driver.compile_kernels(source_or_path, build, **options)
    if cache is None:
        tmp = Path(tempfile.mkdtemp(prefix="rdsl-jit-"))
        atexit.register(shutil.rmtree, tmp, True)
        build_library(module, build.target, tmp, STEM, quick)
        return tmp
    root, key = cache
    try:
        root.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{key[:16]}-", dir=root))
    except OSError as e:
        raise CompileError(f"cannot write to the kernel cache `{root}`: {e.strerror or e} "
                           "(set $RDSL_CACHE_DIR)") from None
    try:
        build_library(module, build.target, tmp, STEM, quick)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return tmp
