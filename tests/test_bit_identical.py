"""Images stay bit-identical across refactorings: a few renders (every colour variant of the
Cornell box, the generic build, a scene with analytic spheres and a rough conductor) are
hashed and compared with the hashes the build before the architecture change produced.

A change that alters an image on purpose regenerates the table with
``python tests/test_bit_identical.py --update`` and says why in its commit.

The test renders with the host's widest target, and the table keeps one set of hashes per
target, each recorded on a host whose widest target it is: the same kernel gives other
bits on another kind of host, since Embree (its BVH and intersectors) and numpy (the scene's
transforms) choose their code by the CPU they run on, not by rdsl's target. ``--update``
writes the entries of this host's own target and keeps the others, so the table is
regenerated on an AVX-512 host and on an AVX2-only one.
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

import numpy as np
import pytest
from _scenes import CBOX

ROOT = Path(__file__).resolve().parents[1]
MATERIALS = ROOT / "bench" / "scenes" / "materials.xml"
TABLE = Path(__file__).with_name("golden") / "images" / "hashes.json"
TARGETS = ("avx512", "avx2")

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


if __name__ == "__main__" and "--update" in sys.argv:
    host = _host_target()
    if host is None:
        sys.exit(f"this machine runs none of {TARGETS}")
    table = json.loads(TABLE.read_text()) if TABLE.is_file() else {}
    for name, path, variant, specialize in CASES:
        k = key(name, variant, specialize, host)
        table[k] = render_hash(path, variant, specialize, host)
        print(k, table[k])
    TABLE.write_text(json.dumps(table, indent=1, sort_keys=True) + "\n")
