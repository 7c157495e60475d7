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
    const int64_t F = sizeof(float), I = sizeof(int32_t);
    rdsl_demo_kernel(7, x, F, 1.5f, i, I, 2, buf, y, F, q, I, pos, 1, NULL, 0);
    for (int k = 0; k < 7; k++) printf("%g %d %d\n", y[k], q[k], pos[k]);
    y[2] = -1.0f;
    rdsl_demo_kernel(7, x, F, 2.0f, i, I, -1, buf, y, F, q, I, pos, 1, m, 1);
    printf("%g %g\n", y[2], y[3]);
    rdsl_demo_kernel_range(3, 5, x, F, 10.0f, i, I, 0, buf, y, F, q, I, pos, 1, NULL, 0);
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


def _run_c(cc: str, tmp_path, so, source: str) -> list[str]:
    """Compile ``source`` against the generated header and library, run it, its lines."""
    src = tmp_path / "main.c"
    src.write_text(source)
    exe = tmp_path / "main"
    r = subprocess.run([cc, "-std=c99", "-Wall", "-Werror", "-o", str(exe), str(src),
                        f"-I{tmp_path}", str(so), f"-Wl,-rpath,{tmp_path}"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    out = subprocess.run([str(exe)], capture_output=True, text=True, check=True).stdout
    return out.splitlines()


def test_c_program_calls_kernel(tmp_path):
    cc = shutil.which("cc")
    if cc is None:
        pytest.skip("no C compiler (`cc`) on PATH")
    t = host_target()
    paths = build_library(_module(t.width), t, tmp_path, "shade")
    header = paths["header"].read_text()
    assert "#include <stdint.h>" in header
    assert ("void rdsl_demo_kernel(int64_t n, const float* x, int64_t x_stride, float scale, "
            "const int32_t* i, int64_t i_stride, int32_t d, float* buf, "
            "float* out_ret_0, int64_t out_ret_0_stride, int32_t* out_ret_1, "
            "int64_t out_ret_1_stride, uint8_t* out_ret_2, int64_t out_ret_2_stride, "
            "const uint8_t* mask, int64_t mask_stride);") in header
    assert "#define RDSL_ABI_VERSION 2" in header
    lines = _run_c(cc, tmp_path, paths["so"], C_MAIN)
    assert lines[:7] == ["0 3 1", "1.5 -3 0", "3 0 0", "4.5 50 1", "6 -1073741824 0",
                         "7.5 4 1", "9 0 1"]
    # second call: d = -1 (INT_MIN / -1 wraps), lane 2 masked off keeps -1
    assert lines[7] == "-1 6"
    # range [3, 5) with d = 0: division by zero gives 0
    assert lines[8] == "30 40 0 0"
    assert lines[9] == "42"


# An array of structures from C: the kernel reads x and i and writes its three results into
# the records themselves, with the mask a field of each record too.  A packed record puts
# the floats at odd offsets (no alignment) and 37 records cover full vectors and a tail on
# every target.
C_AOS = r"""
#include <stddef.h>
#include <stdio.h>
#include "shade.h"

#pragma pack(push, 1)
typedef struct { uint8_t tag; float x; int32_t i; float y; int32_t q; uint8_t pos, on; } Rec;
#pragma pack(pop)

int main(void) {
    Rec r[37];
    for (int k = 0; k < 37; k++) {
        r[k].tag = 0xAB; r[k].x = (float)k; r[k].i = 10 * k - 60;
        r[k].y = -1.0f; r[k].q = -1; r[k].pos = 7; r[k].on = (uint8_t)(k % 3 != 1);
    }
    float buf[1] = {0};
    const char* b = (const char*)r;
    const int64_t S = sizeof(Rec);
    rdsl_demo_kernel(37, (const float*)(const void*)(b + offsetof(Rec, x)), S, 0.5f,
                     (const int32_t*)(const void*)(b + offsetof(Rec, i)), S, 3, buf,
                     (float*)(void*)((char*)r + offsetof(Rec, y)), S,
                     (int32_t*)(void*)((char*)r + offsetof(Rec, q)), S,
                     &r[0].pos, S, &r[0].on, S);
    for (int k = 0; k < 37; k++)
        printf("%g %d %d %d %g %d\n", r[k].y, r[k].q, r[k].pos, r[k].tag, r[k].x, r[k].i);
    return 0;
}
"""


def test_c_program_passes_an_array_of_structures(tmp_path):
    cc = shutil.which("cc")
    if cc is None:
        pytest.skip("no C compiler (`cc`) on PATH")
    t = host_target()
    paths = build_library(_module(t.width), t, tmp_path, "shade")
    lines = _run_c(cc, tmp_path, paths["so"], C_AOS)
    want = []
    for k in range(37):
        i = 10 * k - 60
        if k % 3 != 1:  # active: x * 0.5, i / 3 (truncating), i > 0
            q = abs(i) // 3 * (1 if i >= 0 else -1)
            want.append(f"{k * 0.5:g} {q} {int(i > 0)} 171 {k:g} {i}")
        else:  # masked off: the outputs keep their old values, the other fields too
            want.append(f"-1 -1 7 171 {k:g} {i}")
    assert lines == want
