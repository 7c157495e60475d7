"""Loads and stores of one vector of a kernel's array arguments, in LLVM, for any byte stride.

An entry point receives every array as a base pointer and a byte stride (ABI 2, see
:mod:`rdsl.compiler.backends.base`): element i is at ``base + i * stride``.  Once per call,
:meth:`ArrayAccess.prepare` classifies each array, and each access is emitted one of three
ways (``how``):

* ``contiguous``: the array is known to be contiguous and aligned to its element size (the
  entry point checked every array first): plain vector loads and stores, masked ones in the
  tail or under a user mask.  The loops contiguous callers run: the same code as before
  strides existed.
* ``strided`` (the loop over full vectors when some array is not contiguous): a branch on
  the array's layout, always the same way within a call, between the contiguous access;
  for strides of 2, 3 or 4 elements (columns of C-order ``(N, 2)``, ``(N, 3)``, ``(N, 4)``
  arrays) one wide load of the vectors' span and a shuffle, or a masked store of the
  interleaved vector that writes only the array's own elements; and for any other stride
  (record fields, negative steps, stride 0) gathers and scatters.
* ``any`` (the tail): the contiguous access or gathers and scatters.

The 2, 3 or 4 arrays of one vector argument or result (``wi.x``, ``wi.y``, ``wi.z``) are an
:class:`ArrayGroup` as well: when they are the columns of one C-order ``(N, k)`` array
(checked once per call), the strided loop reads them with one load of the k * W elements'
span and a shuffle each, and writes them interleaved in registers with one store, in place
of a masked store per column over that span.

Measured on ``bench/ggx_kernel.rdsl`` (4M samples, one thread, medians of 11 calls
alternated in one process, CPU time, AVX-512 / AVX2), time over the component-array call:
C-order ``(N, 3)``/``(N, 2)`` inputs +0.7% / +10% grouped, +1.1% / +12% per column, +4.4% /
+19% by gathers; with a C-order ``(N, 4)`` ``out=`` as well, +1.0% / +13% grouped, +10% /
+24% by a masked store per column, +25% / +32% by scatters.
Earlier, on ``bench/ggx_kernel.rdsl`` (4M samples, one thread, median CPU time on a loaded
2-core AVX-512 machine), C-order ``(N, 3)``/``(N, 2)`` inputs against one contiguous array
per component, AVX-512 / AVX2: wide loads and shuffles +4% / +13%, gathers +6% / +23%;
writing a C-order ``(N, 4)`` ``out=`` as well: wide masked stores +14% / +21%, scatters
+34% / +36%.  In earlier runs per-lane loads and inserts were 37% slower than gathers on
AVX-512 (equal on AVX2, where LLVM scalarized the gathers itself until the avx2 target got
``+fast-gather``: these AVX2 numbers are from before it), and gathers with 32-bit lane offsets 5% faster than 64-bit ones on
AVX-512 only; just the 64-bit form is kept (no range check, less code to compile).
Branching per access inside the contiguous loops cost AVX2 10 to 16%, hence their own copy.
Loads and stores of strided arrays assume no alignment (align 1).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import llvmlite.ir as L

from .llvm_ops import ALIGN, I1, I8, I32, I64, MEM, PTR, const, mangle

SHUFFLE_FACTORS = (3, 2, 4)  # strides (in elements) read by a wide load and a shuffle


class StridedArray:
    """One array argument: its element dtype, base pointer and byte stride, and what
    ``prepare`` computes once per call from them."""

    def __init__(self, dtype: str, ptr: L.Value, stride: L.Value) -> None:
        self.dtype, self.ptr, self.stride = dtype, ptr, stride
        self.contiguous: L.Value | None = None  # i1: stride == size, base aligned
        self.factor: dict[int, L.Value] = {}  # k -> i1: stride == k * size
        self.offsets: L.Value | None = None  # <W x i64>: lane * stride


class ArrayGroup:
    """The k arrays of one vector argument or result (``wi.x``, ``wi.y``, ...) that may be
    the k columns of one C-order ``(N, k)`` array: ``prepare_group`` checks, once per call,
    that each starts one element after the one before and that every stride is k
    elements."""

    def __init__(self, members: list[StridedArray]) -> None:
        self.members = members
        self.ok: L.Value | None = None  # i1: one interleaved array


class ArrayAccess:
    """Emits the accesses of one entry point's arrays into the function ``fn`` through the
    builder ``b``, for W lanes; ``end`` bounds the elements that exist past a vector."""

    def __init__(self, ml: Any, fn: L.Function, b: L.IRBuilder, end: L.Value) -> None:
        self.ml, self.fn, self.b, self.W, self.end = ml, fn, b, ml.width, end
        self.mask_ty = L.VectorType(I1, self.W) if self.W > 1 else I1

    # -- once per call -------------------------------------------------------------------
    def prepare(self, arr: StridedArray) -> None:
        """Classify ``arr`` (emitted where the builder is: before the loops)."""
        if self.W == 1:
            return  # one element per step: base + i * stride is all there is
        b, W, size = self.b, self.W, ALIGN[arr.dtype]
        ok = b.icmp_signed("==", arr.stride, const(I64, size))
        if size > 1:
            low = b.and_(b.ptrtoint(arr.ptr, I64), const(I64, size - 1))
            ok = b.and_(ok, b.icmp_signed("==", low, const(I64, 0)))
        arr.contiguous = ok
        arr.factor = {k: b.icmp_signed("==", arr.stride, const(I64, k * size))
                      for k in SHUFFLE_FACTORS}
        lanes = L.Constant(L.VectorType(I64, W), [L.Constant(I64, k) for k in range(W)])
        arr.offsets = b.mul(lanes, self.ml.splat(b, arr.stride, W))

    def prepare_group(self, g: ArrayGroup) -> None:
        """Check whether the members of ``g`` interleave into one array (see ArrayGroup)."""
        b, first, k = self.b, g.members[0], len(g.members)
        size = ALIGN[first.dtype]
        base = b.ptrtoint(first.ptr, I64)
        ok = None
        for j, m in enumerate(g.members):
            same = b.icmp_signed("==", m.stride, const(I64, k * size))
            if j:
                at = b.icmp_signed("==", b.ptrtoint(m.ptr, I64), b.add(base, const(I64, j * size)))
                same = b.and_(same, at)
            ok = same if ok is None else b.and_(ok, same)
        g.ok = ok

    # -- helpers -------------------------------------------------------------------------
    def vec_ty(self, dtype: str) -> L.Type:
        return L.VectorType(MEM[dtype], self.W) if self.W > 1 else MEM[dtype]

    def element(self, arr: StridedArray, i: L.Value) -> L.Value:
        """The address of element i."""
        return self.b.gep(arr.ptr, [self.b.mul(i, arr.stride)], source_etype=I8)

    def lane_ptrs(self, arr: StridedArray, i: L.Value) -> L.Value:
        """The addresses of elements i .. i + W - 1."""
        g = self.b.gep(self.element(arr, i), [arr.offsets], source_etype=I8)
        g.type = L.VectorType(PTR, self.W)  # llvmlite assumes a scalar result
        return g

    def branch(self, cond: L.Value, then: Callable[[], Any], other: Callable[[], Any]
               ) -> L.Value | None:
        """``then()`` or ``other()`` (each emits code and returns a value or None) by
        ``cond``; the phi of their values."""
        b = self.b
        t_bb = self.fn.append_basic_block("then")
        o_bb = self.fn.append_basic_block("else")
        join = self.fn.append_basic_block("join")
        b.cbranch(cond, t_bb, o_bb)
        b.position_at_end(t_bb)
        vt = then()
        t_end = b.block
        b.branch(join)
        b.position_at_end(o_bb)
        vo = other()
        o_end = b.block
        b.branch(join)
        b.position_at_end(join)
        if vt is None:
            return None
        if isinstance(vt, list):  # several values: a phi each
            return [self._phi(x, t_end, y, o_end) for x, y in zip(vt, vo)]
        return self._phi(vt, t_end, vo, o_end)

    def _phi(self, vt: L.Value, t_end: L.Block, vo: L.Value, o_end: L.Block) -> L.Value:
        phi = self.b.phi(vt.type)
        phi.add_incoming(vt, t_end)
        phi.add_incoming(vo, o_end)
        return phi

    def by_factor(self, arr: StridedArray, cond: Callable[[int], L.Value],
                  shuffled: Callable[[int], Any], other: Callable[[], Any],
                  ks: tuple[int, ...] = SHUFFLE_FACTORS) -> L.Value | None:
        """A chain of branches: ``shuffled(k)`` for the first k whose ``cond(k)`` holds,
        else ``other()``."""
        if not ks:
            return other()
        k = ks[0]
        return self.branch(cond(k), lambda: shuffled(k),
                           lambda: self.by_factor(arr, cond, shuffled, other, ks[1:]))

    def intrinsic(self, name: str, ret: L.Type, args: list[L.Value]) -> L.Value:
        return self.b.call(self.ml.intrinsic(name, ret, [a.type for a in args]), args)

    # -- loads ---------------------------------------------------------------------------
    def load(self, arr: StridedArray, i: L.Value, lanes: L.Value | None, how: str
             ) -> L.Value:
        """Elements i .. i + W - 1 of ``arr`` as a vector in memory layout; ``lanes``: the
        tail's lane mask (the other lanes are not read), None for a full vector.  ``how``:
        "contiguous" (known to be), "strided" (a branch between the contiguous access, wide
        loads and gathers) or "any" (between the contiguous access and gathers)."""
        b, ty, size = self.b, self.vec_ty(arr.dtype), ALIGN[arr.dtype]
        if self.W == 1:
            return b.load(self.element(arr, i), typ=ty, align=1)

        def contiguous() -> L.Value:
            p = b.gep(arr.ptr, [i], source_etype=MEM[arr.dtype])
            if lanes is None:
                return b.load(p, typ=ty, align=size)
            return self.intrinsic(f"llvm.masked.load.{mangle(ty)}.p0", ty,
                                  [p, const(I32, size), lanes, const(ty, 0)])

        def strided() -> L.Value:
            if lanes is not None or how == "any":
                return self.gather(arr, i, lanes if lanes is not None
                                   else const(self.mask_ty, 1))
            # the wide load reads up to element i + W's address: only when that exists
            more = b.icmp_signed("<", b.add(i, const(I64, self.W)), self.end)
            return self.by_factor(arr, lambda k: b.and_(arr.factor[k], more),
                                  lambda k: self.wide_load(arr, i, k),
                                  lambda: self.gather(arr, i, const(self.mask_ty, 1)))

        if how == "contiguous":
            return contiguous()
        return self.branch(arr.contiguous, contiguous, strided)

    def wide_load(self, arr: StridedArray, i: L.Value, k: int) -> L.Value:
        """Elements i .. i + W - 1 of an array of stride k elements: every k-th of the
        k * W elements from element i."""
        b, W = self.b, self.W
        wide = L.VectorType(MEM[arr.dtype], k * W)
        v = b.load(self.element(arr, i), typ=wide, align=1)
        pick = L.Constant(L.VectorType(I32, W), [L.Constant(I32, k * j) for j in range(W)])
        return b.shuffle_vector(v, L.Constant(wide, None), pick)

    def load_group(self, g: ArrayGroup, i: L.Value) -> list[L.Value]:
        """Elements i .. i + W - 1 of every member of ``g`` (its ``ok`` holds): one load of
        the k * W elements' span (all inside the array, unlike a member's own wide load)
        and a shuffle per member."""
        b, W, k = self.b, self.W, len(g.members)
        wide = L.VectorType(MEM[g.members[0].dtype], k * W)
        v = b.load(self.element(g.members[0], i), typ=wide, align=1)
        picks = [L.Constant(L.VectorType(I32, W), [L.Constant(I32, k * x + j)
                                                   for x in range(W)]) for j in range(k)]
        return [b.shuffle_vector(v, L.Constant(wide, None), pick) for pick in picks]

    def gather(self, arr: StridedArray, i: L.Value, lanes: L.Value) -> L.Value:
        ty = self.vec_ty(arr.dtype)
        ptrs = self.lane_ptrs(arr, i)
        return self.intrinsic(f"llvm.masked.gather.{mangle(ty)}.{mangle(ptrs.type)}", ty,
                              [ptrs, const(I32, 1), lanes, const(ty, 0)])

    # -- stores --------------------------------------------------------------------------
    def store(self, arr: StridedArray, i: L.Value, v: L.Value, mask: L.Value | None,
              how: str, masked: L.Value | None = None) -> None:
        """Store the vector ``v`` (memory layout) at elements i .. i + W - 1 of ``arr`` on
        the lanes of ``mask`` (None: every lane); other lanes' memory is not written.
        ``how`` as for :meth:`load` (wide stores in place of wide loads).  ``masked``: an
        i1 saying whether ``mask`` may have inactive lanes; where it does not, a contiguous
        array takes a plain store (a masked one is slow on AVX2 and without AVX)."""
        b, size = self.b, ALIGN[arr.dtype]
        if self.W == 1:
            p = self.element(arr, i)
            if mask is None:
                b.store(v, p, align=1)
            else:
                with b.if_then(mask):
                    b.store(v, p, align=1)
            return

        def plain() -> None:
            b.store(v, b.gep(arr.ptr, [i], source_etype=MEM[arr.dtype]), align=size)

        def under_mask() -> None:
            p = b.gep(arr.ptr, [i], source_etype=MEM[arr.dtype])
            self.intrinsic(f"llvm.masked.store.{mangle(v.type)}.p0", L.VoidType(),
                           [v, p, const(I32, size), mask])

        def contiguous() -> None:
            self.plain_or_masked(mask, masked, plain, under_mask)

        def strided() -> None:
            m = mask if mask is not None else const(self.mask_ty, 1)
            if how == "any":
                self.scatter(arr, i, v, m)
                return
            self.by_factor(arr, lambda k: arr.factor[k],
                           lambda k: self.wide_store(arr, i, v, m, k),
                           lambda: self.scatter(arr, i, v, m))

        if how == "contiguous":
            contiguous()
        else:
            self.branch(arr.contiguous, contiguous, strided)

    def wide_store(self, arr: StridedArray, i: L.Value, v: L.Value, m: L.Value,
                   k: int) -> None:
        """Store into an array of stride k elements: ``v`` spread to every k-th lane of a
        k * W vector, written with a masked store that leaves the lanes between alone."""
        b, W = self.b, self.W
        wide = L.VectorType(v.type.element, k * W)
        spread = L.Constant(L.VectorType(I32, k * W),
                            [L.Constant(I32, j // k if j % k == 0 else W) for j in range(k * W)])
        wv = b.shuffle_vector(v, L.Constant(v.type, None), spread)
        wm = b.shuffle_vector(m, const(self.mask_ty, 0), spread)
        self.intrinsic(f"llvm.masked.store.{mangle(wide)}.p0", L.VoidType(),
                       [wv, self.element(arr, i), const(I32, 1), wm])

    def store_group(self, g: ArrayGroup, i: L.Value, vs: list[L.Value], mask: L.Value | None,
                    masked: L.Value | None = None) -> None:
        """Store ``vs`` (one vector per member of ``g``, whose ``ok`` holds) at elements
        i .. i + W - 1: interleaved in registers, then one store of the k * W elements'
        span, masked by ``mask`` spread to every member (None: every lane; ``masked`` as
        for :meth:`store`)."""
        b, W, k = self.b, self.W, len(vs)
        parts = list(vs)
        while len(parts) & (len(parts) - 1):  # pad to a power of two, then concatenate
            parts.append(L.Constant(vs[0].type, None))
        while len(parts) > 1:
            n = parts[0].type.count
            both = L.Constant(L.VectorType(I32, 2 * n), [L.Constant(I32, x)
                                                       for x in range(2 * n)])
            parts = [b.shuffle_vector(parts[x], parts[x + 1], both)
                     for x in range(0, len(parts), 2)]
        # lane j * W + l of the concatenation is member j's lane l: put it at k * l + j
        pick = L.Constant(L.VectorType(I32, k * W),
                          [L.Constant(I32, (x % k) * W + x // k) for x in range(k * W)])
        wv = b.shuffle_vector(parts[0], L.Constant(parts[0].type, None), pick)
        p = self.element(g.members[0], i)

        def plain() -> None:
            b.store(wv, p, align=1)

        def under_mask() -> None:
            spread = L.Constant(L.VectorType(I32, k * W), [L.Constant(I32, x // k)
                                                           for x in range(k * W)])
            wm = b.shuffle_vector(mask, const(self.mask_ty, 0), spread)
            self.intrinsic(f"llvm.masked.store.{mangle(wv.type)}.p0", L.VoidType(),
                           [wv, p, const(I32, 1), wm])

        self.plain_or_masked(mask, masked, plain, under_mask)

    def plain_or_masked(self, mask: L.Value | None, masked: L.Value | None,
                        plain: Callable[[], None], under_mask: Callable[[], None]) -> None:
        """A store: ``plain()`` without a mask, ``under_mask()`` with one, or the choice
        at run time where ``masked`` says whether the mask may have inactive lanes."""
        if mask is None:
            plain()
        elif masked is None:
            under_mask()
        else:
            self.branch(masked, under_mask, plain)

    def scatter(self, arr: StridedArray, i: L.Value, v: L.Value, m: L.Value) -> None:
        ptrs = self.lane_ptrs(arr, i)
        self.intrinsic(f"llvm.masked.scatter.{mangle(v.type)}.{mangle(ptrs.type)}",
                       L.VoidType(), [v, ptrs, const(I32, 1), m])
