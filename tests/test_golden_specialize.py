"""Golden IR of ``specialize`` for a small scene: two diffuse instances and one
roughconductor.

``golden/specialize/scene.expected`` holds what the pass reports and the IR of the program
and of the placeholder it rewrote: a dispatch over the two plugin *types*, the diffuse
reflectances selected by instance id, every parameter a constant.
``scene.generic.expected`` is the generic build (``fold=False``, ``rdsl render
--no-specialize``): the same dispatch reading the parameters from ``PRM``.  Update with
``RDSL_UPDATE_GOLDEN=1`` (see ``tests/_golden.py``).
"""

from __future__ import annotations

import pytest
from _golden import GOLDEN, check_golden
from rdsl.compiler.driver import frontend, run_passes
from rdsl.compiler.passes.specialize import Specialize
from rdsl.compiler.printer import print_function
from rdsl.core.scene_spec import Instance, SceneSpec

SRC = """\
import render.scene;
import bsdf.diffuse;
import bsdf.roughconductor;
fn shade(id: Int, si: Surface, wo: Vec3, T: [Float]) -> Spectrum {
    return scene_bsdf_eval(id, si, wo, T);
}
"""
SCENE = SceneSpec(bsdfs=[
    Instance("diffuse", {"reflectance": (0.8, 0.1, 0.1)}),
    Instance("roughconductor", {"alpha": 0.3}),
    Instance("diffuse", {"reflectance": (0.1, 0.7, 0.2)}),
])
SHOWN = ["shade", "scene_bsdf_eval"]


@pytest.mark.parametrize("fold,stem", [(True, "scene"), (False, "scene.generic")])
def test_specialize_golden(fold: bool, stem: str) -> None:
    module = frontend(SRC, filename="scene.rdsl")
    report: list[str] = []
    run_passes(module, [Specialize(SCENE, report, fold=fold)])
    got = "// ----- specialize report -----\n" + "".join(f"// {line}\n" for line in report)
    got += "// ----- after specialize -----\n"
    got += "".join(print_function(module.functions[n], locs=False) + "\n" for n in SHOWN)
    check_golden(got, GOLDEN / "specialize" / f"{stem}.expected")
