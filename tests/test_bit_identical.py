"""Images stay bit-identical across refactorings: a few renders (every colour variant of the
Cornell box, the generic build, a scene with analytic spheres and a rough conductor) are
hashed and compared with the hashes the build before the architecture change produced.

A change that alters an image on purpose regenerates the table with
``python tests/test_bit_identical.py --update`` and says why in its commit.

The test renders with the host's widest target, and the table keeps one set of hashes per
target, each recorded on a host whose widest target it is: the same kernel gives other
bits on another kind of host, since Embree (its BVH and intersectors) and numpy (the scene's
transforms) choose their code by the CPU they run on, not by rdsl's target. ``--update``
writes the entries of this host's own target and keeps the others.  An AVX-512 host can
also stand in for an AVX2-only one: with Embree's AVX2 kernels (``RDSL_EMBREE_CONFIG=isa=avx2``)
and numpy's AVX2 code (``NPY_DISABLE_CPU_FEATURES``), the ``avx2`` target's renders give the
bits an AVX2-only host recorded (checked below for two cases; all eight matched when this
was written), so ``--update --as avx2`` regenerates those entries there too.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from _scenes import CBOX

ROOT = Path(__file__).resolve().parents[1]
MATERIALS = ROOT / "bench" / "scenes" / "materials.xml"
TABLE = Path(__file__).with_name("golden") / "images" / "hashes.json"
TARGETS = ("avx512", "avx2")
# the environment that makes an AVX-512 host render as an AVX2-only one (set before numpy
# and Embree load: a fresh process)
STAND_IN = {"avx2": {"RDSL_EMBREE_CONFIG": "isa=avx2",
                     "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR"}}

# (name, scene, variant, specialize)
CASES = [
    *(("cbox", CBOX, v, True)
      for v in ("mono", "rgb", "spectral", "mono_polarized", "spectral_polarized")),
    ("cbox", CBOX, "rgb", False),
    ("materials", MATERIALS, "rgb", True),
    ("materials", MATERIALS, "spectral_polarized", True),
]


def key(name: str, variant: str, specialize: bool, target: str) -> str:
    return f"{name}/{variant}/{'specialized' if specialize else 'generic'}/{target}"


def render_hash(scene_path: Path, variant: str, specialize: bool, target: str) -> str:
    import rdsl

    scene = rdsl.load_scene(scene_path, variant=variant, target=target,
                            specialize=specialize, res=48, spp=4)
    img = np.ascontiguousarray(scene.render(spp=4, seed=3, threads=2), np.float32)
    return hashlib.sha256(img.tobytes()).hexdigest()


def _host_target() -> str | None:
    from rdsl.compiler.targets import host_supports

    return next((t for t in TARGETS if host_supports(t)), None)


@pytest.mark.parametrize("name,scene_path,variant,specialize", CASES,
                         ids=[key(c[0], c[2], c[3], "") .rstrip("/") for c in CASES])
def test_image_is_bit_identical(name, scene_path, variant, specialize):
    pytest.importorskip("rdsl.runtime.embree")
    if not scene_path.is_file():
        pytest.skip(f"{scene_path} is not present")
    target = _host_target()
    if target is None:
        pytest.skip(f"this machine runs none of {TARGETS}, the targets the hashes cover")
    expected = json.loads(TABLE.read_text())[key(name, variant, specialize, target)]
    assert render_hash(scene_path, variant, specialize, target) == expected


def _stand_in_hashes(target: str, keys: list[str]) -> dict[str, str]:
    """The hashes of ``keys`` rendered in a fresh process made to run as a ``target`` host."""
    env = dict(os.environ, **STAND_IN[target])
    out = subprocess.run([sys.executable, __file__, "--hash", *keys], env=env, check=True,
                         capture_output=True, text=True, cwd=Path(__file__).parent).stdout
    return dict(line.split() for line in out.splitlines() if line.strip())


def test_an_avx512_host_reproduces_the_avx2_hosts_images():
    """The avx2 entries, recorded on an AVX2-only host, checked on an AVX-512 one: the same
    kernels with Embree's and numpy's AVX2 code give the same bits (so an AVX-512 host
    checks, and can regenerate, both targets' entries)."""
    pytest.importorskip("rdsl.runtime.embree")
    if _host_target() != "avx512":
        pytest.skip("needs an AVX-512 host, which stands in for an AVX2-only one")
    keys = [key("cbox", "rgb", True, "avx2"), key("materials", "rgb", True, "avx2")]
    table = json.loads(TABLE.read_text())
    assert _stand_in_hashes("avx2", keys) == {k: table[k] for k in keys}


def _cases_by_key() -> dict[str, tuple]:
    return {key(n, v, sp, t): (p, v, sp, t) for n, p, v, sp in CASES for t in TARGETS}


if __name__ == "__main__" and "--hash" in sys.argv:  # KEY ...: print "KEY HASH" lines
    cases = _cases_by_key()
    for k in sys.argv[sys.argv.index("--hash") + 1:]:
        print(k, render_hash(*cases[k]), flush=True)

if __name__ == "__main__" and "--update" in sys.argv:
    host = _host_target()
    if "--as" in sys.argv:  # --as avx2 on an AVX-512 host
        want = sys.argv[sys.argv.index("--as") + 1]
        if want not in STAND_IN or host != "avx512":
            sys.exit(f"--as takes one of {sorted(STAND_IN)}, on an AVX-512 host")
        keys = [k for k in _cases_by_key() if k.endswith("/" + want)]
        fresh = _stand_in_hashes(want, keys)
    elif host is None:
        sys.exit(f"this machine runs none of {TARGETS}")
    else:
        fresh = {k: render_hash(*c) for k, c in _cases_by_key().items() if c[3] == host}
    table = json.loads(TABLE.read_text()) if TABLE.is_file() else {}
    for k, h in fresh.items():
        table[k] = h
        print(k, h)
    TABLE.write_text(json.dumps(table, indent=1, sort_keys=True) + "\n")
