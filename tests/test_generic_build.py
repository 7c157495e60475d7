"""The generic build (``--no-specialize``): instance parameters read at run time from ``PRM``,
every emitter kind compiled.  It renders the same image as the specialized build, one
generic kernel serves scenes that differ only in parameter values, and ``--report`` compares
the two kernels' sizes."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rdsl.runtime.embree")

from _scenes import CBOX, edited_copy
from rdsl.cli import main
from rdsl.runtime.render.renderer import load_scene
from test_scene_bsdfs import BSDFS, OBLIQUE, scene_xml

needs_cbox = pytest.mark.skipif(not CBOX.is_file(), reason=f"needs {CBOX}")


def same_image(path: Path, spp: int = 4, seed: int = 3, **defaults) -> str:
    """Render ``path`` specialized and generic; assert the images agree, say how."""
    a = load_scene(path, **defaults)
    b = load_scene(path, specialize=False, **defaults)
    ia, ib = a.render(spp=spp, seed=seed), b.render(spp=spp, seed=seed)
    assert b.prm.size > 0  # the generic kernel did read its parameters at run time
    assert ia.shape == ib.shape and a.nonfinite == b.nonfinite
    if np.array_equal(ia, ib):
        return "bit for bit"
    diff = float(np.abs(ia - ib).max())
    assert diff < 1e-5, diff
    return f"max abs diff {diff:.2g}"


@needs_cbox
def test_cbox_generic_equals_specialized():
    how = same_image(CBOX, res=64)
    print(f"cbox: {how}")


def test_bsdfs_textures_and_emitter_kinds(tmp_path):
    """Every BSDF type, nested combinators, a checkerboard and a bitmap texture, an area, a
    point and a constant emitter."""
    from PIL import Image

    rng = np.random.default_rng(9)
    Image.fromarray(rng.integers(40, 255, (3, 4, 3)).astype(np.uint8), "RGB").save(
        tmp_path / "tex.png")
    spheres = "".join(
        f'<shape type="sphere"><point name="center" value="{2.2 * (i % 5) - 4.4}, '
        f'{2.2 * (i // 5) - 2.2}, 1"/><float name="radius" value="0.9"/>{b}</shape>'
        for i, b in enumerate(BSDFS))
    body = ('<shape type="rectangle"><transform name="to_world"><scale value="4"/>'
            '<translate z="8"/></transform><boolean name="flip_normals" value="true"/>'
            '<emitter type="area"><rgb name="radiance" value="3, 2, 1"/></emitter></shape>'
            '<shape type="rectangle"><transform name="to_world"><scale value="12"/>'
            '</transform><bsdf type="diffuse"><texture type="checkerboard" '
            'name="reflectance"><rgb name="color0" value="0.8, 0.5, 0.2"/>'
            '<transform name="to_uv"><scale x="6" y="6"/></transform></texture></bsdf>'
            '</shape>'
            '<shape type="sphere"><point name="center" value="4.4, 4.4, 1"/>'
            '<float name="radius" value="0.9"/><bsdf type="roughplastic">'
            '<texture type="bitmap" name="diffuse_reflectance">'
            '<string name="filename" value="tex.png"/></texture></bsdf></shape>'
            '<emitter type="point"><point name="position" value="0, 0, 5"/>'
            '<rgb name="intensity" value="10, 10, 10"/></emitter>'
            '<emitter type="constant"><rgb name="radiance" value="0.2, 0.3, 0.4"/></emitter>'
            + spheres)
    path = tmp_path / "all.xml"
    path.write_text(scene_xml(body, OBLIQUE, res=32))
    how = same_image(path, spp=4)
    print(f"bsdfs + textures: {how}")


COLORED = """<scene version="3.0.0">
    <default name="color" value="0.5, 0.5, 0.5"/>
    <sensor type="perspective"><float name="fov" value="40"/>
        <transform name="to_world"><lookat origin="0, -6, 3" target="0, 0, 0" up="0, 0, 1"/>
        </transform>
        <film type="hdrfilm"><integer name="width" value="16"/>
            <integer name="height" value="16"/></film>
    </sensor>
    <shape type="rectangle"><transform name="to_world"><scale value="3"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="$color"/></bsdf></shape>
    <shape type="rectangle"><transform name="to_world"><translate z="4"/></transform>
        <boolean name="flip_normals" value="true"/>
        <emitter type="area"><rgb name="radiance" value="5, 5, 5"/></emitter></shape>
</scene>"""


def test_generic_kernel_is_shared_across_parameter_values(tmp_path, monkeypatch):
    monkeypatch.setenv("RDSL_CACHE_DIR", str(tmp_path / "cache"))
    path = tmp_path / "colored.xml"
    path.write_text(COLORED)
    colors = ["0.8, 0.1, 0.1", "0.1, 0.2, 0.7"]  # as `-D color=...`
    generic = [load_scene(path, specialize=False, color=c) for c in colors]
    images = [s.render(spp=2, seed=1) for s in generic]
    assert [s.from_cache for s in generic] == [False, True]  # one compile serves both
    specialized = [load_scene(path, color=c) for c in colors]
    for s, img in zip(specialized, images):
        np.testing.assert_allclose(s.render(spp=2, seed=1), img, rtol=0, atol=1e-5)
    assert [s.from_cache for s in specialized] == [False, False]  # values are constants
    assert not np.allclose(images[0], images[1])  # the parameter did reach the kernel


@needs_cbox
def test_report_compares_instruction_counts(tmp_path, capsys):
    out = tmp_path / "cbox.exr"
    assert main(["render", str(CBOX), "-D", "res=16", "--spp", "1", "-o", str(out),
                 "--report", "--quiet"]) == 0
    text = capsys.readouterr().out
    m = re.search(r"render_sample: (\d+) instructions specialized, (\d+) generic", text)
    assert m, text
    spec, generic = int(m[1]), int(m[2])
    assert spec < generic, text
    # 3 diffuse colours, the light's radiance and the path integrator's 3 params
    assert "parameters: 15 values of 5 instance(s) folded as constants" in text
    assert ("sampling code for point, spot, directional, constant, envmap, projector "
            "folded away") in text
    print(m[0])


@needs_cbox
def test_an_integer_beyond_float_precision_renders_specialized_only(tmp_path, capsys):
    """max_depth 2**25: a valid integer the specialized build folds; the generic build's
    float parameter buffer (also the differentiated kernels') cannot hold it exactly, an
    error at the integrator's line, not a traceback or a silently rounded depth."""
    from rdsl.compiler.diagnostics import CompileError

    path = edited_copy(CBOX, tmp_path, 'name="max_depth" value="$max_depth"',
                       'name="max_depth" value="33554432"')
    line = next(i for i, t in enumerate(path.read_text().splitlines(), 1)
                if '<integrator type="path">' in t)
    assert main(["render", str(path), "-D", "res=8", "--spp", "1", "-o",
                 str(tmp_path / "out.exr"), "--report", "--quiet"]) == 0
    assert "no generic build (an integer parameter of 2**24 or more)" in capsys.readouterr().out
    for what in ("render", "params"):
        scene = load_scene(path, res=8, specialize=what == "params")
        with pytest.raises(CompileError) as e:
            scene.render(spp=1) if what == "render" else scene.params
        assert f"cbox.xml:{line}:" in str(e.value) and "33554432 is too large" in str(e.value)


def test_fold_false_reads_parameters_from_prm():
    """``Specialize(scene, fold=False)``: same dispatch, parameters loaded from ``PRM``
    (threaded to the caller as its last argument); same results as the folded build."""
    import rdsl
    from rdsl.compiler.driver import frontend, run_passes
    from rdsl.compiler.ir import Op
    from rdsl.compiler.passes.specialize import Specialize, parameter_slots
    from test_specialize import SCENE, SRC, surface

    m = frontend(SRC)
    run_passes(m, [Specialize(SCENE, fold=False)])
    assert m.functions["shade"].params[-1].value.name == "PRM"
    loads = [i for i in m.functions["scene_bsdf_eval"].walk() if i.op is Op.LOAD]
    assert len(loads) == 7  # two rgb reflectances and one alpha
    generic, prm = parameter_slots(SCENE)
    np.testing.assert_array_equal(prm, np.float32([0.8, 0.1, 0.1, 0.3, 0.1, 0.7, 0.2]))
    a = rdsl.jit(SRC, target="host", scene=SCENE)
    b = rdsl.jit(SRC, target="host", scene=generic)
    rng = np.random.default_rng(5)
    si, wo = surface(200, rng), surface(200, rng)["wi"]
    ids = rng.integers(0, 3, 200).astype(np.int32)
    t = np.zeros(3, np.float32)
    np.testing.assert_array_equal(a.shade(ids, si, wo, t), b.shade(ids, si, wo, t, prm))


METALS = """<scene version="3.0.0">
    <default name="metal" value="Au"/>
    <default name="eta" value="400:1.5, 500:0.9, 650:0.3"/>
    <integrator type="path"><integer name="max_depth" value="4"/></integrator>
    <sensor type="perspective"><float name="fov" value="50"/>
        <transform name="to_world"><lookat origin="0, -7, 4" target="0, 0, 0.8" up="0, 0, 1"/>
        </transform>
        <film type="hdrfilm"><integer name="width" value="16"/>
            <integer name="height" value="16"/></film>
    </sensor>
    <shape type="sphere"><point name="center" value="-1.1, 0, 1"/>
        <bsdf type="conductor"><string name="material" value="$metal"/></bsdf></shape>
    <shape type="sphere"><point name="center" value="1.1, 0, 1"/>
        <bsdf type="roughconductor"><float name="alpha" value="0.3"/>
            <spectrum name="eta" value="$eta"/>
            <spectrum name="k" value="380:3.0, 612.5:3.3, 830:4.0"/></bsdf></shape>
    <shape type="rectangle"><transform name="to_world"><scale value="5"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.4, 0.3"/></bsdf></shape>
    <emitter type="constant"><rgb name="radiance" value="0.8, 0.9, 1.0"/></emitter>
</scene>"""


def test_spectral_tabulated_spectra_are_read_from_prm(tmp_path, monkeypatch):
    """Spectral generic build: tabulated spectra (a named conductor's eta and k, `<spectrum>`
    pairs) are read from PRM, in a layout that does not depend on their knots, so scenes
    differing in the metal and in the knots share one kernel; and it renders what the
    specialized build does (both evaluate the knots' interpolant exactly)."""
    from rdsl.compiler.driver import compile_kernels
    from rdsl.compiler.ir import Op
    from rdsl.compiler.passes.specialize import parameter_slots
    from rdsl.core import spectral

    monkeypatch.setenv("RDSL_CACHE_DIR", str(tmp_path / "cache"))
    path = tmp_path / "metals.xml"
    path.write_text(METALS)
    values = [{"metal": "Au", "eta": "400:1.5, 500:0.9, 650:0.3"},
              {"metal": "Cu", "eta": "380:0.4, 452.25:1.9, 500:1.1, 563.7:0.7, 800:0.2"}]
    generic = [load_scene(path, variant="spectral", specialize=False, **v) for v in values]
    images = [s.render(spp=2, seed=1) for s in generic]
    assert [s.from_cache for s in generic] == [False, True]  # one compile serves both
    # four tabulated spectra in PRM, none among the code's constant tables (only the CIE
    # and D65 curves, 95 samples each), read at varying offsets
    assert generic[0].prm.size >= 4 * spectral.GENERIC_SLOT
    build = generic[0].build
    module, _ = compile_kernels(generic[0].kernel_src, build,
                                scene=parameter_slots(generic[0].scene_spec, build.model)[0])
    instrs = [i for fn in module.functions.values() for i in fn.walk()]
    assert {len(i.attrs["values"]) for i in instrs if i.op is Op.TABLE} == {spectral.CIE_SAMPLES}
    assert any(i.op is Op.GATHER and i.operands[0].name == "PRM" for i in instrs)
    specialized = [load_scene(path, variant="spectral", **v) for v in values]
    for s, img in zip(specialized, images):
        np.testing.assert_allclose(s.render(spp=2, seed=1), img, rtol=1e-5, atol=1e-6)
    assert not np.allclose(images[0], images[1], rtol=0.02)  # the spectra reached the kernel
