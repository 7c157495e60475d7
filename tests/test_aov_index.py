"""The `aov` integrator's `prim_index` and `shape_index` against Mitsuba 3's (scalar_rgb).

Mitsuba 3.9 writes a hit's shape as its place in the scene's shape list, from 1 (0 on a
miss): the shapes that are not meshes (sphere, disk, cylinder, instance) first in declaration
order, then the meshes (obj, ply, rectangle, cube), in an order that changes from one load
to the next (measured: the same file loaded three times numbers its meshes differently).
So the non-meshes' numbers are compared as they are, and a mesh's as the shape it names:
the shape of Mitsuba's list at that place (its bounding box) is the one rdsl names.  The
prim_index is the triangle in its mesh (an instance's: in the shapegroup's mesh), 0 on the
shapes Mitsuba does not build of triangles.

Pixels are compared where one primitive covers the whole pixel: a box filter of radius 0.5
gives each pixel its samples' mean, and a pixel counts where Mitsuba's value is the same
integer in two renders of different seeds and in its 8 neighbours.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from _mitsuba_render import mitsuba_variant

pytest.importorskip("rdsl.runtime.embree")

RES = 60
# a quad of four triangles around its centre (OBJ) and of two (ASCII PLY), in [-1, 1]^2
FAN_OBJ = ("v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nv 0 0 0\n"
           "f 1 2 5\nf 2 3 5\nf 3 4 5\nf 4 1 5\n")
QUAD_PLY = ("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
            "property float z\nelement face 2\nproperty list uchar int vertex_indices\n"
            "end_header\n-1 -1 0\n1 -1 0\n1 1 0\n-1 1 0\n3 0 1 3\n3 1 2 3\n")


def _at(x: float, y: float, s: float = 0.8, first: str = "") -> str:
    return (f'<transform name="to_world">{first}<scale value="{s}"/>'
            f'<translate x="{x}" y="{y}"/></transform>')


CUBE_TURN = '<rotate x="1" angle="30"/><rotate y="1" angle="40"/>'
FILE = '<string name="filename" value="{}"/>'
EMITTER = '<emitter type="area"><rgb name="radiance" value="1"/></emitter>'
SPHERE = '<point name="center" x="-2" y="2" z="0"/><float name="radius" value="0.8"/>'
CYLINDER = ('<float name="radius" value="0.7"/><point name="p0" x="-2.8" y="-2" z="0"/>'
            '<point name="p1" x="-1.2" y="-2" z="0"/>')


def _shape(kind: str, centre: tuple, inner: str) -> tuple[str, tuple, str]:
    return kind, centre, f'<shape type="{kind}">{inner}</shape>'


# (type, centre, XML) of each shape in declaration order, on a 3 x 3 grid
SHAPES = [
    _shape("obj", (0, 2), FILE.format("fan.obj") + _at(0, 2) + '<ref id="mat"/>'),
    _shape("sphere", (-2, 2), SPHERE),
    _shape("rectangle", (2, 2), _at(2, 2) + EMITTER),
    _shape("cube", (-2, 0), _at(-2, 0, 0.55, CUBE_TURN)),
    _shape("ply", (0, 0), FILE.format("quad.ply") + _at(0, 0)),
    _shape("disk", (2, 0), _at(2, 0) + '<ref id="mat"/>'),
    _shape("cylinder", (-2, -2), CYLINDER),
    _shape("instance", (0, -2), '<ref id="grp"/>' + _at(0, -2, 1)),
    _shape("instance", (2, -2), '<ref id="grp"/>' + _at(2, -2, 1)),
]
MESHES = ("obj", "ply", "rectangle", "cube")
GROUP = f"""<shape type="shapegroup" id="grp">
    <shape type="cube">{_at(0, 0, 0.5, CUBE_TURN)}</shape>
    <shape type="sphere"><float name="radius" value="0.35"/><point name="center" x="0.35"
        y="0.35" z="1"/></shape>
  </shape>"""


# an SDF grid of a sphere (5^3 samples) and a bent linear curve
CENTRED = '<translate x="-0.5" y="-0.5" z="-0.5"/>'  # the grid's unit cube around 0
SDF_SHAPES = [
    _shape("linearcurve", (0, 1.5), FILE.format("lin.txt") + _at(0, 1.5, 1.5)),
    _shape("rectangle", (-2, 2), _at(-2, 2)),
    _shape("sdfgrid", (0, -1), FILE.format("g.vol") + _at(0, -1, 2, CENTRED)),
]
LINEAR = "-1.0 0.0 0.0 0.2\n0.0 0.3 0.2 0.3\n1.0 0.0 0.5 0.1\n"


def _files(folder: Path) -> None:
    from rdsl.runtime.scene.volgrid import write_vol

    (folder / "fan.obj").write_text(FAN_OBJ)
    (folder / "quad.ply").write_text(QUAD_PLY)
    (folder / "lin.txt").write_text(LINEAR)
    x = np.linspace(0.0, 1.0, 5)
    z, y, x = np.meshgrid(x, x, x, indexing="ij")
    write_vol(folder / "g.vol", (np.sqrt((x - 0.5) ** 2 + (y - 0.5) ** 2 + (z - 0.5) ** 2)
                                 - 0.4).astype(np.float32))


def scene(folder: Path, shapes: list = SHAPES) -> Path:
    _files(folder)
    body = "\n  ".join(xml for _, _, xml in shapes)
    path = folder / "index.xml"
    path.write_text(f"""<scene version="3.0.0">
  <integrator type="aov"><string name="aovs" value="pi:prim_index,si:shape_index"/>
  </integrator>
  <sensor type="orthographic">
    <transform name="to_world"><scale x="3" y="3"/>
      <lookat origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/></transform>
    <sampler type="independent"><integer name="sample_count" value="16"/></sampler>
    <film type="hdrfilm"><integer name="width" value="{RES}"/>
      <integer name="height" value="{RES}"/><rfilter type="box"/></film>
  </sensor>
  <bsdf type="diffuse" id="mat"><rgb name="reflectance" value="0.3, 0.5, 0.7"/></bsdf>
  {GROUP}
  {body}
</scene>
""")
    return path


def solid(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Where two renders agree on one integer, in the pixel and its 8 neighbours."""
    ok = (a == b) & (a == np.round(a))
    pad = np.pad(a, 1, mode="edge")
    for dy in (0, 1, 2):
        for dx in (0, 1, 2):
            ok &= pad[dy:dy + RES, dx:dx + RES] == a
    return ok


def mitsuba_render(path: Path) -> tuple:
    """Mitsuba's prim_index and shape_index at two seeds, and the centre (x, y) of the shape
    at each place of its shape list."""
    with mitsuba_variant("scalar_rgb") as mi:
        s = mi.load_file(str(path))
        a, b = (np.array(mi.render(s, spp=32, seed=k)) for k in (1, 2))
        centres = [_centre(np.array(sh.bbox().center())[:2]) for sh in s.shapes()]
    return a, b, centres


@pytest.fixture(scope="module")
def mixed(tmp_path_factory):
    path = scene(tmp_path_factory.mktemp("aov_index"))
    return (path, *mitsuba_render(path))


def _centre(c: tuple) -> tuple:
    return tuple(round(float(x), 3) for x in c)


def check(path: Path, a: np.ndarray, b: np.ndarray, centres: list, shapes: list,
          min_prims: int, target: str = "host", **options) -> None:
    """rdsl's render of ``path`` against Mitsuba's ``a`` and ``b`` where a primitive
    covers the whole pixel."""
    from rdsl.runtime.render.renderer import load_scene

    sc = load_scene(path, target=target, **{"variant": "rgb", **options})
    assert sc.channel_names[-2:] == ["pi.I", "si.I"]
    ours = sc.render(spp=16, seed=3)
    # prim_index: the same primitive wherever one covers the pixel
    prim = solid(a[..., -2], b[..., -2])
    assert len(np.unique(a[..., -2][prim])) >= min_prims
    np.testing.assert_array_equal(ours[..., -2][prim], a[..., -2][prim])
    # shape_index: misses 0 and non-meshes as Mitsuba numbers them; meshes name the same shape
    ok = solid(a[..., -1], b[..., -1])
    theirs, mine = a[..., -1][ok].astype(int), ours[..., -1][ok].astype(int)
    assert np.all(ours[..., -1][ok] == mine)
    kinds = [t for t, _, _ in shapes]
    order = ([k for k, t in enumerate(kinds) if t not in MESHES]
             + [k for k, t in enumerate(kinds) if t in MESHES])
    named = {place: _centre(shapes[k][1]) for place, k in enumerate(order, 1)}
    meshes = theirs > len(order) - sum(t in MESHES for t in kinds)
    np.testing.assert_array_equal(mine[~meshes], theirs[~meshes])
    assert [named[v] for v in mine[meshes]] == [centres[v - 1] for v in theirs[meshes]]
    assert set(theirs) == set(range(len(shapes) + 1))  # every shape and the background seen


@pytest.mark.parametrize("accel,triangulate,variant", [
    ("embree", False, "rgb"), ("bvh", False, "rgb"), ("embree", True, "rgb"),
    ("embree", False, "spectral")])
def test_indices_match_mitsuba(mixed, accel, triangulate, variant):
    """Meshes from OBJ and PLY, a rectangle with an area emitter, a cube, a sphere, a disk,
    a cylinder, two instances of a shapegroup (a cube and a sphere), shapes with a `<ref>`'d
    BSDF; with Embree, with the rdsl BVH (instances copied), triangulated, and spectral."""
    check(*mixed, SHAPES, 8, accel=accel, triangulate=triangulate, variant=variant)


@pytest.mark.skipif(shutil.which("cc") is None, reason="no C compiler (cc) on PATH")
def test_c_target_matches_mitsuba(mixed):
    """The C target (the rdsl BVH, compiled by cc) numbers them alike."""
    check(*mixed, SHAPES, 8, target="c")


@pytest.mark.parametrize("accel", ["embree", "bvh"])
def test_curve_and_sdfgrid_indices_match_mitsuba(tmp_path, accel):
    """A curve's segment and an SDF grid's voxel (numbered among the voxels that hold
    surface, as Mitsuba's primitives)."""
    path = scene(tmp_path, SDF_SHAPES)
    check(path, *mitsuba_render(path), SDF_SHAPES, 6, accel=accel)


def test_bad_aov_type_is_a_diagnostic(tmp_path):
    """A misspelt type is an error at the `aovs` line that lists the types, these among
    them."""
    from rdsl.runtime.render.renderer import load_scene
    from rdsl.runtime.scene import SceneError

    path = scene(tmp_path)
    path.write_text(path.read_text().replace("si:shape_index", "si:shape_idx"))
    with pytest.raises(SceneError) as e:
        load_scene(path, variant="rgb", target="host")
    text = str(e.value)
    assert text.startswith(f"{path}:2:") and "bad entry 'si:shape_idx'" in text
    assert "prim_index, shape_index" in text
