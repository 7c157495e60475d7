"""The GLSL text of one kernel as a compute shader, and the layout the runtime binds it with.

Devices bind few storage buffers per shader (lavapipe: 32, Vulkan guarantees 4) and kernels
take dozens of arrays, so arrays share one storage buffer per element type (a *pool*:
``F`` float, ``I`` int, ``U`` uint, bools and the mask, ``L`` uint64_t), each from an offset
the parameter block gives.  Binding 0 is the parameter block (std430): the element count
``n``, whether the mask is set, one ``uint`` offset per array (the varying inputs, buffers
and outputs of the kernel's C view, ``base.c_args``, in order, then the mask), then the
uniform arguments (64-bit ones first, so that every member sits at its natural alignment).
Invocation ``i`` (a 2-D dispatch of work groups of :data:`LOCAL_SIZE`, so more than 65535
groups fit) runs element ``i`` when ``i < n`` and its mask is set; bools are 32-bit 0/1.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from .. import ir
from ..diagnostics import CompileError
from .base import CArg, c_arg_names, c_args, kernels, split_params
from .glsl import FMODF, GLSL_MEM, GLSL_TYPES, GlslPrinter

LOCAL_SIZE = 64
_SIZE = {"f32": 4, "i32": 4, "u32": 4, "u64": 8, "bool": 4}
POOLS = {"f32": ("F", 1), "i32": ("I", 2), "u32": ("U", 3), "bool": ("U", 3), "u64": ("L", 4)}
N_BINDINGS = 5


@dataclass
class Shader:
    """One kernel's compute shader and what the runtime needs to bind it."""

    name: str
    source: str
    arrays: list[dict[str, Any]] = field(default_factory=list)  # arg, dtype, kind, offset
    uniforms: list[dict[str, Any]] = field(default_factory=list)  # name, dtype, offset
    params_size: int = 8
    int64: bool = False

    def layout(self) -> dict[str, Any]:
        """The manifest's description of the shader's bindings."""
        return {"local_size": LOCAL_SIZE, "bindings": N_BINDINGS, "arrays": self.arrays,
                "uniforms": self.uniforms, "params_size": self.params_size,
                "int64": self.int64}


def shaders(module: ir.Module) -> list[Shader]:
    """The compute shader of every kernel of ``module`` (post-vectorize, width 1)."""
    return [kernel_shader(fn) for fn in kernels(module)]


def _params_block(shader: Shader, args: list[CArg], names: list[str]) -> list[str]:
    """Lay out the parameter block (offsets of the arrays, then the uniforms) in
    ``shader``; returns its GLSL members."""
    members = ["uint n;", "uint has_mask;"]
    offset = 8
    arrays = [(a, n) for a, n in zip(args, names) if a.kind != "uniform"]
    for a, name in [*arrays, (CArg("mask", "bool", "mask"), "mask")]:
        members.append(f"uint o_{name};")
        shader.arrays.append({"arg": a.name if a.kind != "mask" else None, "dtype": a.dtype,
                              "kind": a.kind, "pool": POOLS[a.dtype][0], "offset": offset})
        offset += 4
    uniform = sorted([(a, n) for a, n in zip(args, names) if a.kind == "uniform"],
                     key=lambda an: _SIZE[an[0].dtype] != 8)
    if uniform and _SIZE[uniform[0][0].dtype] == 8 and offset % 8:
        members.append("uint pad_;")
        offset += 4
    for a, name in uniform:
        members.append(f"{GLSL_MEM[a.dtype]} {name};")
        shader.uniforms.append({"name": a.name, "dtype": a.dtype, "offset": offset})
        offset += _SIZE[a.dtype]
    shader.params_size = offset
    return members


def _declarations(members: list[str], args: list[CArg]) -> list[str]:
    out = ["layout(std430, binding = 0) readonly buffer Params {",
           *("    " + m for m in members), "} p;"]
    used = {POOLS[a.dtype] for a in args if a.kind != "uniform"} | {POOLS["bool"]}
    for pool, k in sorted(used, key=lambda pk: pk[1]):
        elem = {"F": "float", "I": "int", "U": "uint", "L": "uint64_t"}[pool]
        out.append(f"layout(std430, binding = {k}) buffer Pool{pool} {{ {elem} d[]; }} {pool};")
    return out


# long: one straight sequence (declarations, inputs, body, outputs) per shader
def kernel_shader(fn: ir.Function) -> Shader:
    """The compute shader of one kernel."""
    params, mask_param = split_params(fn)
    if mask_param is None:
        raise CompileError(f"kernel `{fn.name}` has no execution mask parameter "
                           "(run vectorize first)", fn.loc)
    args = c_args(fn)
    names = ["a_" + n for n in c_arg_names(args)]
    n_in = sum(a.kind != "output" for a in args)
    shader = Shader(fn.name, "")
    decls = _declarations(_params_block(shader, args, names), args)

    p = GlslPrinter({mask_param.value: "true"}, indent=1)
    for prm, a, name in zip(params, args[:n_in], names[:n_in]):
        pool = POOLS[a.dtype][0]
        if a.kind == "buffer":
            p.names[prm.value] = name
            p.pooled[name] = (pool, f"p.o_{name}")
        elif a.kind == "uniform":
            p.names[prm.value] = f"(p.{name} != 0u)" if a.dtype == "bool" else f"p.{name}"
        else:
            ref = f"{pool}.d[p.o_{name} + i]"
            p.line(f"{GLSL_TYPES[a.dtype]} in_{name} = "
                   + (f"{ref} != 0u;" if a.dtype == "bool" else f"{ref};"))
            p.names[prm.value] = f"in_{name}"
    outs = names[n_in:]

    def on_return(vals: list[str]) -> None:
        for name, v, a in zip(outs, vals, args[n_in:]):
            p.line(f"{POOLS[a.dtype][0]}.d[p.o_{name} + i] = "
                   f"{f'uint({v})' if a.dtype == 'bool' else v};")

    p.on_return = on_return
    p.block(fn.body)
    body = ["void main() {",
            (f"    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * "
             f"gl_NumWorkGroups.x * {LOCAL_SIZE}u;"),
            "    if (i >= p.n || (p.has_mask != 0u && U.d[p.o_mask + i] == 0u)) return;",
            *p.lines, "}"]
    tables = [f"const uint {name}[{len(vals)}] = uint[{len(vals)}]("
              + ", ".join(_bits(v) for v in vals) + ");" for name, vals in p.tables.items()]
    if p.uses_fmodf:
        tables += ["", FMODF]
    text = "\n".join(decls + tables + body)
    shader.int64 = "int64_t" in text
    head = [(f"// Generated by rdsl: kernel `{fn.name}` as a GLSL compute shader "
             "(one invocation per element)."), "#version 450"]
    if shader.int64:
        head.append("#extension GL_ARB_gpu_shader_int64 : require")
    head.append(f"layout(local_size_x = {LOCAL_SIZE}) in;")
    shader.source = "\n".join(head + [""] + decls + [""] + tables + [""] + body) + "\n"
    return shader


def _bits(value: float) -> str:
    import numpy as np

    return f"0x{int(np.float32(value).view(np.uint32)):08x}u"
