"""Kernel calls with arrays in any layout: C-order, Fortran-order, slices with steps, record
arrays, misaligned offsets, scalars, strided masks and ``out=`` arrays all give bit for bit
the results of the call with one contiguous array per component, on every target."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
import rdsl
from _backend_util import runnable_targets

SOURCE = """
struct Probe { n: Vec3, k: Int, on: Bool }

fn mix(p: Vec3, uv: Vec2, s: Float, h: Probe, big: UInt64) -> (Vec4, Int, Bool, UInt64) {
    let d = dot(p, h.n) * s + uv.x;
    let k = select(h.on, h.k * 3 + 1, 0 - h.k);
    let q = Vec4(d, uv.y - p.z, sqrt(abs(p.x)) * s, p.y / (uv.x + 2.0));
    return (q, k, d > 0.0 && h.on, big * 3ul + UInt64(UInt(k)));
}
"""
SIZES = [5, 37, 10_007]  # a tail only; full vectors and a tail on every width; threads


@pytest.fixture(scope="module", params=[
    pytest.param((t.values[0], how), marks=t.marks, id=f"{t.values[0]}-{how}")
    for t in runnable_targets() for how in ("gathers", "shuffles")])
def mix(request: Any) -> Any:
    """``mix`` has 19 arrays, more than SHUFFLED_ARRAYS_LIMIT: its strided loop gathers and
    scatters.  The "shuffles" build raises the limit (and marks its source, so the kernel
    cache keeps the two apart) to test the wide loads and shuffles that smaller kernels
    use."""
    from rdsl.compiler.backends import llvm_entry

    target, how = request.param
    if how == "gathers":
        assert llvm_entry.SHUFFLED_ARRAYS_LIMIT < 19
        return rdsl.jit(SOURCE, target=target)["mix"]
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(llvm_entry, "SHUFFLED_ARRAYS_LIMIT", 64)
        return rdsl.jit(SOURCE + "// built with wide loads and shuffles\n",
                        target=target)["mix"]


def _data(n: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(n)
    return {"p": rng.standard_normal((n, 3)).astype(np.float32),
            "uv": rng.standard_normal((n, 2)).astype(np.float32),
            "s": rng.standard_normal(n).astype(np.float32),
            "n": rng.standard_normal((n, 3)).astype(np.float32),
            "k": rng.integers(-1000, 1000, n).astype(np.int32),
            "on": rng.random(n) < 0.7,
            "big": rng.integers(0, 2 ** 63, n, dtype=np.uint64),
            "mask": rng.random(n) < 0.6}


def _args(d: dict[str, np.ndarray]) -> tuple:
    return d["p"], d["uv"], d["s"], {"n": d["n"], "k": d["k"], "on": d["on"]}, d["big"]


def _contiguous(d: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Every component its own contiguous array (Fortran order for vectors)."""
    return {k: np.asfortranarray(v) for k, v in d.items()}


def _c_order(d: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    return {k: np.ascontiguousarray(v) for k, v in d.items()}


def _stepped(d: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Slices with steps of larger arrays, some of them reversed."""
    out = {}
    for j, (k, v) in enumerate(d.items()):
        shape = (3 * len(v), *v.shape[1:])
        big = np.zeros(shape[:1] + tuple(s + 2 for s in shape[1:]), v.dtype)
        view = big[::3, 1:-1] if v.ndim == 2 else big[::3]
        if j % 2:
            view = view[::-1]
        view[...] = v
        out[k] = view
    return out


def _wide_rows(d: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Vectors as the trailing columns of (N, 4) arrays: a stride of 4 elements."""
    out = dict(d)
    for k in ("p", "uv", "n"):
        v = d[k]
        big = np.zeros((len(v), 4), v.dtype)
        big[:, 4 - v.shape[1]:] = v
        out[k] = big[:, 4 - v.shape[1]:]
    return out


def _records(d: dict[str, np.ndarray], align: bool) -> dict[str, np.ndarray]:
    """Fields of one record array: aligned, or packed (fields at odd offsets)."""
    fields = [("tag", np.uint8)] + [(k, v.dtype, v.shape[1:]) for k, v in d.items()]
    rec = np.zeros(len(d["p"]), np.dtype(fields, align=align))
    rec["tag"] = 0xAB
    for k, v in d.items():
        rec[k] = v
    return {k: rec[k] for k in d}


def _misaligned(d: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Contiguous arrays one byte off their element alignment."""
    out = {}
    for k, v in d.items():
        raw = np.zeros(v.nbytes + 1, np.uint8)
        a = np.ndarray(v.shape, v.dtype, buffer=raw, offset=1)
        a[...] = v
        assert not a.flags.aligned or v.dtype.itemsize == 1
        out[k] = a
    return out


LAYOUTS: dict[str, Callable[[dict[str, np.ndarray]], dict[str, np.ndarray]]] = {
    "c_order": _c_order, "fortran": _contiguous, "stepped": _stepped,
    "wide_rows": _wide_rows, "records": lambda d: _records(d, True),
    "packed_records": lambda d: _records(d, False), "misaligned": _misaligned}


def _bits(a: np.ndarray) -> np.ndarray:
    """The bytes of ``a``'s values (NaN payloads and signed zeros included)."""
    a = np.ascontiguousarray(a)
    return a.view(np.uint8) if a.dtype == np.bool_ else a.view(f"u{a.dtype.itemsize}")


def _same(got: Any, want: Any) -> None:
    assert len(got) == len(want)
    for g, w in zip(got, want):
        assert g.shape == w.shape and g.dtype == w.dtype
        np.testing.assert_array_equal(_bits(g), _bits(w))


@pytest.mark.parametrize("n", SIZES)
@pytest.mark.parametrize("layout", list(LAYOUTS))
def test_layout_matches_contiguous(mix: Any, layout: str, n: int) -> None:
    d = _data(n)
    ref = _contiguous(d)
    want = mix(*_args(ref), threads=2)
    want_m = mix(*_args(ref), mask=ref["mask"], threads=2)
    lay = LAYOUTS[layout](d)
    _same(mix(*_args(lay), threads=2), want)
    _same(mix(*_args(lay), mask=lay["mask"], threads=2), want_m)


def _out_c_order(n: int) -> tuple:
    return (np.full((n, 4), 7, np.float32), np.full(n, 7, np.int32), np.ones(n, np.bool_),
            np.full(n, 7, np.uint64))


def _out_records(n: int) -> tuple:
    rec = np.zeros(n, np.dtype([("tag", np.uint8), ("q", np.float32, (4,)), ("k", np.int32),
                                ("b", np.bool_), ("big", np.uint64)], align=False))
    rec["q"], rec["k"], rec["b"], rec["big"] = 7, 7, True, 7
    return rec["q"], rec["k"], rec["b"], rec["big"]


def _out_stepped(n: int) -> tuple:
    q = np.full((2 * n, 6), 7, np.float32)[::-2, 1:5]
    return q, np.full(3 * n, 7, np.int32)[::3], np.ones(n, np.bool_), np.full(n, 7, np.uint64)


@pytest.mark.parametrize("n", SIZES)
@pytest.mark.parametrize("make_out", [_out_c_order, _out_records, _out_stepped])
def test_out_in_any_layout(mix: Any, make_out: Callable[[int], tuple], n: int) -> None:
    d = _c_order(_data(n))
    want = mix(*_args(_contiguous(d)), threads=2)
    out = make_out(n)
    assert mix(*_args(d), out=out, threads=2) is out
    _same(out, want)
    # masked: the lanes outside the mask keep what ``out`` held
    out = make_out(n)
    before = tuple(np.copy(a) for a in out)
    mix(*_args(d), mask=d["mask"][::-1], out=out, threads=2)
    keep = ~d["mask"][::-1]
    for o, b, w in zip(out, before, want):
        np.testing.assert_array_equal(_bits(o[keep]), _bits(b[keep]))
        np.testing.assert_array_equal(_bits(o[~keep]), _bits(w[~keep]))


def test_scalars_and_conversions(mix: Any) -> None:
    """A Python scalar is one value for every element (stride 0); arrays of other dtypes
    are converted first, with the results of converting them by hand."""
    d = _data(37)
    p64, s = d["p"].astype(np.float64), np.float32(0.75)
    want = mix(p64.astype(np.float32), d["uv"], np.full(37, s), *_args(d)[3:])
    _same(mix(p64, d["uv"], 0.75, *_args(d)[3:]), want)
    h = {"n": d["n"], "k": d["k"].astype(np.int64), "on": d["on"].astype(np.int16) * 5}
    want = mix(d["p"], d["uv"], d["s"], {"n": d["n"], "k": d["k"], "on": d["on"]}, d["big"])
    _same(mix(d["p"], d["uv"], d["s"], h, d["big"], mask=np.ones(37, np.int8)), want)


def test_errors_stay_clear(mix: Any) -> None:
    d = _data(37)
    p, uv, s, h, big = _args(d)
    with pytest.raises(ValueError, match=r"parameter `p` expects a float32 array of shape "
                                         r"\(N, 3\), got shape \(37, 4\)"):
        mix(np.zeros((37, 4), np.float32), uv, s, h, big)
    with pytest.raises(ValueError, match=r"parameter `s` expects a float32 array .* got dtype "
                                         r"complex64"):
        mix(p, uv, s.astype(np.complex64), h, big)
    with pytest.raises(ValueError, match=r"`uv` has 36 elements, expected 37"):
        mix(p, uv[1:], s, h, big)
    out = _out_c_order(37)
    with pytest.raises(ValueError, match=r"`out` is not a result of this kernel over 37"):
        mix(p, uv, s, h, big, out=(out[0].astype(np.float64), *out[1:]))
    with pytest.raises(ValueError, match=r"`out` is not a result of this kernel over 37"):
        mix(p, uv, s, h, big, out=(out[0][:, :3], *out[1:]))
    frozen = out[0].copy()
    frozen.flags.writeable = False
    with pytest.raises(ValueError, match=r"`out` is not a result of this kernel over 37"):
        mix(p, uv, s, h, big, out=(frozen, *out[1:]))


GROUPED = """
fn split(p: Vec3, s: Float) -> (Vec3, Vec2, Vec3) {
    return (p * s, Vec2(p.x - s, p.y / (s + 3.0)), Vec3(s, p.z, sqrt(abs(p.y))));
}
"""


def _outs_grouped(n: int) -> list[tuple]:
    """``out=`` layouts for split's (Vec3, Vec2, Vec3): C-order (N, 3) and (N, 2) arrays
    (written interleaved, one store per vector), and ones that only look alike: columns of
    one (N, 8) array, reversed columns, Fortran order."""
    wide = np.full((n, 8), 7, np.float32)
    return [(np.full((n, 3), 7, np.float32), np.full((n, 2), 7, np.float32),
             np.full((n, 3), 7, np.float32)),
            (wide[:, :3], wide[:, 3:5], wide[:, 5:]),
            (np.full((n, 3), 7, np.float32)[:, ::-1], np.full((n, 2), 7, np.float32),
             np.asfortranarray(np.full((n, 3), 7, np.float32)))]


@pytest.mark.parametrize("target", runnable_targets())
def test_out_vectors_interleaved(target: str) -> None:
    """Vector results written into C-order ``out=`` arrays (their components interleaved in
    registers) are bit for bit the contiguous call's, with and without a mask."""
    k = rdsl.jit(GROUPED, target=target)["split"]
    for n in SIZES:
        d = _data(n)
        want = k(np.asfortranarray(d["p"]), d["s"], threads=2)
        for out in _outs_grouped(n):
            _same(k(d["p"], d["s"], out=out, threads=2), want)
        for out in _outs_grouped(n):
            before = tuple(np.copy(a) for a in out)
            k(d["p"], d["s"], mask=d["mask"], out=out, threads=2)
            on = d["mask"]
            for o, b, w in zip(out, before, want):
                np.testing.assert_array_equal(_bits(o[~on]), _bits(b[~on]))
                np.testing.assert_array_equal(_bits(o[on]), _bits(w[on]))



def _overlapping_outs(n: int, p: np.ndarray) -> dict[str, tuple]:
    """``out=`` arrays for split over the memory of its input ``p`` (rows ``[0, n)`` of an
    (n + 1, 3) array): lane i's results written where other lanes read their inputs
    (reversed, one row on), or where only lane i reads (in place, its row's columns)."""
    vec2 = np.zeros((n, 2), np.float32)
    return {"reversed": (p[::-1], vec2, np.zeros((n, 3), np.float32)),
            "next_row": (np.zeros((n, 3), np.float32), vec2, p.base[1:]),
            "in_place": (p, vec2, np.zeros((n, 3), np.float32)),
            "own_row": (p[:, ::-1], vec2, np.zeros((n, 3), np.float32))}


@pytest.mark.parametrize("target", runnable_targets())
def test_out_over_the_inputs(target: str) -> None:
    """An ``out=`` array over the memory of an input (the mask too) gives the results of the
    call with separate arrays, as numpy's ufuncs do: where another lane would read what lane
    i wrote, the input is copied first.  Two results in the same memory are an error."""
    k = rdsl.jit(GROUPED, target=target)["split"]
    positive = rdsl.jit("fn positive(x: Float) -> Bool { return x > 0.0; }",
                        target=target)["positive"]
    for n in SIZES:
        d = _data(n)
        want = k(d["p"], d["s"], threads=2)
        for layout in _overlapping_outs(n, np.zeros((n + 1, 3), np.float32)[:-1]):
            p = np.zeros((n + 1, 3), np.float32)[:-1]
            p[...] = d["p"]
            out = _overlapping_outs(n, p)[layout]
            got = k(p, d["s"], out=out, threads=2)
            assert got is out
            for g, w in zip(got, want):
                np.testing.assert_array_equal(_bits(g), _bits(w), err_msg=layout)
        on = d["mask"].copy()
        got = positive(d["s"], mask=on, out=on[::-1], threads=2)
        np.testing.assert_array_equal(got, np.where(d["mask"], d["s"] > 0, d["mask"][::-1]))
    p, s, vec3 = d["p"], d["s"], np.zeros((n, 3), np.float32)
    with pytest.raises(ValueError, match=r"split\(\): `out` gives results `ret.0.x` and "
                                         r"`ret.2.x` the same memory"):
        k(p, s, out=(vec3, np.zeros((n, 2), np.float32), vec3))
