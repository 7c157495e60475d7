"""The GLSL text of one kernel as a compute shader, and the layout the runtime binds it with.

Every argument of the kernel's C view (``base.c_args``) that is an array becomes a storage
buffer (std430) of its elements, contiguous: binding 1 on, in argument order, then the mask
(``uint`` 0/1 per element).  Binding 0 is the parameter block: the element count ``n``, a
flag saying whether the mask is bound, then the uniform arguments (64-bit ones first, so
every member sits at its natural alignment).  Invocation ``i`` (a 2-D dispatch of work
groups of :data:`LOCAL_SIZE`, so more than 65535 groups fit) runs element ``i`` when
``i < n`` and its mask is set; bools are 32-bit 0/1 in every buffer.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from .. import ir
from ..diagnostics import CompileError
from .base import CArg, c_arg_names, c_args, kernels, split_params
from .glsl import GLSL_MEM, GLSL_TYPES, GlslPrinter

LOCAL_SIZE = 64
_SIZE = {"f32": 4, "i32": 4, "u32": 4, "u64": 8, "bool": 4}


@dataclass
class Shader:
    """One kernel's compute shader and what the runtime needs to bind it."""

    name: str
    source: str
    bindings: list[dict[str, Any]] = field(default_factory=list)  # binding k: arg, dtype
    uniforms: list[dict[str, Any]] = field(default_factory=list)  # name, dtype, offset
    params_size: int = 8
    int64: bool = False

    def layout(self) -> dict[str, Any]:
        """The manifest's description of the shader's bindings."""
        return {"local_size": LOCAL_SIZE, "bindings": self.bindings,
                "uniforms": self.uniforms, "params_size": self.params_size,
                "int64": self.int64}


def shaders(module: ir.Module) -> list[Shader]:
    """The compute shader of every kernel of ``module`` (post-vectorize, width 1)."""
    return [kernel_shader(fn) for fn in kernels(module)]


def _params_block(args: list[CArg], names: list[str]) -> tuple[list[str], list[dict], int]:
    """The members of the parameter block, their layout, and its size in bytes."""
    members = ["uint n;", "uint has_mask;"]
    layout: list[dict[str, Any]] = []
    offset = 8
    uniform = [(a, n) for a, n in zip(args, names) if a.kind == "uniform"]
    for a, name in sorted(uniform, key=lambda an: _SIZE[an[0].dtype] != 8):
        members.append(f"{GLSL_MEM[a.dtype]} {name};")
        layout.append({"name": a.name, "dtype": a.dtype, "offset": offset})
        offset += _SIZE[a.dtype]
    return members, layout, offset


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
    members, uniforms, size = _params_block(args, names)
    shader = Shader(fn.name, "", uniforms=uniforms, params_size=size)
    decls = ["layout(std430, binding = 0) readonly buffer Params {",
             *("    " + m for m in members), "} p;"]
    for a, name in zip(args, names):
        if a.kind == "uniform":
            continue
        k = len(shader.bindings) + 1
        access = {"varying": "readonly ", "output": "writeonly "}.get(a.kind, "")
        decls.append(f"layout(std430, binding = {k}) {access}buffer B{k} "
                     f"{{ {GLSL_MEM[a.dtype]} d[]; }} {name};")
        shader.bindings.append({"binding": k, "arg": a.name, "dtype": a.dtype,
                                "kind": a.kind})
    k = len(shader.bindings) + 1
    decls.append(f"layout(std430, binding = {k}) readonly buffer B{k} {{ uint d[]; }} mask_;")
    shader.bindings.append({"binding": k, "arg": None, "dtype": "bool", "kind": "mask"})

    p = GlslPrinter({mask_param.value: "true"}, indent=1)
    for prm, a, name in zip(params, args[:n_in], names[:n_in]):
        if a.kind == "buffer":
            p.names[prm.value] = f"{name}.d"
        elif a.kind == "uniform":
            p.names[prm.value] = f"(p.{name} != 0u)" if a.dtype == "bool" else f"p.{name}"
        else:
            ref = f"{name}.d[i]"
            p.line(f"{GLSL_TYPES[a.dtype]} in_{name} = "
                   + (f"{ref} != 0u;" if a.dtype == "bool" else f"{ref};"))
            p.names[prm.value] = f"in_{name}"
    outs = names[n_in:]

    def on_return(vals: list[str]) -> None:
        for name, v, a in zip(outs, vals, args[n_in:]):
            p.line(f"{name}.d[i] = {f'uint({v})' if a.dtype == 'bool' else v};")

    p.on_return = on_return
    p.block(fn.body)
    body = ["void main() {",
            f"    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * "
            f"gl_NumWorkGroups.x * {LOCAL_SIZE}u;",
            "    if (i >= p.n || (p.has_mask != 0u && mask_.d[i] == 0u)) return;",
            *p.lines, "}"]
    tables = [f"const uint {name}[{len(vals)}] = uint[{len(vals)}]("
              + ", ".join(_bits(v) for v in vals) + ");" for name, vals in p.tables.items()]
    text = "\n".join(decls + tables + body)
    shader.int64 = "int64_t" in text
    head = [f"// Generated by rdsl: kernel `{fn.name}` as a GLSL compute shader "
            "(one invocation per element).", "#version 450"]
    if shader.int64:
        head.append("#extension GL_ARB_gpu_shader_int64 : require")
    head.append(f"layout(local_size_x = {LOCAL_SIZE}) in;")
    shader.source = "\n".join(head + [""] + decls + [""] + tables + [""] + body) + "\n"
    return shader


def _bits(value: float) -> str:
    import numpy as np

    return f"0x{int(np.float32(value).view(np.uint32)):08x}u"
