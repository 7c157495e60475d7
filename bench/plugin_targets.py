"""Plugin kernels on every CPU target: the LLVM targets this CPU runs (avx2, avx512), SIMD C
(``cc -O2 -march=native`` at the host's widest width) and OpenCL C on PoCL (``--target
opencl``, the host's widest width and width 1, which PoCL leaves scalar).  Each kernel maps
over N random inputs through the same Python call (numpy in, one reused ``out``), on every
core; the builds are timed in turn, round after round, and the table shows medians and the
ratio of each build's throughput to the first LLVM target's.  For OpenCL it also shows the
kernel alone (the device's own timing of the launch, without the copies to and from the
device).  Outputs are compared with the LLVM build's, bit for bit.  Not a test: run it by
hand.

    python bench/plugin_targets.py [--n 1048576] [--repeat 5]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path
from typing import Any

import numpy as np
import rdsl
from rdsl.compiler.targets import get_target, host_supports

ROOT = Path(rdsl.__file__).resolve().parent
KERNELS = [  # (source, kernel, uniform parameters)
    (ROOT / "bench" / "ggx_kernel.rdsl", "ggx_eval_sample", {}),
    (ROOT / "stdlib" / "bsdf" / "roughconductor.rdsl", "roughconductor.eval", {}),
    (ROOT / "stdlib" / "bsdf" / "roughconductor.rdsl", "roughconductor.sample", {}),
    (ROOT / "stdlib" / "bsdf" / "principled.rdsl", "principled.eval", {}),
    (ROOT / "stdlib" / "bsdf" / "dielectric.rdsl", "dielectric.sample", {}),
]


def random_value(tj: dict[str, Any], name: str, n: int, rng: np.random.Generator) -> Any:
    """Random arrays for a parameter of type JSON ``tj``: unit vectors with z > 0 for
    3-vectors (directions in the local frame), [0, 1) for samples and other floats."""
    kind = tj["kind"]
    if kind == "struct":
        return {f: random_value(ft, f, n, rng) for f, ft in tj["fields"]}
    if kind == "tuple":
        return tuple(random_value(e, name, n, rng) for e in tj["elems"])
    if kind == "vec" and tj["n"] == 3:
        v = rng.standard_normal((n, 3)).astype(np.float32)
        v[:, 2] = np.abs(v[:, 2]) + 0.05
        return v / np.linalg.norm(v, axis=1, keepdims=True)
    shape = (n, tj["n"]) if kind == "vec" else (n,)
    dt = tj["dtype"]
    if dt == "bool":
        return np.ones(shape, bool)
    if dt == "f32":
        return rng.random(shape, dtype=np.float32)
    return np.zeros(shape, {"i32": np.int32, "u32": np.uint32, "u64": np.uint64}[dt])


def builds() -> list[tuple[str, str, int | None]]:
    """(label, target, width) of every build this machine runs, the reference first."""
    llvm = [t for t in ("avx512", "avx2") if host_supports(get_target(t))] or ["scalar"]
    w = get_target(llvm[0]).width
    out = [(t, t, None) for t in llvm] + [(f"c{w}", "c", w), (f"opencl{w}", "opencl", w)]
    return out + [("opencl1", "opencl", 1)]


def flat_leaves(v: Any) -> list[np.ndarray]:
    if isinstance(v, dict):
        return [x for f in v.values() for x in flat_leaves(f)]
    if isinstance(v, tuple):
        return [x for e in v for x in flat_leaves(e)]
    return [np.asarray(v)]


def same(a: Any, b: Any) -> bool:
    return all(np.array_equal(x, y, equal_nan=True) for x, y in
               zip(flat_leaves(a), flat_leaves(b)))


# long: one table; compile, warm up, time the rounds, print
def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1 << 20)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    rng = np.random.default_rng(7)
    table = builds()
    device = ""
    print(f"{'kernel':24} {'build':10} {'Msamp/s':>8} {'ratio':>6} {'kernel only':>12} "
          f"{'bitwise':>8}")
    for src, name, uniforms in KERNELS:
        ks = {label: rdsl.jit(src, target=t, width=w)[name] for label, t, w in table}
        ref = ks[table[0][0]]
        inputs = [random_value(p["type"], p["name"], args.n, rng) for p in ref._positional]
        outs = {label: k(*inputs, **uniforms) for label, k in ks.items()}
        times: dict[str, list[float]] = {label: [] for label in ks}
        dev: dict[str, list[float]] = {label: [] for label in ks}
        for _ in range(args.repeat):  # interleaved: machine noise hits every build alike
            for label, k in ks.items():
                t = time.perf_counter()
                k(*inputs, out=outs[label], **uniforms)
                times[label].append(time.perf_counter() - t)
                dev[label].append(getattr(k, "last_device_seconds", 0.0))
        med = {label: statistics.median(v) for label, v in times.items()}
        first = table[0][0]
        for label, k in ks.items():
            rate = args.n / med[label] / 1e6
            ratio = med[first] / med[label]
            only = ""
            if label.startswith("opencl"):
                d = statistics.median(dev[label])
                only = f"{args.n / d / 1e6:7.1f} ({med[first] / d:4.2f}x)"
                device = k.module.device
            print(f"{name:24} {label:10} {rate:8.1f} {ratio:5.2f}x {only:>12} "
                  f"{'yes' if same(outs[label], outs[first]) else 'NO':>8}")
    print(f"\nN = {args.n}, median of {args.repeat} interleaved calls, every core; ratio: "
          f"throughput over {table[0][0]}'s (above 1 = faster).  'kernel only': the OpenCL "
          f"launch alone, without the copies to and from the device ({device}).")


if __name__ == "__main__":
    main()
