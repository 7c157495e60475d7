"""The generated header and shared library, used from a C program."""

from __future__ import annotations

import shutil
import subprocess

import pytest
from _backend_util import add_kernel, new_module, vt
from rdsl.compiler import ir
from rdsl.compiler.backends.clib import build_library
from rdsl.compiler.targets import host_target

Op = ir.Op

C_MAIN = r"""
#include <stdio.h>
#include "shade.h"

int main(void) {
    float x[7] = {0, 1, 2, 3, 4, 5, 6};
    int32_t i[7] = {7, -7, 0, 100, -2147483647 - 1, 9, 1};
    float y[7];
    int32_t q[7];
    uint8_t pos[7];
    uint8_t m[7] = {1, 1, 0, 1, 1, 1, 1};
    float buf[2] = {0, 0};
    rdsl_demo_kernel(7, x, 1.5f, i, 2, buf, y, q, pos, NULL);
    for (int k = 0; k < 7; k++) printf("%g %d %d\n", y[k], q[k], pos[k]);
    y[2] = -1.0f;
    rdsl_demo_kernel(7, x, 2.0f, i, -1, buf, y, q, pos, m);
    printf("%g %g\n", y[2], y[3]);
    rdsl_demo_kernel_range(3, 5, x, 10.0f, i, 0, buf, y, q, pos, NULL);
    printf("%g %g %d %d\n", y[3], y[4], q[3], q[4]);
    printf("%g\n", buf[0]);
    return 0;
}
"""


def _module(width: int) -> ir.Module:
    """demo.kernel(x: f32, scale: f32, i: i32, d: i32, buf) -> (x * scale, i / d, i > 0);
    also stores 42 into buf[0]."""
    m = new_module(width)
    f, i32 = vt("f32", width), vt("i32", width)

    def body(b, a, mask):
        y = b.op(Op.MUL, f, a["x"], b.op(Op.BROADCAST, f, a["scale"]))
        q = b.op(Op.DIV, i32, a["i"], b.op(Op.BROADCAST, i32, a["d"]))
        pos = b.op(Op.GT, vt("bool", width), a["i"], b.op(Op.BROADCAST, i32, b.const(0, ir.I32)))
        b.emit(Op.STORE, [a["buf"], b.const(0, ir.I32), b.const(42.0, ir.F32)], [])
        return [y, q, pos]
    add_kernel(m, "demo.kernel", [("x", "f32", "varying"), ("scale", "f32", "uniform", 1.0),
                                  ("i", "i32", "varying"), ("d", "i32", "uniform", 1),
                                  ("buf", "f32", "buffer")], body,
               ["ret.0", "ret.1", "ret.2"])
    return m


def test_c_program_calls_kernel(tmp_path):
    cc = shutil.which("cc")
    if cc is None:
        pytest.skip("no C compiler (`cc`) on PATH")
    t = host_target()
    paths = build_library(_module(t.width), t, tmp_path, "shade")
    header = paths["header"].read_text()
    assert "#include <stdint.h>" in header
    assert ("void rdsl_demo_kernel(int64_t n, const float* x, float scale, const int32_t* i, "
            "int32_t d, float* buf, float* out_ret_0, int32_t* out_ret_1, uint8_t* out_ret_2, "
            "const uint8_t* mask);") in header
    src = tmp_path / "main.c"
    src.write_text(C_MAIN)
    exe = tmp_path / "main"
    r = subprocess.run([cc, "-std=c99", "-Wall", "-Werror", "-o", str(exe), str(src),
                        f"-I{tmp_path}", str(paths["so"]), f"-Wl,-rpath,{tmp_path}"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    out = subprocess.run([str(exe)], capture_output=True, text=True, check=True).stdout
    lines = out.splitlines()
    assert lines[:7] == ["0 3 1", "1.5 -3 0", "3 0 0", "4.5 50 1", "6 -1073741824 0",
                         "7.5 4 1", "9 0 1"]
    # second call: d = -1 (INT_MIN / -1 wraps), lane 2 masked off keeps -1
    assert lines[7] == "-1 6"
    # range [3, 5) with d = 0: division by zero gives 0
    assert lines[8] == "30 40 0 0"
    assert lines[9] == "42"
