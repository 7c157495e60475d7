"""Native callbacks of rdsl's Embree user geometries (analytic spheres and disks, SDF grids),
in LLVM IR.

Embree calls a user geometry's intersect and occluded callbacks during traversal, from the
compiled kernels' ``rtcIntersectN``/``rtcOccludedN``.  Those callbacks are generated here as
LLVM IR (llvmlite), compiled once (a cached shared library: native_lib.py); :func:`callback_addresses`
hands their addresses to the runtime (``runtime/embree_user.py``), which binds them to each
geometry, so no Python runs per ray.  The bounds callback is native too (it only copies a
box).

Each geometry owns a block of doubles (its ``geometryUserPtr``, laid out by
:data:`rdsl.core.embree_abi.USER_BLOCK`); world space throughout:

    sphere  [0:3] center, [3] radius
    disk    [0:12] rows of to_object (3 x 4), [12:15] the geometric normal (unit, unflipped)
    sdfgrid [0] address of its rdsl kernel, [1] address of its record (int64 bit patterns)
    all     [16:19] lower corner of the bounding box, [19:22] upper corner

The callbacks follow the ``RTCIntersectFunctionNArguments`` / ``RTCOccludedFunctionNArguments``
ABI of ``embree4/rtcore_geometry.h`` (64-bit):

    int* valid @0, void* geometryUserPtr @8, uint primID @16, RTCRayQueryContext* context @24,
    RTCRayHitN* rayhit (or RTCRayN* ray) @32, uint N @40, uint geomID @44

and handle any ``N`` (Embree passes 1 or a packet width): lane ``i`` is active when
``valid[i] != 0``; field ``k`` of ``RAY_FIELDS``/``HIT_FIELDS`` is the float/uint at index
``k * N + i`` of the ray (hit rows start after the 12 ray rows).  A hit is reported only for
``tnear <= t <= tfar``, as Embree requires, by writing ``tfar``, ``Ng``, ``u``, ``v``,
``primID``, ``geomID`` and ``instID[0]`` (occluded: ``tfar = -inf``).  The arithmetic is in
double precision, as Mitsuba's sphere intersection on the CPU:

- sphere: Mitsuba's robust form, which moves the origin to the point of the ray closest to
  the center before solving the quadratic; ``Ng = hit point - center``, ``u = v = 0``;
- disk: the ray in object space meets z = 0 inside the unit circle; ``u, v`` are the local
  coordinates x, y of the hit (stdlib/render/geometry.rdsl rebuilds the point from them);
- sdfgrid: the callback calls the shape's kernel, written in rdsl
  (stdlib/render/sdfgrid_kernel.rdsl: a walk over the voxels the ray crosses, Mitsuba's
  per-voxel root finding); ``u`` = the index of the hit's voxel.
"""

from __future__ import annotations

import threading
from typing import Any

import llvmlite.ir as L

from ...core.embree_abi import HIT_FIELDS, RAY_FIELDS, USER_BLOCK, USER_CALLBACKS, EmbreeError
from .native_lib import address_of, load_native_from

_engine: Any = None
_addresses: dict[str, int] = {}
_lock = threading.Lock()


def callback_addresses() -> dict[str, int]:
    """Addresses of the native callbacks (JIT-compiled on first use, once per process):
    ``bounds``, ``sphere_intersect``, ``sphere_occluded``, ``disk_intersect``,
    ``disk_occluded``."""
    global _engine
    with _lock:
        if not _addresses:
            import llvmlite.binding as llvm

            llvm.initialize_native_target()
            llvm.initialize_native_asmprinter()
            cpu, features = llvm.get_host_cpu_name(), llvm.get_host_cpu_features().flatten()

            def build() -> tuple[Any, Any]:  # only when the library is not cached
                mod = llvm.parse_assembly(str(build_module()))
                mod.verify()
                tm = llvm.Target.from_default_triple().create_target_machine(
                    cpu=cpu, features=features, opt=3, reloc="pic")
                _optimize(llvm, mod, tm)
                return mod, tm

            # the IR is this file's (and core/embree_abi.py's) doing, which the compiler's
            # fingerprint in the key covers, and llvmlite's: it is not even built when cached
            lib = load_native_from(f"rdsl_embree_user llvmlite {_llvmlite_version()}",
                                   f"{cpu} {features} O3", "the Embree user-geometry callbacks",
                                   build)
            addrs = {n: address_of(lib, f"rdsl_user_{n}") for n in USER_CALLBACKS}
            if not all(addrs.values()):
                raise EmbreeError("the compiled user-geometry callbacks are incomplete")
            _engine = lib  # keeps the code mapped for the process
            _addresses.update(addrs)
        return dict(_addresses)


def _llvmlite_version() -> str:
    import llvmlite

    return llvmlite.__version__


def _optimize(llvm: Any, mod: Any, tm: Any) -> None:
    """LLVM's O3 module passes on the callbacks.  Unoptimized, the scalar loop was a quarter
    of the render time of a scene of sphere lights (bench/scene_set.py, veach).  LLVM's loop
    vectorizer does not vectorize the lane loop (its stores are conditional), so packets of
    :data:`PACKET_WIDTHS` lanes take explicit vector code (``_lane_loop``'s ``packet``):
    ``rdsl_user_sphere_occluded`` went from 15.9% to 2.0% of `perf` samples of a veach
    render loop on an AMD EPYC (AVX-512) host, the whole loop's samples -13%."""
    pto = llvm.PipelineTuningOptions(speed_level=3)
    pto.loop_vectorization = True
    pto.slp_vectorization = True
    pb = llvm.create_pass_builder(tm, pto)
    pb.getModulePassManager().run(mod, pb)


def build_module() -> Any:
    """The llvmlite module of the callbacks (``rdsl_user_<name>``, each ``void (ptr)``)."""
    mod = L.Module(name="rdsl_embree_user")
    _bounds_function(mod)
    for kind, test in (("sphere", _sphere_test), ("disk", _disk_test),
                       ("sdfgrid", _sdfgrid_test)):
        for query in ("intersect", "occluded"):
            _query_function(mod, kind, query, test)
    _backface_filter(mod)
    return mod


def _backface_filter(mod: Any) -> None:
    """``rdsl_user_backface_filter``: an Embree filter function that rejects the hits whose
    geometric normal faces along the ray (runtime/embree_curves.py sets it on curves:
    Mitsuba's Embree is built with EMBREE_BACKFACE_CULLING_CURVES, embreex's is not).

    RTCFilterFunctionNArguments: int* valid @0, void* geometryUserPtr @8, context @16,
    RTCRayN* ray @24, RTCHitN* hit @32, uint N @40; row k of the ray or the hit holds lane
    i at index ``k * N + i``."""
    fn = L.Function(mod, L.FunctionType(L.VoidType(), [L.PointerType()]),
                    "rdsl_user_backface_filter")

    def lane(x: _IR, args: Any, i: Any, n: Any, nxt: Any) -> None:
        b = x.b
        rays, hits = x.byte(args, x.ptr, 24), x.byte(args, x.ptr, 32)

        def row(base: Any, k: int) -> Any:
            return x.load(base, x.f32, b.add(b.mul(x.c(x.i64, k), n), i))

        d = [row(rays, RAY_FIELDS.index(f"dir_{a}")) for a in "xyz"]
        ng = [row(hits, HIT_FIELDS.index(f"Ng_{a}")) for a in "xyz"]
        facing = b.fadd(b.fadd(b.fmul(d[0], ng[0]), b.fmul(d[1], ng[1])), b.fmul(d[2], ng[2]))
        slot = x.at(x.byte(args, x.ptr, 0), x.i32, i)
        back = b.fcmp_ordered(">", facing, x.c(x.f32, 0.0))
        b.store(b.select(back, x.c(x.i32, 0), b.load(slot, typ=x.i32)), slot)
        b.branch(nxt)

    _lane_loop(fn, 40, lane)


class _IR:
    """Shorthands for the IR builders below.  ``width`` > 1: the tests compute on vectors of
    that many lanes (:meth:`k` and :meth:`uniform` give them their constants and the
    geometry's numbers, splat); addresses and indices stay scalar (:meth:`c`)."""

    def __init__(self, b: Any, width: int = 1) -> None:
        self.L, self.b, self.width = L, b, width
        self.f32, self.f64, self.i32, self.i64 = L.FloatType(), L.DoubleType(), \
            L.IntType(32), L.IntType(64)
        self.i8, self.ptr = L.IntType(8), L.PointerType()

    def c(self, ty: Any, v: Any) -> Any:
        return self.L.Constant(ty, v)

    def lanes(self, ty: Any) -> Any:
        """``ty``, or a vector of ``width`` of it."""
        return ty if self.width == 1 else L.VectorType(ty, self.width)

    def k(self, ty: Any, v: Any) -> Any:
        """The constant ``v`` in every lane."""
        return self.c(ty, v) if self.width == 1 else \
            L.Constant(self.lanes(ty), [L.Constant(ty, v)] * self.width)

    def uniform(self, value: Any) -> Any:
        """A scalar ``value`` in every lane."""
        if self.width == 1:
            return value
        vt = self.lanes(value.type)
        one = self.b.insert_element(L.Constant(vt, L.Undefined), value, self.c(self.i32, 0))
        return self.b.shuffle_vector(one, L.Constant(vt, L.Undefined),
                                     L.Constant(self.lanes(self.i32), [0] * self.width))

    def sqrt(self, value: Any) -> Any:
        suffix = "f64" if self.width == 1 else f"v{self.width}f64"
        fn = _intrinsic(self.b.module, f"llvm.sqrt.{suffix}", value.type, [value.type])
        return self.b.call(fn, [value])

    def at(self, base: Any, ty: Any, index: Any) -> Any:
        """Pointer to element ``index`` (an int or an i64 value) of an array of ``ty``."""
        idx = self.c(self.i64, index) if isinstance(index, int) else index
        return self.b.gep(base, [idx], source_etype=ty)

    def load(self, base: Any, ty: Any, index: Any) -> Any:
        return self.b.load(self.at(base, ty, index), typ=ty)

    def byte(self, base: Any, ty: Any, offset: int) -> Any:
        """The ``ty`` at byte ``offset`` of a struct."""
        return self.b.load(self.at(base, self.i8, offset), typ=ty)

    def vec(self, base: Any, first: int) -> list[Any]:
        """The 3 doubles of the geometry's block at ``first``, in every lane."""
        return [self.uniform(self.load(base, self.f64, first + k)) for k in range(3)]

    def dot(self, a: list[Any], c: list[Any]) -> Any:
        b = self.b
        return b.fadd(b.fadd(b.fmul(a[0], c[0]), b.fmul(a[1], c[1])), b.fmul(a[2], c[2]))


def _bounds_function(mod: Any) -> None:
    """RTCBoundsFunctionArguments: geometryUserPtr @0, primID @8, timeStep @12, bounds_o @16;
    RTCBounds: lower_x, lower_y, lower_z, pad, upper_x, upper_y, upper_z, pad (floats)."""
    fn = L.Function(mod, L.FunctionType(L.VoidType(), [L.PointerType()]), "rdsl_user_bounds")
    b = L.IRBuilder(fn.append_basic_block("entry"))
    x = _IR(b)
    args = fn.args[0]
    user, out = x.byte(args, x.ptr, 0), x.byte(args, x.ptr, 16)
    (lower, _), (upper, _) = USER_BLOCK["lower"], USER_BLOCK["upper"]
    corners = [lower + k for k in range(3)] + [upper + k for k in range(3)]
    for first, slot in zip(corners, (0, 1, 2, 4, 5, 6)):
        v = b.fptrunc(x.load(user, x.f64, first), x.f32)
        b.store(v, x.at(out, x.f32, slot))
    b.ret_void()


def _sphere_test(x: _IR, user: Any, o: list[Any], d: list[Any], tnear: Any, tfar: Any
                 ) -> tuple[Any, Any, list[Any], Any, Any]:
    """(hit, t, Ng, u, v) of the ray against the sphere, in double precision."""
    b = x.b
    c = x.vec(user, USER_BLOCK["center"][0])
    r = x.uniform(x.load(user, x.f64, USER_BLOCK["radius"][0]))
    l_ = [b.fsub(o[k], c[k]) for k in range(3)]
    dd = x.dot(d, d)
    # the point of the ray closest to the center, as the new origin (Mitsuba's robust form)
    tp = b.fdiv(b.fneg(x.dot(l_, d)), dd)
    q = [b.fadd(l_[k], b.fmul(d[k], tp)) for k in range(3)]
    bb = b.fmul(x.k(x.f64, 2.0), x.dot(q, d))
    cc = b.fsub(x.dot(q, q), b.fmul(r, r))
    disc = b.fsub(b.fmul(bb, bb), b.fmul(b.fmul(x.k(x.f64, 4.0), dd), cc))
    root = x.sqrt(disc)  # NaN when disc < 0: every comparison below fails
    inv2a = b.fdiv(x.k(x.f64, 0.5), dd)
    near = b.fadd(b.fmul(b.fsub(b.fneg(bb), root), inv2a), tp)
    far = b.fadd(b.fmul(b.fsub(root, bb), inv2a), tp)
    t = b.select(b.fcmp_ordered(">=", near, tnear), near, far)
    hit = b.and_(b.fcmp_ordered(">=", t, tnear), b.fcmp_ordered("<=", t, tfar))
    ng = [b.fsub(b.fadd(o[k], b.fmul(d[k], t)), c[k]) for k in range(3)]
    zero = x.k(x.f64, 0.0)
    return hit, t, ng, zero, zero


def _disk_test(x: _IR, user: Any, o: list[Any], d: list[Any], tnear: Any, tfar: Any
               ) -> tuple[Any, Any, list[Any], Any, Any]:
    """(hit, t, Ng, u, v) of the ray against the disk; u, v = the local x, y of the hit."""
    b = x.b
    first = USER_BLOCK["to_object"][0]
    rows = [[x.uniform(x.load(user, x.f64, first + 4 * i + j)) for j in range(4)]
            for i in range(3)]
    lo = [b.fadd(x.dot(rows[i][:3], o), rows[i][3]) for i in range(3)]
    ld = [x.dot(rows[i][:3], d) for i in range(3)]
    t = b.fdiv(b.fneg(lo[2]), ld[2])
    px = b.fadd(lo[0], b.fmul(ld[0], t))
    py = b.fadd(lo[1], b.fmul(ld[1], t))
    r2 = b.fadd(b.fmul(px, px), b.fmul(py, py))
    hit = b.and_(b.fcmp_ordered("<=", r2, x.k(x.f64, 1.0)),
                 b.and_(b.fcmp_ordered(">=", t, tnear), b.fcmp_ordered("<=", t, tfar)))
    return hit, t, x.vec(user, USER_BLOCK["normal"][0]), px, py


def _sdfgrid_test(x: _IR, user: Any, o: list[Any], d: list[Any], tnear: Any, tfar: Any
                  ) -> tuple[Any, Any, list[Any], Any, Any]:
    """(hit, t, Ng, u, v) of the ray against the SDF grid: a call of its rdsl kernel
    (stdlib/render/sdfgrid_kernel.rdsl, ``rdsl_sdfgrid_intersect``, compiled scalar) on one
    ray; u = the voxel's index, Ng = (0, 0, 1) (the renderer's kernels take the normal from
    the grid, not from Embree)."""
    b = x.b
    fn = b.function
    entry = L.IRBuilder(fn.entry_basic_block)
    entry.position_at_start(fn.entry_basic_block)
    slots = entry.alloca(x.f32, size=10)  # the kernel's 8 inputs and 2 outputs, one ray
    for k, value in enumerate(o + d + [tnear, tfar]):
        b.store(b.fptrunc(value, x.f32), x.at(slots, x.f32, k))
    record = b.inttoptr(x.load(user, x.i64, USER_BLOCK["record"][0]), x.ptr)
    args: list[Any] = [x.c(x.i64, 1), record]
    arg_tys: list[Any] = [x.i64, x.ptr]
    for k in range(10):  # each array and its byte stride
        args += [x.at(slots, x.f32, k), x.c(x.i64, 4)]
        arg_tys += [x.ptr, x.i64]
    args += [x.c(x.ptr, None), x.c(x.i64, 0)]  # no mask: the one lane is active
    arg_tys += [x.ptr, x.i64]
    kernel = b.inttoptr(x.load(user, x.i64, USER_BLOCK["kernel"][0]),
                        L.FunctionType(L.VoidType(), arg_tys).as_pointer())
    b.call(kernel, args)
    t = b.fpext(x.load(slots, x.f32, 8), x.f64)
    cell = b.fpext(x.load(slots, x.f32, 9), x.f64)
    hit = b.and_(b.and_(b.fcmp_ordered(">=", t, tnear), b.fcmp_ordered("<=", t, tfar)),
                 b.fcmp_ordered("<", t, x.c(x.f64, float("inf"))))  # infinity: a miss
    zero, one = x.c(x.f64, 0.0), x.c(x.f64, 1.0)
    return hit, t, [zero, zero, one], cell, zero


# packet sizes the callbacks handle as one SIMD vector (Embree calls them with its packet
# width, or 1 where its hybrid traversal went on with single rays)
PACKET_WIDTHS = (16, 8, 4)


def _lane_loop(fn: Any, count_offset: int, lane: Any, packet: Any = None) -> None:
    """The body of callback ``fn``: for each of the packet's N lanes (N the uint at byte
    ``count_offset`` of the arguments) whose ``valid`` entry (the int* at byte 0) is set,
    ``lane(x, args, i, n, nxt)`` emits the lane's code, which ends by branching to ``nxt``.
    With ``packet``, an N of :data:`PACKET_WIDTHS` runs ``packet(x, args)`` instead: all N
    lanes at once, ``x`` computing on vectors of N (it returns from ``fn``)."""
    entry, head, body, work, nxt, done = (
        fn.append_basic_block(s) for s in ("entry", "head", "body", "lane", "next", "done"))
    b = L.IRBuilder(entry)
    x = _IR(b)
    args = fn.args[0]
    valid = x.byte(args, x.ptr, 0)
    n = b.zext(x.byte(args, x.i32, count_offset), x.i64)
    if packet is None:
        b.branch(head)
    else:
        switch = b.switch(n, head)
        for width in PACKET_WIDTHS:
            block = fn.append_basic_block(f"packet{width}")
            switch.add_case(x.c(x.i64, width), block)
            packet(_IR(L.IRBuilder(block), width), args)

    b.position_at_end(head)
    i = b.phi(x.i64, name="i")
    i.add_incoming(x.c(x.i64, 0), entry)
    b.cbranch(b.icmp_unsigned("<", i, n), body, done)

    b.position_at_end(body)
    active = b.icmp_signed("!=", x.load(valid, x.i32, i), x.c(x.i32, 0))
    b.cbranch(active, work, nxt)

    b.position_at_end(work)
    lane(x, args, i, n, nxt)

    b.position_at_end(nxt)
    i.add_incoming(b.add(i, x.c(x.i64, 1)), nxt)
    b.branch(head)

    b.position_at_end(done)
    b.ret_void()


def _query_function(mod: Any, kind: str, query: str, test: Any) -> None:
    fn = L.Function(mod, L.FunctionType(L.VoidType(), [L.PointerType()]),
                    f"rdsl_user_{kind}_{query}")

    def lane(x: _IR, args: Any, i: Any, n: Any, nxt: Any) -> None:
        b = x.b
        found = fn.append_basic_block("found")
        user, prim = x.byte(args, x.ptr, 8), x.byte(args, x.i32, 16)
        context, rays = x.byte(args, x.ptr, 24), x.byte(args, x.ptr, 32)
        geom = x.byte(args, x.i32, 44)

        def slot(row: int, ty: Any) -> Any:  # lane i of row `row` (ray rows, then hit rows)
            return x.at(rays, ty, b.add(b.mul(x.c(x.i64, row), n), i))

        def ray(name: str) -> Any:
            return b.fpext(b.load(slot(RAY_FIELDS.index(name), x.f32), typ=x.f32), x.f64)

        o = [ray(f"org_{a}") for a in "xyz"]
        d = [ray(f"dir_{a}") for a in "xyz"]
        tnear, tfar = ray("tnear"), ray("tfar")
        hit, t, ng, u, v = test(x, user, o, d, tnear, tfar)
        b.cbranch(hit, found, nxt)

        b.position_at_end(found)
        tfar_slot = slot(RAY_FIELDS.index("tfar"), x.f32)
        if query == "occluded":
            b.store(x.c(x.f32, float("-inf")), tfar_slot)
        else:
            b.store(b.fptrunc(t, x.f32), tfar_slot)

            def put(name: str, value: Any, ty: Any) -> None:
                b.store(value, slot(len(RAY_FIELDS) + HIT_FIELDS.index(name), ty))

            for a, comp in zip("xyz", ng):
                put(f"Ng_{a}", b.fptrunc(comp, x.f32), x.f32)
            put("u", b.fptrunc(u, x.f32), x.f32)
            put("v", b.fptrunc(v, x.f32), x.f32)
            put("primID", prim, x.i32)
            put("geomID", geom, x.i32)
            put("instID", x.load(context, x.i32, 0), x.i32)  # context->instID[0]
            put("instPrimID", x.c(x.i32, -1), x.i32)
        b.branch(nxt)

    # the SDF grid's test calls its (scalar) kernel once per ray: lane by lane
    _lane_loop(fn, 40, lane, None if kind == "sdfgrid" else
               lambda x, args: _packet_query(x, args, query, test))


def _packet_query(x: _IR, args: Any, query: str, test: Any) -> None:
    """The ``query`` (intersect or occluded) of all lanes of a packet at once: ``x``
    computes on vectors of the packet's width, the rays' rows are vectors (the packet's
    lanes are consecutive), and the lanes that hit store their results (masked)."""
    b = x.b
    user, prim = x.byte(args, x.ptr, 8), x.byte(args, x.i32, 16)
    context, rays = x.byte(args, x.ptr, 24), x.byte(args, x.ptr, 32)
    geom = x.byte(args, x.i32, 44)
    active = b.icmp_signed("!=", b.load(x.byte(args, x.ptr, 0), typ=x.lanes(x.i32),
                                        align=4), x.k(x.i32, 0))

    def ray(name: str) -> Any:  # row `name`: the packet's lanes are consecutive
        row = x.at(rays, x.f32, RAY_FIELDS.index(name) * x.width)
        return b.fpext(b.load(row, typ=x.lanes(x.f32), align=4), x.lanes(x.f64))

    o = [ray(f"org_{a}") for a in "xyz"]
    d = [ray(f"dir_{a}") for a in "xyz"]
    hit, t, ng, u, v = test(x, user, o, d, ray("tnear"), ray("tfar"))
    found = b.and_(active, hit)

    def put(row: int, value: Any) -> None:  # the lanes that found a hit
        ty = value.type.element
        b.call(_masked_store(b.module, value.type),
               [value, x.at(rays, ty, row * x.width), x.c(x.i32, 4), found])

    tfar = RAY_FIELDS.index("tfar")
    if query == "occluded":
        put(tfar, x.k(x.f32, float("-inf")))
    else:
        put(tfar, b.fptrunc(t, x.lanes(x.f32)))
        hits = len(RAY_FIELDS)
        for a, comp in zip("xyz", ng):
            put(hits + HIT_FIELDS.index(f"Ng_{a}"), b.fptrunc(comp, x.lanes(x.f32)))
        put(hits + HIT_FIELDS.index("u"), b.fptrunc(u, x.lanes(x.f32)))
        put(hits + HIT_FIELDS.index("v"), b.fptrunc(v, x.lanes(x.f32)))
        put(hits + HIT_FIELDS.index("primID"), x.uniform(prim))
        put(hits + HIT_FIELDS.index("geomID"), x.uniform(geom))
        put(hits + HIT_FIELDS.index("instID"), x.uniform(x.load(context, x.i32, 0)))
        put(hits + HIT_FIELDS.index("instPrimID"), x.k(x.i32, -1))
    b.ret_void()


def _masked_store(mod: Any, vt: Any) -> Any:
    """``llvm.masked.store`` of the vector type ``vt`` (of floats or i32s)."""
    elem = "f32" if isinstance(vt.element, L.FloatType) else "i32"
    return _intrinsic(mod, f"llvm.masked.store.v{vt.count}{elem}.p0", L.VoidType(),
                      [vt, L.PointerType(), L.IntType(32), L.VectorType(L.IntType(1), vt.count)])


def _intrinsic(mod: Any, name: str, ret: Any, args: list[Any]) -> Any:
    """The LLVM intrinsic ``name`` of ``mod``, declared on first use."""
    return mod.globals.get(name) or L.Function(mod, L.FunctionType(ret, args), name)


__all__ = ["build_module", "callback_addresses"]
