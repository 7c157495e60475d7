"""Helpers for the backend/runtime tests: build post-vectorize kernels by hand."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from rdsl.compiler import ir

KIND_VARYING, KIND_UNIFORM, KIND_BUFFER = "varying", "uniform", "buffer"


def add_kernel(module: ir.Module, name: str,
               params: list[tuple[str, str, str] | tuple[str, str, str, Any]],
               body: Callable[..., list[ir.Value]],
               ret_names: list[str] | None = None) -> ir.Function:
    """Append an exported kernel to ``module`` (whose ``attrs["width"]`` is set).

    ``params``: (abi name, dtype, kind[, default]) with kind varying/uniform/buffer.
    ``body(b, args, mask)`` gets a Builder, a dict abi name -> Value and the mask Value and
    returns the result values."""
    W = module.attrs["width"]
    ps: list[ir.Param] = []
    abi = []
    for p in params:
        pname, dtype, kind = p[:3]
        default = p[3] if len(p) > 3 else None
        st = ir.ScalarType(dtype)
        if kind == KIND_BUFFER:
            t: ir.Type = ir.BufferType(st)
        elif kind == KIND_UNIFORM:
            t = st
        else:
            t = st.with_lanes(W)
        ps.append(ir.Param(ir.Value(t, pname), uniform=kind != KIND_VARYING, default=default))
        abi.append({"name": pname, "type": ir.type_to_json(t if kind == KIND_BUFFER else st),
                    "uniform": kind != KIND_VARYING, "default": default,
                    "leaves": [] if kind == KIND_BUFFER else [pname]})
    mask = ir.Value(ir.BOOL.with_lanes(W), "mask")
    ps.append(ir.Param(mask, uniform=False))
    blk = ir.Block()
    b = ir.Builder(blk)
    args = {p.value.name: p.value for p in ps[:-1]}
    results = body(b, args, mask)
    b.return_(*results)
    rtypes = [r.type for r in results]
    if ret_names is None:
        ret_names = ["ret"] if len(results) == 1 else [f"ret.{i}" for i in range(len(results))]
    fn = ir.Function(name, ps, rtypes, blk, attrs={"export": True}, ret_names=ret_names)
    fn.attrs["abi_params"] = abi
    if not results:
        fn.attrs["abi_result"] = {"type": None, "leaves": []}
    elif len(results) == 1:
        fn.attrs["abi_result"] = {"type": ir.type_to_json(rtypes[0].with_lanes(1)),
                                  "leaves": ret_names}
    else:
        fn.attrs["abi_result"] = {"type": {"kind": "tuple", "elems": [
            ir.type_to_json(t.with_lanes(1)) for t in rtypes]}, "leaves": ret_names}
    module.add(fn)
    return fn


def new_module(width: int, **attrs: Any) -> ir.Module:
    return ir.Module(attrs={"width": width, **attrs})


def vt(dtype: str, width: int) -> ir.ScalarType:
    return ir.ScalarType(dtype, lanes=width)


def build_and_load(module: ir.Module, target: str, out_dir, stem: str = "kernels"):
    """Compile ``module`` into ``out_dir`` and load it with ``rdsl.load``."""
    import rdsl
    from rdsl.compiler.backends.clib import build_library

    build_library(module, target, out_dir, stem)
    return rdsl.load(out_dir / f"{stem}.so")


def runnable_targets() -> list:
    """pytest params for every CPU target, skipped where this host cannot run it."""
    import pytest
    from rdsl.compiler.targets import TARGETS, host_supports

    return [pytest.param(name, marks=pytest.mark.skipif(
        not host_supports(name), reason=f"this CPU cannot run the {name} target"))
        for name in TARGETS]
