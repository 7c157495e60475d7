"""Mitsuba 3's `sdfgrid` shape: a signed distance field on a grid over the unit cube.

- `.vol` files: rdsl reads what Mitsuba's VolumeGrid writes and Mitsuba reads what rdsl
  writes;
- hits (Embree user geometry, callback in rdsl, every packet width) are Mitsuba 3's hits on
  the same grid, and land within the trilinear interpolation error of the true sphere the
  grid samples (an error that shrinks 4x when the grid spacing halves);
- the geometric (gradient) and smooth shading normals are Mitsuba's;
- a scene with an sdfgrid renders as Mitsuba renders it (noise-aware), through Embree and
  through rdsl's own BVH;
- a missing file, a bad header, a wrong size, a grid of several channels or without
  surface, a bad `grid` array in load_dict, or an sdfgrid as an emitter: an error that names
  the file and says what was expected.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

import rdsl
from rdsl.runtime.scene.analytic import Analytic
from rdsl.runtime.scene.dicts import dict_to_xml
from rdsl.runtime.scene.errors import SceneError
from rdsl.runtime.scene.loader import load_scene_description
from rdsl.runtime.scene.volgrid import read_vol, write_vol

embree = pytest.importorskip("rdsl.runtime.embree")
try:
    embree.load_embree()
except Exception as e:  # pragma: no cover - depends on the machine
    pytest.skip(f"Embree is not available: {e}", allow_module_level=True)

from rdsl.runtime import embree_user  # noqa: E402
from rdsl.runtime.render.shapes import shape_record  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent / "compat"))
from _sheet import RATIO, rmse  # noqa: E402

CENTER, RADIUS = np.array([0.5, 0.45, 0.5]), 0.35
# object space [0, 1]^3 to world: a non-uniform scale and a translation
TO_WORLD = np.array([[2.0, 0, 0, -1.0], [0, 1.5, 0, -0.7], [0, 0, 2.5, -1.2], [0, 0, 0, 1]])


def sphere_grid(n: int) -> np.ndarray:
    """The distance to the sphere (CENTER, RADIUS), sampled on n^3 points: (z, y, x)."""
    x = np.linspace(0.0, 1.0, n)
    z, y, x = np.meshgrid(x, x, x, indexing="ij")
    d = np.sqrt((x - CENTER[0]) ** 2 + (y - CENTER[1]) ** 2 + (z - CENTER[2]) ** 2) - RADIUS
    return d.astype(np.float32)


def user_scene(grid: np.ndarray, to_world: np.ndarray = TO_WORLD, smooth: bool = True):
    rec = shape_record(Analytic("sdfgrid", to_world, grid=grid, smooth=smooth))
    return embree.EmbreeScene([embree_user.sdfgrid(rec, to_world)]), rec


def random_rays(n: int, seed: int, to_world: np.ndarray = TO_WORLD):
    """Rays from around the grid's box towards points in it (unnormalized directions)."""
    rng = np.random.default_rng(seed)
    o = rng.uniform(-3, 3, (n, 3))
    target = rng.uniform(0.1, 0.9, (n, 3)) @ to_world[:3, :3].T + to_world[:3, 3]
    d = (target - o) * rng.uniform(0.5, 2.0, (n, 1))
    return o.astype(np.float32), d.astype(np.float32)


def mitsuba_scene(grid: np.ndarray, to_world: np.ndarray = TO_WORLD, normals: str = "smooth"):
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    return mi, mi.load_dict({"type": "scene", "s": {
        "type": "sdfgrid", "grid": mi.TensorXf(grid[..., None]), "normals": normals,
        "to_world": mi.ScalarTransform4f(to_world)}})


def test_vol_files_are_mitsubas(tmp_path):
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    g = np.random.default_rng(0).normal(size=(3, 4, 5, 1)).astype(np.float32)
    mi.VolumeGrid(g).write(str(tmp_path / "mi.vol"))
    data, bbox = read_vol(tmp_path / "mi.vol")
    assert np.array_equal(data, g) and bbox.shape == (2, 3)
    write_vol(tmp_path / "rdsl.vol", g[..., 0])
    assert np.array_equal(np.array(mi.VolumeGrid(str(tmp_path / "rdsl.vol"))).reshape(g.shape), g)


def test_hits_are_mitsubas_at_every_packet_width():
    grid = sphere_grid(16)
    scene, _ = user_scene(grid)
    o, d = random_rays(1500, 1)
    ours = scene.intersect(o, d, width=1)
    assert 0.3 < ours["hit"].mean() < 0.9
    for width in (4, 8, 16):
        got = scene.intersect(o, d, width=width)
        np.testing.assert_array_equal(got["t"], ours["t"])
    mi, ms = mitsuba_scene(grid)
    theirs = np.array([ms.ray_intersect(mi.Ray3f(mi.Point3f(*map(float, a)),
                                                 mi.Vector3f(*map(float, b)))).t
                       for a, b in zip(o, d)])
    hit = np.isfinite(theirs)
    assert np.array_equal(ours["hit"], hit)
    rel = np.abs(ours["t"][hit] - theirs[hit]) / theirs[hit]
    assert rel.max() < 2e-5, rel.max()  # float32 transforms of the ray, 1e-5 solver tolerance
    occluded = scene.occluded(o, d)
    assert np.array_equal(occluded, hit)


@pytest.mark.parametrize("n", [16, 32])
def test_hits_lie_within_the_interpolation_error_of_the_sphere(n):
    """Trilinear interpolation of the sphere's distance errs by at most (h^2 / 8) times the
    sum of |d^2f/dx_i^2| <= 3 h^2 / (8 r) at spacing h (the Hessian's diagonal is at most 1/r
    on the surface, the gradient has length 1): the hit points lie that close to the
    sphere, and halving h cuts the largest error by about 4."""
    h = 1.0 / (n - 1)
    # rotated too (Mitsuba warns and then misses hits: its voxels' world boxes assume no
    # rotation), so the error is measured in object space
    c, s = np.cos(0.7), np.sin(0.7)
    to_world = np.array([[c, 0, s, 0.3], [0, 1, 0, -0.2], [-s, 0, c, 0.1], [0, 0, 0, 1]])
    to_world[:3, :3] *= 1.7
    scene, _ = user_scene(sphere_grid(n), to_world)
    rng = np.random.default_rng(n)
    o = rng.uniform(-1, 2, (4000, 3))
    d = CENTER + rng.uniform(-0.3, 0.3, (4000, 3)) - o
    o, d = (o @ to_world[:3, :3].T + to_world[:3, 3]).astype(np.float32), \
        (d @ to_world[:3, :3].T).astype(np.float32)
    r = scene.intersect(o, d)
    assert r["hit"].mean() > 0.9
    p = o[r["hit"]].astype(np.float64) + d[r["hit"]] * r["t"][r["hit"], None]
    local = (p - to_world[:3, 3]) @ np.linalg.inv(to_world[:3, :3]).T
    err = np.abs(np.linalg.norm(local - CENTER, axis=1) - RADIUS)
    bound = 3 * h * h / (8 * RADIUS)
    assert err.max() <= bound, (err.max(), bound)
    assert err.max() > bound / 30  # the grid's error, not an exact sphere


NORMAL_SRC = """
import render.geometry;
fn gradient_normal(R: [Float], p: Vec3, cell: Float) -> Vec3 {
    let local = record_affine(R, 12, p);
    return normalize(record_normal(R, 12, sdfgrid_gradient(R, 0, cell, local)));
}
fn smooth_normal(R: [Float], p: Vec3) -> Vec3 {
    return normalize(record_normal(R, 12, sdfgrid_smooth(R, 0, record_affine(R, 12, p))));
}
"""


def test_normals_are_mitsubas():
    grid = sphere_grid(12)
    scene, rec = user_scene(grid)
    o, d = random_rays(800, 2)
    r = scene.intersect(o, d)
    hit = r["hit"]
    p = (o + d * r["t"][:, None])[hit].astype(np.float32)
    mod = rdsl.jit(NORMAL_SRC, target="scalar", variant="mono")
    rec32 = rec.astype(np.float32)
    ng = np.asarray(mod.gradient_normal(rec32, p, r["u"][hit]))
    sh = np.asarray(mod.smooth_normal(rec32, p))
    mi, ms = mitsuba_scene(grid)
    ref_n, ref_sh = [], []
    for a, b in zip(o[hit], d[hit]):
        si = ms.ray_intersect(mi.Ray3f(mi.Point3f(*map(float, a)), mi.Vector3f(*map(float, b))))
        ref_n.append(np.array(si.n))
        ref_sh.append(np.array(si.sh_frame.n))
    for ours, theirs in ((ng, np.array(ref_n)), (sh, np.array(ref_sh))):
        cos = np.sum(ours * theirs, axis=1)
        assert cos.min() > 1 - 1e-5, cos.min()  # measured: 1 - 2.4e-7
    # the two kinds differ on a coarse grid: each test above can fail
    assert np.sum(ng * sh, axis=1).min() < 0.999


SCENE = """<scene version="3.0.0">
    <integrator type="path"><integer name="max_depth" value="3"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="40"/>
        <transform name="to_world">
            <lookat origin="0.5, 3, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
        <sampler type="independent"/>
        <film type="hdrfilm"><integer name="width" value="40"/>
            <integer name="height" value="40"/><rfilter type="box"/></film>
    </sensor>
    <emitter type="constant"><rgb name="radiance" value="0.3"/></emitter>
    <emitter type="point"><point name="position" x="2" y="4" z="3"/>
        <rgb name="intensity" value="30"/></emitter>
    <shape type="sdfgrid">
        <string name="filename" value="sphere.vol"/>
        <string name="normals" value="{normals}"/>
        <transform name="to_world"><translate x="-0.5" y="-0.5" z="-0.5"/>
            <scale value="2"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.4, 0.2"/></bsdf>
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><scale value="4"/><rotate x="1" angle="-90"/>
            <translate y="-0.72"/></transform>
        <bsdf type="diffuse"/>
    </shape>
</scene>
"""


@pytest.fixture(scope="module")
def render_scene(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sdfgrid")
    write_vol(folder / "sphere.vol", sphere_grid(16))
    (folder / "scene.xml").write_text(SCENE.format(normals="smooth"))
    return folder / "scene.xml"


def test_render_matches_mitsuba(render_scene):
    """rdsl at 32 spp is as close to a 1024-spp Mitsuba reference as Mitsuba at 32 spp
    (RMSE ratio at most compat's RATIO), through Embree and through rdsl's BVH."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    ms = mi.load_file(str(render_scene))
    ref = np.array(mi.render(ms, spp=1024, seed=7), np.float64)
    theirs = np.median([rmse(np.array(mi.render(ms, spp=32, seed=s), np.float64), ref)
                        for s in (1, 2)])
    for accel in ("embree", "bvh"):
        scene = rdsl.load_scene(render_scene, variant="rgb", accel=accel)
        ours = np.median([rmse(np.asarray(scene.render(spp=32, seed=s), np.float64), ref)
                          for s in (1, 2)])
        assert ours <= RATIO * theirs, (accel, ours, theirs)


def _load(folder: Path, shape: str) -> None:
    (folder / "s.xml").write_text(f'<scene version="3.0.0">{shape}</scene>')
    load_scene_description(folder / "s.xml")


def _sdf(filename: str, extra: str = "") -> str:
    return f'<shape type="sdfgrid"><string name="filename" value="{filename}"/>{extra}</shape>'


@pytest.mark.parametrize("content,expected", [
    (b"VOX\x03" + bytes(44), "does not start with 'VOL'"),
    (b"VOL\x02" + bytes(44), "version 2, expected 3"),
    (b"VOL", "shorter than the 48-byte header"),
])
def test_bad_header_names_the_file(tmp_path, content, expected):
    (tmp_path / "bad.vol").write_bytes(content)
    with pytest.raises(SceneError, match=expected) as e:
        _load(tmp_path, _sdf("bad.vol"))
    assert "bad.vol" in str(e.value) and "s.xml:1" in str(e.value)


def test_bad_grids_name_the_file(tmp_path):
    write_vol(tmp_path / "a.vol", sphere_grid(8))
    data = (tmp_path / "a.vol").read_bytes()
    (tmp_path / "short.vol").write_bytes(data[:-4])
    with pytest.raises(SceneError, match=r"short.vol.*2044 bytes of data, expected 2048"):
        _load(tmp_path, _sdf("short.vol"))
    write_vol(tmp_path / "two.vol", np.stack([sphere_grid(4)] * 2, axis=-1))
    with pytest.raises(SceneError, match=r"two.vol.*2 channels, expected 1"):
        _load(tmp_path, _sdf("two.vol"))
    write_vol(tmp_path / "empty.vol", np.ones((4, 4, 4), np.float32))
    with pytest.raises(SceneError, match=r"empty.vol.*no voxel with samples of both signs"):
        _load(tmp_path, _sdf("empty.vol"))
    with pytest.raises(SceneError, match=r"grid file 'missing.vol' not found"):
        _load(tmp_path, _sdf("missing.vol"))
    with pytest.raises(SceneError, match="normals"):
        _load(tmp_path, _sdf("a.vol", '<string name="normals" value="flat"/>'))
    with pytest.raises(SceneError, match="cannot be an area emitter"):
        _load(tmp_path, _sdf("a.vol", '<emitter type="area"/>'))
    with pytest.raises(SceneError, match="cannot hold a sensor"):
        _load(tmp_path, _sdf("a.vol", '<sensor type="irradiancemeter"/>'))
    with pytest.raises(SceneError, match="cannot instance an 'sdfgrid'"):
        _load(tmp_path, f'<shape type="shapegroup">{_sdf("a.vol")}</shape>')


def test_load_dict_grid_becomes_a_vol_file():
    g = sphere_grid(5)
    xml = dict_to_xml({"type": "scene", "s": {"type": "sdfgrid", "grid": g[..., None]}})
    name = xml.split('name="filename" value="')[1].split('"')[0]
    assert np.array_equal(read_vol(name)[0][..., 0], g)
    for bad, why in ((g[..., None].repeat(2, axis=-1), "2 channels, expected 1"),
                     (g[0], r"shape \(5, 5\), expected \(z, y, x, 1\)"),
                     (g[:1], "at least 2 along each axis")):
        with pytest.raises(SceneError, match=rf"scene\['s'\]\['grid'\]: the grid .*{why}"):
            dict_to_xml({"type": "scene", "s": {"type": "sdfgrid", "grid": bad}})
