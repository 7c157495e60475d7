"""Mitsuba 3's `shapegroup`, `instance` and `merge` shapes: renders against Mitsuba 3 (Embree
instancing and the rdsl BVH's world-space copies), the memory of 10^4 instances of a
~10k-triangle mesh against one (RSS), and bad input."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from _plugin_scenes import check_bad, median_rmse, write_scene

# a sphere (tessellated inside a group) and a cube, instanced three times: rotated, scaled
# unevenly (normals need the inverse transpose) and mirrored (the winding turns around)
GROUP = """
  <shape type="shapegroup" id="g">
    <shape type="sphere"><float name="radius" value="0.3"/>
      <bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.7, 0.3"/></bsdf></shape>
    <shape type="cube">
      <transform name="to_world"><scale value="0.2"/><translate x="0.5"/></transform>
      <bsdf type="roughconductor"><float name="alpha" value="0.2"/></bsdf></shape>
  </shape>
  <shape type="instance"><ref id="g"/><transform name="to_world">
    <rotate y="1" angle="30"/><translate x="-0.7" y="0.4"/></transform></shape>
  <shape type="instance"><ref id="g"/><transform name="to_world">
    <scale x="1.5" y="0.7" z="1"/><translate x="0.5" y="-0.5"/></transform></shape>
  <shape type="instance"><ref id="g"/><transform name="to_world">
    <scale x="-1"/><translate x="0.3" y="0.7"/></transform></shape>"""

MERGE = """
  <shape type="merge">
    <shape type="cube"><transform name="to_world"><scale value="0.4"/><rotate x="1"
      angle="40"/><rotate y="1" angle="30"/><translate x="-0.5"/></transform>
      <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.3, 0.2"/></bsdf></shape>
    <shape type="rectangle"><transform name="to_world"><scale value="0.5"/><rotate y="1"
      angle="-30"/><translate x="0.6"/></transform>
      <bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.3, 0.8"/></bsdf></shape>
  </shape>"""


def _check(path: Path) -> None:
    """rdsl's median RMSE within 1.2x of Mitsuba's at 32 spp, against 4096 spp."""
    mine, theirs = median_rmse(path, 32)
    assert mine <= 1.2 * theirs, (mine, theirs)


def test_instances_against_mitsuba(tmp_path):
    _check(write_scene(tmp_path, GROUP))


def test_merge_against_mitsuba(tmp_path):
    _check(write_scene(tmp_path, MERGE))


def test_bvh_flattens_instances_as_embree_instances_them(tmp_path):
    """The rdsl BVH (no instances) traces world-space copies: the same image as Embree's
    instances, to float rounding; Embree's buffers hold the group's triangles once."""
    import rdsl

    path = write_scene(tmp_path, GROUP)
    embree = rdsl.load_scene(path, accel="embree")
    bvh = rdsl.load_scene(path, accel="bvh")
    a, b = embree.render(spp=8, seed=3), bvh.render(spp=8, seed=3)
    assert np.sqrt(np.mean((a - b) ** 2)) < 1e-4 * max(float(a.mean()), 1e-3)
    assert len(bvh.buffers.F) > 2.9 * len(embree.buffers.F)  # three copies against one


def _rss(tmp_path: Path, count: int) -> dict:
    script = Path(__file__).with_name("_instancing_rss.py")
    out = subprocess.run([sys.executable, str(script), str(tmp_path), str(count)],
                         capture_output=True, text=True, timeout=900, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_ten_thousand_instances_cost_memory_once(tmp_path):
    """10^4 instances of a ~10k-triangle mesh: the process's peak RSS grows by far less
    than 10^4 copies of the mesh would take (its vertices and triangles alone: ~1.8 GB)."""
    one, many = _rss(tmp_path, 1), _rss(tmp_path, 10_000)
    assert one["triangles"] > 9000 and many["instances"] == 10_000
    copies = 10_000 * one["mesh_bytes"]
    growth = (many["maxrss_kib"] - one["maxrss_kib"]) * 1024
    assert growth < 0.05 * copies, (growth, copies)
    assert many["mean"] > 0  # the instances rendered


BAD = {
    "not_a_group": (('<shape type="rectangle" id="r"/><shape type="instance"><ref id="r"/>'
                    '</shape>'), ("instance: takes a <ref> to a 'shapegroup', got shape 'r' "
                    "(a 'rectangle')")),
    "no_group": ('<shape type="instance"/>', "shape 'instance' takes 1 nested <shape>, got 0"),
    "emitter": (('<shape type="shapegroup"><shape type="rectangle"><emitter type="area"/>'
                '</shape></shape>'), "shapegroup: a shape with an emitter cannot be instanced"),
    "nested": ('<shape type="shapegroup"><shape type="shapegroup"/></shape>',
               "shapegroup: cannot hold a nested 'shapegroup' shape"),
    "singular": (('<shape type="shapegroup" id="g"/><shape type="instance"><ref id="g"/>'
                 '<transform name="to_world"><scale x="0"/></transform></shape>'),
                 "instance: 'to_world' is singular or not finite"),
    "group_param": ('<shape type="shapegroup"><float name="radius" value="1"/></shape>',
                    ("unknown parameter 'radius' of shape 'shapegroup'; accepted: no "
                    "parameters")),
    "merge_group": ('<shape type="merge"><shape type="shapegroup"/></shape>',
                    "merge: cannot hold a nested 'shapegroup' shape"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_instancing(tmp_path, case):
    check_bad(tmp_path, *BAD[case])


def test_default_camera_frames_instances_as_the_shapes_they_place(tmp_path):
    """Without a sensor, the camera frames the instances' world-space bounds: the same camera
    as for the group's shapes placed directly."""
    from rdsl.runtime.scene import load_scene_description

    move = '<rotate z="1" angle="30"/><translate x="2" y="-1"/>'
    inst = tmp_path / "inst.xml"
    inst.write_text('<scene version="3.0.0"><shape type="shapegroup" id="g"><shape type="cube"/>'
                    '</shape><shape type="instance"><ref id="g"/><transform name="to_world">'
                    f'{move}</transform></shape></scene>')
    plain = tmp_path / "plain.xml"
    plain.write_text(f'<scene version="3.0.0"><shape type="cube"><transform name="to_world">'
                     f'{move}</transform></shape></scene>')
    a, b = (load_scene_description(p).sensor["to_world"] for p in (inst, plain))
    np.testing.assert_allclose(a, b, atol=1e-5)


def test_too_many_copies_for_the_bvh_is_a_clear_error(tmp_path, monkeypatch):
    """The rdsl BVH copies instances; past a bound of triangles that is an error naming the
    instance's line and Embree's instancing, not hours of BVH building."""
    import rdsl
    from rdsl.compiler.diagnostics import CompileError
    from rdsl.runtime.render import flatten

    monkeypatch.setattr(flatten, "MAX_COPIED_TRIANGLES", 100)
    path = write_scene(tmp_path, GROUP)
    with pytest.raises(CompileError, match=r"copied into [\d,]+ triangles.*--accel embree"):
        rdsl.load_scene(path, accel="bvh")


def test_opencl_renders_instances_as_embree_does(tmp_path):
    """A GPU-style target (OpenCL, on PoCL here) traces the rdsl BVH's copies: the same image
    as the CPU's Embree instances, to float rounding."""
    import rdsl
    from rdsl.runtime.opencl import OpenCLUnavailable, opencl_context

    try:
        opencl_context()
    except OpenCLUnavailable as e:
        pytest.skip(str(e))
    path = write_scene(tmp_path, GROUP)
    a = rdsl.load_scene(path).render(spp=4, seed=2)
    scene = rdsl.load_scene(path, target="opencl")
    assert scene.accel == "bvh"
    b = scene.render(spp=4, seed=2)
    assert np.sqrt(np.mean((a - b) ** 2)) < 1e-4 * max(float(a.mean()), 1e-3)
