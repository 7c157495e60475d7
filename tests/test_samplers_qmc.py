"""Mitsuba 3's `orthogonal` and `ldsampler` samplers (stdlib/render/sampler.rdsl) and a
`<sampler>` at the scene's top level: the sample patterns' stratification, a lower error
than the independent sampler at equal spp on the Cornell box, rdsl against Mitsuba 3's own
sampler on a small scene, Mitsuba's rounding of the sample count, and bad input."""

from __future__ import annotations

import itertools
import warnings

import numpy as np
import pytest
import rdsl
from _plugin_scenes import write_scene
from _scenes import CBOX
from rdsl.runtime.render.image import read_exr, rmse
from rdsl.runtime.scene import SceneError, load_scene_description
from rdsl.runtime.scene.samplers import valid_count

PATTERNS = """
import render.sampler;
fn ortho(i: UInt, n: UInt, dim: UInt, seed: UInt, u: Float) -> Float {
    return orthogonal_1d(i, n, dim, seed, u);
}
fn ld1(i: UInt, n: UInt, key: UInt, dim: UInt) -> Float { return ld_1d(i, n, key, dim); }
fn ld2x(i: UInt, n: UInt, key: UInt, dim: UInt) -> Float { return ld_2d(i, n, key, dim).x; }
fn ld2y(i: UInt, n: UInt, key: UInt, dim: UInt) -> Float { return ld_2d(i, n, key, dim).y; }
"""


@pytest.fixture(scope="module")
def patterns():
    return rdsl.jit(PATTERNS, target="avx2")


def _u(n: int, v: int) -> np.ndarray:
    return np.full(n, v, np.uint32)


@pytest.mark.parametrize("r", [2, 3, 5, 7])
def test_orthogonal_array_is_stratified_in_every_pair_of_dimensions(patterns, r):
    """Strength 2: any two of the r + 1 dimensions Bose's construction makes distinct put
    one sample in each cell of the r x r grid, and each dimension one in each of r^2
    strata; with or without jitter, for several pixels."""
    n = r * r
    i = np.arange(n, dtype=np.uint32)
    rng = np.random.default_rng(r)
    for seed in (1, 77, 0xdeadbeef):
        jitter = rng.random(n, dtype=np.float32)
        dims = [patterns.ortho(i, _u(n, n), _u(n, d), _u(n, seed), jitter)
                for d in range(r + 1)]
        for x in dims:
            assert (x >= 0).all() and (x < 1).all()
            assert sorted(np.floor(x * n).astype(int).tolist()) == list(range(n))
        for a, b in itertools.combinations(dims, 2):
            cells = np.floor(a * r).astype(int) * r + np.floor(b * r).astype(int)
            assert sorted(cells.tolist()) == list(range(n))


@pytest.mark.parametrize("m", [2, 4, 6])
def test_ldsampler_is_a_0_m_2_net(patterns, m):
    """The 2^m points of a pixel's 2D draw put one point in every elementary interval of
    area 2^-m (2^a x 2^(m-a) cells, every a), and a 1D draw one in each of 2^m strata."""
    n = 1 << m
    i = np.arange(n, dtype=np.uint32)
    for key, dim in ((3, 0), (12345, 5), (0xabcdef, 17)):
        x = patterns.ld2x(i, _u(n, n), _u(n, key), _u(n, dim))
        y = patterns.ld2y(i, _u(n, n), _u(n, key), _u(n, dim))
        assert (x >= 0).all() and (x < 1).all() and (y >= 0).all() and (y < 1).all()
        for a in range(m + 1):
            cells = np.floor(x * (1 << a)).astype(int) * (1 << (m - a)) + \
                np.floor(y * (1 << (m - a))).astype(int)
            assert sorted(cells.tolist()) == list(range(n)), a
        u = patterns.ld1(i, _u(n, n), _u(n, key), _u(n, dim))
        assert sorted(np.floor(u * n).astype(int).tolist()) == list(range(n))
        # the sample order differs between dimensions (Kollig and Keller's padding)
        other = patterns.ld1(i, _u(n, n), _u(n, key), _u(n, dim + 1))
        assert not np.array_equal(np.argsort(u), np.argsort(other))


def test_sample_counts_are_rounded_as_mitsuba_rounds_them():
    assert [valid_count("orthogonal", n) for n in (1, 4, 5, 16, 25, 64)] == \
        [4, 4, 9, 25, 25, 121]
    assert [valid_count("ldsampler", n) for n in (1, 4, 5, 16, 17, 64)] == \
        [4, 4, 16, 16, 64, 64]


def _cbox(tmp_path, sampler: str):
    path = tmp_path / f"cbox_{sampler}.xml"
    path.write_text(CBOX.read_text().replace('<sampler type="independent">',
                                             f'<sampler type="{sampler}">'))
    return path


@pytest.mark.parametrize(("sampler", "spp"), [("orthogonal", 25), ("ldsampler", 16)])
def test_low_discrepancy_lowers_the_error_on_the_cornell_box(tmp_path, sampler, spp):
    """At equal spp, against Mitsuba 3's reference image; unbiased (the image's mean)."""
    ref = read_exr(CBOX.with_name("cbox_ref_rgb.exr"))[..., :3]
    errors = {}
    for name, path in (("independent", CBOX), (sampler, _cbox(tmp_path, sampler))):
        img = rdsl.load_scene(path, spp=spp, res=256).render(spp=spp, seed=3)
        errors[name] = rmse(img, ref)
        assert abs(np.mean(img) - ref.mean()) < 0.01 * ref.mean(), name
    assert errors[sampler] < 0.75 * errors["independent"], errors


@pytest.mark.parametrize(("sampler", "spp"), [("orthogonal", 25), ("ldsampler", 16)])
def test_against_mitsubas_own_sampler(tmp_path, sampler, spp):
    """A small scene with the sampler declared at the top level, as Mitsuba's docs scenes
    do (Mitsuba 3.9 ignores it there, so its render is given the sampler in the sensor):
    rdsl's RMSE at equal spp is within 1.2x of Mitsuba's with its own sampler (medians of
    four seeds each: a path that finds the small light makes a rare firefly), against an
    independent-sampler reference."""
    from _mitsuba_compare import mitsuba_render

    top = f'<sampler type="{sampler}"><integer name="sample_count" value="{spp}"/></sampler>'
    ours = write_scene(tmp_path, top, name="ours.xml")
    theirs, plain = ours.with_name("theirs.xml"), ours.with_name("plain.xml")
    theirs.write_text(ours.read_text().replace(top, "").replace("</film>", "</film>" + top))
    plain.write_text(ours.read_text().replace(top, ""))
    scene = rdsl.load_scene(ours)
    assert scene.desc.sensor.sampler.type == sampler and scene.spp == spp
    ref = mitsuba_render(plain, 4096, seed=100)

    def err(img: np.ndarray) -> float:
        return float(np.sqrt(np.mean((np.asarray(img, np.float64)[..., :3] - ref) ** 2)))

    mine = np.median([err(scene.render(seed=k)) for k in range(4)])
    other = np.median([err(mitsuba_render(theirs, spp, seed=7 + k)) for k in range(4)])
    independent = np.median([err(mitsuba_render(plain, spp, seed=20 + k)) for k in range(4)])
    assert mine <= 1.2 * other, (mine, other)
    assert mine < 0.75 * independent, (mine, independent)


def test_top_level_sampler_applies_to_sensors_without_their_own(tmp_path):
    top = '<sampler type="ldsampler"><integer name="sample_count" value="64"/></sampler>'
    desc = load_scene_description(write_scene(tmp_path, top))
    assert (desc.sensor.sampler.type, desc.sensor.sampler["sample_count"]) == ("ldsampler", 64)
    own = write_scene(tmp_path, top, name="own.xml").read_text().replace(
        "</film>", '</film><sampler type="stratified"/>')
    (tmp_path / "own.xml").write_text(own)
    assert load_scene_description(tmp_path / "own.xml").sensor.sampler.type == "stratified"


BAD = {
    "strength": ('<sampler type="orthogonal"><integer name="strength" value="3"/></sampler>',
                 "rdsl builds orthogonal arrays of strength 2 only"),
    "float_count": (('<sampler type="ldsampler"><float name="sample_count" value="16"/>'
                    '</sampler>'), ("parameter 'sample_count' of sampler 'ldsampler' expects an "
                    "integer, got <float>")),
    "ld_jitter": ('<sampler type="ldsampler"><boolean name="jitter" value="false"/></sampler>',
                  "unknown parameter 'jitter' of sampler 'ldsampler'"),
    "zero_count": (('<sampler type="orthogonal"><integer name="sample_count" value="0"/>'
                   '</sampler>'), "'sample_count' must be positive"),
    "two": ('<sampler type="ldsampler"/>\n<sampler type="orthogonal"/>',
            "more than one <sampler> outside its sensors"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_sampler(tmp_path, case):
    body, message = BAD[case]
    path = write_scene(tmp_path, body)
    lines = path.read_text().split("\n")
    line = 1 + next(k for k, t in enumerate(lines) if body.split("\n")[-1] in t)
    with pytest.raises(SceneError) as exc:
        load_scene_description(path)
    text = str(exc.value)
    assert message in text and text.startswith(f"{path}:{line}:"), text


def test_rounded_count_warns_naming_the_line(tmp_path):
    body = '<sampler type="orthogonal"><integer name="sample_count" value="16"/></sampler>'
    path = write_scene(tmp_path, body)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        desc = load_scene_description(path)
    assert desc.sensor.sampler["sample_count"] == 25
    assert any(f"{path}:" in str(w.message) and "rounding 16 to 25" in str(w.message)
               for w in caught), [str(w.message) for w in caught]
