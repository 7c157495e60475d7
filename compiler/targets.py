"""CPU targets: a SIMD width plus the LLVM CPU name and feature string to compile for.

``get_target("host")`` picks the widest target this machine can run, from
``llvmlite.binding.get_host_cpu_features()``.  ``get_target("c", width)`` is the SIMD C
target (``backend == "c"``, see ``backends/c.py``) at width 1, 4, 8 or 16, compiled by the
machine's ``cc`` for the machine itself (``-march=native``); without a width it takes the
host's widest LLVM target's.  ``get_target("opencl", width)`` is OpenCL C
(``backends/opencl.py``): W lanes per work-item as OpenCL vectors (1, 4, 8 or 16; by
default as many as the widest LLVM target's), run by the machine's OpenCL driver (PoCL on a
CPU, which compiles for the host).  ``get_target("ptx")`` (or :func:`ptx_target` with an
``sm_XY`` architecture) is CUDA PTX through LLVM's NVPTX backend: width 1, one lane per CUDA
thread (``backends/ptx.py``).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

from .diagnostics import CompileError


@dataclass(frozen=True)
class Target:
    """A CPU code-generation target.

    ``requires`` lists the host CPU features (LLVM names, without ``+``) needed to *run* code
    compiled for this target; ``vector_bits`` is the SIMD register width the kernels use."""

    name: str
    width: int
    cpu: str
    features: str
    requires: tuple[str, ...] = ()
    vector_bits: int = 128
    backend: str = "llvm"  # code generator: "llvm", "c", "opencl", "ptx" (NVPTX), "spirv"

    @property
    def triple(self) -> str:
        if self.backend == "ptx":
            return "nvptx64-nvidia-cuda"
        import llvmlite.binding as llvm

        return llvm.get_default_triple()


_AVX512 = ("avx512f", "avx512bw", "avx512dq", "avx512vl", "avx512cd")

TARGETS: dict[str, Target] = {
    t.name: t
    for t in (
        Target("scalar", 1, "x86-64", "+sse,+sse2", ("sse2",), 128),
        Target("sse4", 4, "x86-64", "+sse2,+sse3,+ssse3,+sse4.1,+sse4.2,+popcnt",
               ("sse4.2", "popcnt"), 128),
        # +fast-gather: LLVM's Haswell tuning scalarizes every gather (its cost model
        # trusts AVX2 gathers on Skylake and later only), 8 extracts, loads and inserts
        # each; with vgatherdps the matpreview_diffuse kernel is a third smaller and the
        # scene set renders in 0.74x the CPU time (geometric mean) on an AVX2-only AMD
        # EPYC (Zen 3), bit for bit the same images (docs/bench.md, stop 31)
        Target("avx2", 8, "haswell", "+avx,+avx2,+fma,+bmi,+bmi2,+f16c,+popcnt,+fast-gather",
               ("avx2", "fma", "bmi2"), 256),
        Target("avx512", 16, "skylake-avx512",
               "+avx,+avx2,+fma,+bmi,+bmi2,+f16c,+popcnt,"
               + ",".join("+" + f for f in _AVX512),
               ("avx2", "fma") + _AVX512, 512),
    )
}

# widest first: what "host" resolves to
_PREFERENCE = ("avx512", "avx2", "sse4", "scalar")


# /proc/cpuinfo spells a few features differently from LLVM
_CPUINFO_TO_LLVM = {"sse4_1": "sse4.1", "sse4_2": "sse4.2", "pni": "sse3"}


@lru_cache(maxsize=1)
def host_features() -> frozenset[str]:
    """The CPU features of this machine (LLVM names), or an empty set if unknown."""
    # /proc/cpuinfo is read in microseconds; importing llvmlite costs tens of milliseconds,
    # which matters on the cached-kernel path
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("flags"):
                    flags = set(line.split(":", 1)[1].split())
                    return frozenset(_CPUINFO_TO_LLVM.get(x, x) for x in flags)
    except OSError:
        pass
    try:
        import llvmlite.binding as llvm

        flags = llvm.get_host_cpu_features()
        return frozenset(k for k, v in flags.items() if v)
    except Exception:  # pragma: no cover - llvmlite cannot query some hosts
        return frozenset()


def host_supports(target: Target | str) -> bool:
    """True if code compiled for ``target`` can run on this machine."""
    t = get_target(target) if isinstance(target, str) else target
    if t.backend in ("c", "opencl", "spirv"):  # built on this machine (cc, the OpenCL
        # driver); spirv: a Vulkan device, checked when a kernel runs
        return True
    if t.backend == "ptx":  # runs on a CUDA GPU (runtime/cuda.py), never on the CPU
        return False
    feats = host_features()
    if not feats:
        return t.name == "scalar"
    return all(f in feats for f in t.requires)


def host_target() -> Target:
    """The widest target this machine supports."""
    for name in _PREFERENCE:
        if host_supports(TARGETS[name]):
            return TARGETS[name]
    return TARGETS["scalar"]


C_WIDTHS = (1, 4, 8, 16)


def c_target(width: int | None = None, backend: str = "c") -> Target:
    """The SIMD C target of ``width`` lanes (default: the host's widest LLVM target's), or
    with ``backend="opencl"`` the OpenCL C target (``width`` lanes per work-item)."""
    if width is None:
        width = host_target().width
    if width not in C_WIDTHS:
        raise CompileError(f"unsupported SIMD width {width} for target `{backend}` (valid "
                           f"widths: {', '.join(map(str, C_WIDTHS))})")
    return Target(backend, width, "native" if backend == "c" else backend, "", (),
                  32 * width, backend=backend)


PTX_ARCHS = ("sm_70", "sm_80", "sm_90")  # Volta, Ampere, Hopper


def ptx_target(arch: str = "sm_70") -> Target:
    """CUDA PTX for GPU architecture ``arch`` (``sm_70``, ``sm_80`` or ``sm_90``); a GPU of
    that architecture or a newer one runs it."""
    if arch not in PTX_ARCHS:
        raise CompileError(f"unknown GPU architecture `{arch}` for target `ptx` (valid: "
                           f"{', '.join(PTX_ARCHS)})")
    return Target("ptx", 1, arch, "", (), 32, backend="ptx")


def spirv_target(width: int | None = None) -> Target:
    """The SPIR-V target (GLSL compute shaders on Vulkan): one element per invocation."""
    if width not in (None, 1):
        raise CompileError(f"target `spirv` runs one element per shader invocation: its "
                           f"width is 1, not {width}")
    return Target("spirv", 1, "vulkan", "", (), 32, backend="spirv")


def get_target(name: str | Target, width: int | None = None) -> Target:
    """Look a target up by name (``scalar``, ``sse4``, ``avx2``, ``avx512``, ``host`` or
    ``c``), ``opencl``, ``ptx`` or ``spirv``.  ``width`` picks the width of ``c`` and
    ``opencl``; an LLVM target has its own, which a different ``width`` contradicts (a
    diagnostic)."""
    if isinstance(name, Target):
        t = name
    elif name in ("c", "opencl"):
        return c_target(width, name)
    elif name == "ptx":
        t = ptx_target()
    elif name == "spirv":
        return spirv_target(width)
    elif name == "host":
        t = host_target()
    else:
        found = TARGETS.get(name)
        if found is None:
            valid = ", ".join([*TARGETS, "host", "c", "opencl", "ptx", "spirv"])
            raise CompileError(f"unknown target `{name}` (valid targets: {valid})")
        t = found
    if width is not None and width != t.width:
        if t.backend in ("c", "opencl"):
            return c_target(width, t.backend)
        raise CompileError(f"target `{t.name}` has SIMD width {t.width}, not {width} "
                           "(a width can be chosen for targets `c` and `opencl`, which take "
                           f"{', '.join(map(str, C_WIDTHS))})")
    return t
