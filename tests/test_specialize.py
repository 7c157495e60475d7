"""`specialize`: the scene placeholders become a dispatch over the scene's plugin types,
with instance parameters as constants; results equal the plugins' own kernels."""

from __future__ import annotations

import numpy as np
import pytest

import rdsl
from rdsl.compiler.build import Build
from rdsl.compiler.driver import frontend, run_passes
from rdsl.compiler.ir import Op
from rdsl.compiler.passes.inline import Inline
from rdsl.compiler.passes.specialize import Specialize
from rdsl.compiler.sources import STDLIB
from rdsl.core.scene_spec import Instance, SceneSpec

SRC = """
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


def surface(n: int, rng) -> dict:
    wi = rng.standard_normal((n, 3)).astype(np.float32)
    wi[:, 2] = np.abs(wi[:, 2])
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    z = np.zeros((n, 3), np.float32)
    return {"p": z, "n": z, "sh_n": z, "uv": np.zeros((n, 2), np.float32), "wi": wi,
            "t": np.ones(n, np.float32), "valid": np.ones(n, bool)}


def test_one_call_per_plugin_type():
    m = frontend(SRC)
    run_passes(m, [Specialize(SCENE)])
    calls = [i.attrs["callee"] for i in m.functions["scene_bsdf_eval"].walk()
             if i.op is Op.CALL]
    assert sorted(calls) == ["diffuse.eval", "roughconductor.eval"]
    run_passes(m, [Inline()])
    assert set(m.functions) == {"shade"}  # unused plugins and placeholders are gone


@pytest.mark.parametrize("target", ["scalar", "host"])
def test_dispatch_matches_the_plugins_own_kernels(target):
    mod = rdsl.jit(SRC, target=target, scene=SCENE)
    own_d = rdsl.jit(STDLIB / "bsdf" / "diffuse.rdsl", target=target)
    own_r = rdsl.jit(STDLIB / "bsdf" / "roughconductor.rdsl", target=target)
    rng = np.random.default_rng(5)
    n = 300
    si = surface(n, rng)
    wo = surface(n, rng)["wi"]
    ids = rng.integers(0, 3, n).astype(np.int32)
    got = mod.shade(ids, si, wo, np.zeros(3, np.float32))
    want = np.where(
        (ids == 0)[:, None], own_d["diffuse.eval"](si, wo, reflectance=(0.8, 0.1, 0.1)),
        np.where((ids == 1)[:, None], own_r["roughconductor.eval"](si, wo, alpha=0.3),
                 own_d["diffuse.eval"](si, wo, reflectance=(0.1, 0.7, 0.2))))
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-7)
    assert np.any(got > 0)


def test_emitter_sampling_disappears_when_every_bsdf_is_delta(tmp_path):
    """With only smooth conductors and dielectrics, a BSDF evaluates to 0 for any sampled
    light direction: the specialized kernel has no shadow ray (one strategy, no MIS)."""
    from pathlib import Path

    from rdsl.compiler import driver

    cbox = Path(__file__).resolve().parents[2] / "shared" / "scenes" / "cbox" / "cbox.xml"
    if not cbox.is_file():
        pytest.skip(f"{cbox} is not present")
    pytest.importorskip("rdsl.runtime.embree")
    src = cbox.read_text()
    for name in ("white", "green", "red"):
        start = src.index(f'<bsdf type="diffuse" id="{name}">')
        end = src.index("</bsdf>", start) + len("</bsdf>")
        plugin = "dielectric" if name == "green" else "conductor"
        src = src[:start] + f'<bsdf type="{plugin}" id="{name}"/>' + src[end:]
    (tmp_path / "delta.xml").write_text(src)

    def shadow_rays(path: Path) -> int:
        s = rdsl.load_scene(path, variant="rgb", target="scalar")
        s.compile()
        mod, _ = driver.compile_kernels(s.kernel_src, Build.of("scalar", "rgb"),
                                        scene=s.scene_spec)
        return sum(i.op is Op.OCCLUDED for i in mod.functions["render_sample"].walk())

    assert shadow_rays(cbox) == 1
    assert shadow_rays(tmp_path / "delta.xml") == 0


def test_an_if_giving_the_same_value_on_both_sides_folds():
    src = """
    fn k(x: Float, c: Bool) -> Float {
        var y = 0.0;
        var z = x;
        if c { y = 0.0; z = x; } else { y = 0.0 * 1.0; }
        return y + z;
    }
    """
    m = frontend(src)
    from rdsl.compiler.passes.optimize import Optimize

    run_passes(m, [Inline(), Optimize()])
    assert not any(i.op is Op.IF for i in m.functions["k"].walk())
    got = rdsl.jit(src, target="scalar").k(np.float32([1.5, -2.0]), np.array([True, False]))
    np.testing.assert_array_equal(got, [1.5, -2.0])


PLUGIN_CALL = """
integrator gain {
    param scale: Float = 2.0;
    param offset: Spectrum = Spectrum(0.0, 0.5, 1.0);
    fn apply(x: Float) -> Spectrum { return Spectrum(x * scale) + offset; }
    fn sample(scene: Scene, ray: Ray, sampler: Sampler) -> Spectrum { return offset; }
}
fn k(x: Float) -> Spectrum { return gain.apply(x); }
"""


@pytest.mark.parametrize("specialize", [True, False])
def test_a_plugin_called_by_name_gets_the_scene_instance_params(specialize):
    """`gain.apply(x)` from a top-level function: the plugin's defaults without a scene,
    the scene's instance's values with one (folded, or read from PRM in the generic build)."""
    src = "import render.integrator;\n" + PLUGIN_CALL
    x = np.float32([1.0, -2.0])
    plain = rdsl.jit(src, target="scalar").k(x)
    np.testing.assert_allclose(plain, [[2.0, 2.5, 3.0], [-4.0, -3.5, -3.0]])
    scene = SceneSpec(integrators=[Instance("gain", {"scale": 3.0})])
    if specialize:
        got = rdsl.jit(src, target="scalar", scene=scene).k(x)
    else:
        from rdsl.compiler.passes.specialize import parameter_slots

        generic, prm = parameter_slots(scene)
        assert list(prm) == [3.0]
        got = rdsl.jit(src, target="scalar", scene=generic).k(x, prm)
    np.testing.assert_allclose(got, [[3.0, 3.5, 4.0], [-6.0, -5.5, -5.0]])
