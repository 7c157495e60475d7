"""What every backend shares: a name, its capabilities, and how kernels appear in an ABI.

The C ABI (version :data:`ABI_VERSION`) passes every array a kernel maps over (varying
inputs, outputs and the mask) as a base pointer plus an ``int64_t`` stride in bytes: element
``i`` is at ``base + i * stride``.  Any layout numpy can describe with one stride (C- or
Fortran-order columns, slices with steps, fields of record arrays at any offset, negative
steps, stride 0 for one value broadcast to every element) is read and written in place.
Buffers stay plain contiguous pointers (the kernel indexes them itself).  A backend that gains
a runtime takes the same arguments, in the order of :func:`c_params`."""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any, ClassVar

from .. import ir
from ..diagnostics import CompileError


class Backend:
    """Base class of code generators.

    Subclasses set the capability flags below and implement the ``emit_*`` methods they list
    in ``emits``."""

    name: ClassVar[str] = "base"
    emits: ClassVar[tuple[str, ...]] = ()  # e.g. ("llvm", "asm", "obj")
    supports_gather: ClassVar[bool] = False
    supports_scatter: ClassVar[bool] = False
    supports_float_rem: ClassVar[bool] = False
    max_width: ClassVar[int] = 1
    widths: ClassVar[tuple[int, ...]] = (1,)

    def check_module(self, module: ir.Module) -> int:
        """Check that ``module`` is something this backend can lower; return its width."""
        width = int(module.attrs.get("width", 1))
        if width not in self.widths:
            raise CompileError(f"the {self.name} backend does not support SIMD width {width} "
                               f"(supported: {', '.join(map(str, self.widths))})")
        return width


# --------------------------------------------------------------------------------------
# The C-level view of a kernel, shared by the LLVM backend, the C header and the runtime.

ABI_VERSION = 2  # 1: contiguous arrays, no strides; 2: a byte stride after every array
CTYPES = {"f32": "float", "i32": "int32_t", "u32": "uint32_t", "u64": "uint64_t",
          "bool": "uint8_t"}


def c_name(name: str) -> str:
    """A C identifier made from a kernel name: every char not in [A-Za-z0-9_] becomes ``_``."""
    return re.sub(r"[^A-Za-z0-9_]", "_", name)


@dataclass
class CArg:
    """One argument of a kernel's C entry point (after ``n`` or ``begin, end``)."""

    name: str
    dtype: str  # f32 i32 u32 u64 bool
    kind: str  # varying | uniform | buffer | output
    uniform_result: bool = False  # output only: the kernel computes one value for all lanes

    @property
    def strided(self) -> bool:
        """Whether the C argument is followed by its stride (``int64_t``, in bytes)."""
        return self.kind in ("varying", "output")

    @property
    def ctype(self) -> str:
        base = CTYPES[self.dtype]
        if self.kind == "uniform":
            return base
        if self.kind == "varying":
            return f"const {base}*"
        return f"{base}*"

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "dtype": self.dtype, "kind": self.kind,
                "strided": self.strided}


def kernels(module: ir.Module) -> list[ir.Function]:
    """The exported functions of a module, in definition order."""
    return [f for f in module.functions.values() if f.attrs.get("export")]


def split_params(fn: ir.Function) -> tuple[list[ir.Param], ir.Param | None]:
    """The kernel's params without the trailing execution mask, and the mask param."""
    params = list(fn.params)
    if params and params[-1].value.name == "mask" and not params[-1].uniform \
            and isinstance(params[-1].value.type, ir.ScalarType) \
            and params[-1].value.type.name == "bool":
        return params[:-1], params[-1]
    return params, None


def result_names(fn: ir.Function) -> list[str]:
    if fn.ret_names is not None and len(fn.ret_names) == len(fn.ret_types):
        return list(fn.ret_names)
    if len(fn.ret_types) == 1:
        return ["ret"]
    return [f"ret.{i}" for i in range(len(fn.ret_types))]


def c_args(fn: ir.Function) -> list[CArg]:
    """The flat C arguments of ``rdsl_<name>`` after ``n``, without the final mask pointer."""
    params, _ = split_params(fn)
    out: list[CArg] = []
    for p in params:
        t = p.value.type
        name = p.value.name or f"arg{len(out)}"
        if isinstance(t, ir.BufferType):
            out.append(CArg(name, t.elem.name, "buffer"))
        elif isinstance(t, ir.ScalarType):
            out.append(CArg(name, t.name, "uniform" if p.uniform else "varying"))
        else:
            raise CompileError(f"kernel `{fn.name}`: parameter `{name}` has type {t}; "
                               "kernels take scalars and buffers only (run scalarize first)",
                               fn.loc)
    width = 0
    for t, name in zip(fn.ret_types, result_names(fn)):
        if not isinstance(t, ir.ScalarType):
            raise CompileError(f"kernel `{fn.name}`: result `{name}` has type {t}; "
                               "kernels return scalars only", fn.loc)
        width = max(width, t.lanes)
        out.append(CArg(name, t.name, "output"))
    # a result is uniform when it has one lane in a module whose width is larger than one
    for arg, t in zip(out[len(out) - len(fn.ret_types):], fn.ret_types):
        arg.uniform_result = t.lanes == 1
    return out


_C_RESERVED = {
    "auto", "break", "case", "char", "const", "continue", "default", "do", "double", "else",
    "enum", "extern", "float", "for", "goto", "if", "inline", "int", "long", "register",
    "restrict", "return", "short", "signed", "sizeof", "static", "struct", "switch",
    "typedef", "union", "unsigned", "void", "volatile", "while", "bool", "true", "false",
    "n", "begin", "end", "mask", "mask_stride"}


def c_arg_names(args: list[CArg]) -> list[str]:
    """Distinct C parameter names for ``args`` (outputs are prefixed with ``out_``); the stride
    of a strided argument is named ``<name>_stride`` (kept distinct as well)."""
    names: list[str] = []
    taken: set[str] = set()
    for a in args:
        base = ("out_" if a.kind == "output" else "") + c_name(a.name)
        if base in _C_RESERVED or base[:1].isdigit():
            base = "arg_" + base
        name, k = base, 2
        while name in taken or (a.strided and name + "_stride" in taken):
            name, k = f"{base}_{k}", k + 1
        names.append(name)
        taken.add(name)
        if a.strided:
            taken.add(name + "_stride")
    return names


def entry_args(fn: ir.Function) -> tuple[list[ir.Param], ir.Param, list[CArg], list[str], int]:
    """What a C-like entry point's definition is made of: the kernel's params without the
    mask, the mask param, the C arguments, their names in the definition and how many of
    them are inputs.  The names are the header's with the prefix ``arg_``, which keeps
    them apart from a body's locals (i, nl, em, k, vN, ...) whatever the params are."""
    params, mask_param = split_params(fn)
    if mask_param is None:
        raise CompileError(f"kernel `{fn.name}` has no execution mask parameter "
                           "(run vectorize first)", fn.loc)
    args = c_args(fn)
    names = ["arg_" + n for n in c_arg_names(args)]
    return params, mask_param, args, names, sum(a.kind != "output" for a in args)


def c_params(args: list[CArg]) -> list[tuple[str, str]]:
    """(C type, name) of every parameter of an entry point after ``n`` (or ``begin, end``):
    each argument, followed by ``int64_t <name>_stride`` when it is strided, then the mask
    and its stride."""
    out: list[tuple[str, str]] = []
    for a, name in zip(args, c_arg_names(args)):
        out.append((a.ctype, name))
        if a.strided:
            out.append(("int64_t", name + "_stride"))
    return out + [("const uint8_t*", "mask"), ("int64_t", "mask_stride")]


def c_prototype(fn: ir.Function, range_: bool = False) -> str:
    """The C prototype of ``rdsl_<name>`` (or of ``rdsl_<name>_range``)."""
    cname = "rdsl_" + c_name(fn.name) + ("_range" if range_ else "")
    head = ["int64_t begin", "int64_t end"] if range_ else ["int64_t n"]
    params = [f"{t} {name}" for t, name in c_params(c_args(fn))]
    return f"void {cname}({', '.join(head + params)})"
