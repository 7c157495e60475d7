"""The polarized BSDFs and the `stokes` integrator against Mitsuba 3 itself (skipped
without the `mitsuba` package): the Mueller matrices of eval() and sample() of every
polarization-aware BSDF (dielectric, conductor, roughconductor, thindielectric, polarizer,
retarder) and the depolarizers (diffuse, plastic, roughdielectric, roughplastic), in
`mono_polarized` against Mitsuba's `scalar_spectral_polarized`, and a small scene rendered
by the `stokes` integrator, S0..S3 per image block.  tests/test_polarized_mitsuba.py does
the same in `spectral_polarized` and for the combinators twosided and blendbsdf."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rdsl

STDLIB = Path(rdsl.__file__).resolve().parent / "stdlib"
f32 = np.float32

# ---------------------------------------------------------------------- against Mitsuba 3
#
# Like for like: Mitsuba's BSDF::eval and BSDF::sample return Mueller matrices in the local
# shading frame, from the implicit Stokes basis of the arriving light (stokes_basis(-wo)) to
# that of the leaving light (stokes_basis(wi)); the integrator does the to_world step.  rdsl's
# plugins return the same (path.rdsl calls to_world_mueller), so the matrices are compared
# entry by entry for local directions, with the frame z = normal, x = u, y = v on both sides
# (Mitsuba's Frame3f((0, 0, 1)) is the identity).  Mitsuba here has no scalar mono polarized
# variant, so it runs `scalar_spectral_polarized` with four equal wavelengths and
# wavelength-independent parameters; rdsl runs `mono_polarized`.

LLVM = "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"


def mitsuba_polarized() -> Iterator[Any]:
    """The `mitsuba` module in `scalar_spectral_polarized` (skips without it), its previous
    variant restored afterwards: the body of the `mi` fixtures."""
    mitsuba = pytest.importorskip("mitsuba", reason="the mitsuba package is not installed")
    previous = mitsuba.variant()
    try:
        mitsuba.set_variant("scalar_spectral_polarized")
    except Exception as e:  # noqa: BLE001 - any failure means no cross-check here
        pytest.skip(f"mitsuba variant scalar_spectral_polarized unavailable: {e}")
    yield mitsuba
    if previous is not None:
        mitsuba.set_variant(previous)


@pytest.fixture(scope="module")
def mi():
    yield from mitsuba_polarized()


_MODS: dict[str, rdsl.Module] = {}


def _plugin(name: str) -> rdsl.Module:
    if name not in _MODS:
        _MODS[name] = rdsl.jit(str(STDLIB / "bsdf" / f"{name}.rdsl"), target="host",
                               variant="mono_polarized")
    return _MODS[name]


def _call(name: str, fn: str, *args, **params):
    """A plugin function, with every Spectrum parameter given as u times the identity."""
    mod = _plugin(name)
    kernel = next(k for k in mod.manifest["kernels"] if k["name"] == f"{name}.{fn}")
    for p in kernel["params"]:
        if p["uniform"] and p["type"].get("name") == "Mueller":
            v = float(params.get(p["name"], p["default"]))
            params[p["name"]] = {f"m{i}{j}": v * (i == j) for i in range(4) for j in range(4)}
    return mod[f"{name}.{fn}"](*args, **params)


def _surfaces(wi: np.ndarray) -> dict:
    n = len(wi)
    z = np.tile(np.array([0, 0, 1], f32), (n, 1))
    return {"p": np.zeros((n, 3), f32), "n": z, "sh_n": z, "uv": np.zeros((n, 2), f32),
            "wi": np.ascontiguousarray(wi, f32), "t": np.ones(n, f32), "valid": np.ones(n, bool)}


def _matrices(weight: dict, n: int) -> np.ndarray:
    """(n, 4, 4) Mueller matrices from a kernel's `Mueller` struct output."""
    return np.stack([np.stack([np.asarray(weight[f"m{i}{j}"]).reshape(n) for j in range(4)], -1)
                     for i in range(4)], -2).astype(np.float64)


def _mi_si(mi, wi):
    si = mi.SurfaceInteraction3f()
    si.p, si.n, si.sh_frame = [0, 0, 0], [0, 0, 1], mi.Frame3f([0, 0, 1])
    si.wavelengths = [550.0] * 4
    si.wi = [float(x) for x in wi]
    return si


def _mi_matrix(m) -> np.ndarray:
    return np.array(m)[..., 0].astype(np.float64)  # [row, column, wavelength]


def _directions(thetas_deg, phis) -> np.ndarray:
    t = np.radians(np.asarray(thetas_deg, np.float64))[:, None]
    p = np.asarray(phis, np.float64)[None, :]
    d = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t) + 0 * p], -1)
    return d.reshape(-1, 3)


def _rel_err(ours: np.ndarray, theirs: np.ndarray) -> float:
    """Largest entry difference relative to the intensity entry (at least 1)."""
    return float(np.abs(ours - theirs).max() / max(1.0, abs(theirs[0, 0])))


DIRS = _directions([3, 30, 56.3, 75, 88], [0.0, 0.7, 2.5, -2.0])  # 56.3: Brewster for 1.5
DELTA_CASES = [  # (plugin, Mitsuba's parameters, rdsl's, light also from below)
    ("dielectric", {"int_ior": 1.5, "ext_ior": 1.0}, {"int_ior": 1.5, "ext_ior": 1.0}, True),
    ("conductor", {"eta": 0.2, "k": 3.9}, {"eta": 0.2, "k": 3.9}, False),
    ("thindielectric", {"int_ior": 1.5, "ext_ior": 1.0}, {"int_ior": 1.5, "ext_ior": 1.0},
     True),
    ("polarizer", {"theta": 30.0}, {"theta": 30.0}, True),
    ("retarder", {"theta": 20.0, "delta": 90.0}, {"theta": 20.0, "delta": 90.0}, True),
    ("plastic", {"int_ior": 1.5, "ext_ior": 1.0, "diffuse_reflectance": 0.4},
     {"int_ior": 1.5, "ext_ior": 1.0, "diffuse_reflectance": 0.4}, False),
]


@pytest.mark.parametrize("plugin,mi_params,params,below", DELTA_CASES,
                         ids=[c[0] for c in DELTA_CASES])
def test_sample_weight_matches_mitsuba(mi, plugin, mi_params, params, below):
    """sample(): the same direction, pdf and Mueller weight as Mitsuba for the same random
    numbers (u1 = 0 picks reflection, 0.999 transmission), over a grid of incident
    directions, including Brewster's angle, grazing light and light from the inside."""
    bsdf = mi.load_dict({"type": plugin, **mi_params})
    ctx = mi.BSDFContext()
    wi = np.concatenate([DIRS, -DIRS]) if below else DIRS
    n = len(wi)
    worst, compared = 0.0, 0
    for u1 in (0.0, 0.999):
        bs = _call(plugin, "sample", _surfaces(wi), np.full(n, u1, f32),
                   np.full((n, 2), 0.5, f32), **params)
        ours = _matrices(bs["weight"], n)
        for i in range(n):
            mbs, mw = bsdf.sample(ctx, _mi_si(mi, wi[i]), u1, [0.5, 0.5])
            if mbs.pdf == 0.0:
                assert bs["pdf"][i] == 0.0 or np.abs(ours[i]).max() == 0.0
                continue
            np.testing.assert_allclose(np.asarray(bs["wo"][i]), np.array(mbs.wo), atol=2e-6)
            assert bs["pdf"][i] == pytest.approx(mbs.pdf, rel=1e-5, abs=1e-7)
            theirs = _mi_matrix(mw)
            err = _rel_err(ours[i], theirs)
            assert err < 5e-5, (plugin, wi[i], u1, ours[i], theirs)
            worst, compared = max(worst, err), compared + 1
    assert compared >= n  # both lobes were reached
    print(f"{plugin}: {compared} samples, max |dM| / max(1, M00) = {worst:.2e}")


ROUGH_CASES = [
    ("roughconductor",
     {"distribution": "ggx", "alpha_u": 0.2, "alpha_v": 0.35, "eta": 0.2, "k": 3.9},
     {"distribution": 0, "alpha": 0.2, "alpha_v": 0.35, "eta": 0.2, "k": 3.9}, 5e-6),
    ("roughdielectric", {"distribution": "ggx", "alpha": 0.3, "int_ior": 1.5, "ext_ior": 1.0},
     {"distribution": 0, "alpha": 0.3, "int_ior": 1.5, "ext_ior": 1.0}, 1e-5),
    ("diffuse", {"reflectance": 0.6}, {"reflectance": 0.6}, 1e-6),
    ("plastic", {"int_ior": 1.5, "ext_ior": 1.0, "diffuse_reflectance": 0.4},
     {"int_ior": 1.5, "ext_ior": 1.0, "diffuse_reflectance": 0.4}, 1e-6),
]
EVAL_DIRS = _directions([5, 30, 60, 80], [0.3, 2.0, -1.2])


@pytest.mark.parametrize("plugin,mi_params,params,tol", ROUGH_CASES,
                         ids=[c[0] for c in ROUGH_CASES])
def test_eval_matches_mitsuba(mi, plugin, mi_params, params, tol):
    """eval(): Mitsuba's Mueller matrix for every pair of a direction grid (reflection, and
    transmission for roughdielectric): roughconductor's microfacet Fresnel matrix turned from
    the s/p basis of the microfacet, and depolarizers elsewhere."""
    bsdf = mi.load_dict({"type": plugin, **mi_params})
    ctx = mi.BSDFContext()
    wi = np.repeat(EVAL_DIRS, len(EVAL_DIRS), axis=0)
    wo = np.tile(EVAL_DIRS, (len(EVAL_DIRS), 1))
    if plugin == "roughdielectric":
        wi, wo = np.concatenate([wi, wi]), np.concatenate([wo, wo * [1, 1, -1]])
    n = len(wi)
    ours = _matrices(_call(plugin, "eval", _surfaces(wi), wo.astype(f32), **params), n)
    worst = 0.0
    for i in range(n):
        theirs = _mi_matrix(bsdf.eval(ctx, _mi_si(mi, wi[i]), [float(x) for x in wo[i]]))
        err = _rel_err(ours[i], theirs)
        assert err < tol, (plugin, wi[i], wo[i], ours[i], theirs)
        worst = max(worst, err)
    if plugin != "roughconductor":  # a depolarizer: only the intensity entry
        assert np.abs(ours.reshape(n, 16)[:, 1:]).max() == 0.0
    print(f"{plugin}: {n} pairs, max |dM| / max(1, M00) = {worst:.2e}")


@pytest.mark.parametrize("plugin,mi_params,params,tol", ROUGH_CASES[:2],
                         ids=[c[0] for c in ROUGH_CASES[:2]])
def test_rough_sample_weight_matches_mitsuba(mi, plugin, mi_params, params, tol):
    """sample() of the rough BSDFs: the visible-normal samplers map random numbers
    differently, so the weight of each of our samples is compared with Mitsuba's
    eval / pdf at the same direction (what Mitsuba's own weight equals)."""
    check_sample_weights(mi, plugin, mi_params, params, tol, EVAL_DIRS)


def check_sample_weights(mi, plugin: str, mi_params: dict, params: dict, tol: float,
                         dirs: np.ndarray) -> None:
    """Each of 16 samples per direction of ``dirs``: its pdf is Mitsuba's pdf() of its
    direction, its weight Mitsuba's eval / pdf there."""
    bsdf = mi.load_dict({"type": plugin, **mi_params})
    ctx = mi.BSDFContext()
    gen = np.random.default_rng(7)
    wi = np.repeat(dirs, 16, axis=0)
    n = len(wi)
    bs = _call(plugin, "sample", _surfaces(wi), gen.random(n).astype(f32),
               gen.random((n, 2)).astype(f32), **params)
    ours = _matrices(bs["weight"], n)
    compared = 0
    for i in range(n):
        if bs["pdf"][i] <= 0.0:
            continue
        si, wo = _mi_si(mi, wi[i]), [float(x) for x in bs["wo"][i]]
        pdf = bsdf.pdf(ctx, si, wo)
        assert bs["pdf"][i] == pytest.approx(pdf, rel=1e-4)
        theirs = _mi_matrix(bsdf.eval(ctx, si, wo)) / pdf
        assert _rel_err(ours[i], theirs) < tol, (plugin, wi[i], wo, ours[i], theirs)
        compared += 1
    assert compared > n // 2


def test_roughplastic_depolarizes_as_mitsuba(mi):
    """roughplastic is a depolarizer in both (only the structure is compared here: this
    plugin kernel, compiled without a scene, computes its tables' integrals exactly at each
    call instead of interpolating Mitsuba's table; tests/test_tables.py compares values)."""
    bsdf = mi.load_dict({"type": "roughplastic", "distribution": "ggx", "alpha": 0.3})
    wi = np.repeat(EVAL_DIRS, len(EVAL_DIRS), axis=0)
    wo = np.tile(EVAL_DIRS, (len(EVAL_DIRS), 1))
    ours = _matrices(_call("roughplastic", "eval", _surfaces(wi), wo.astype(f32),
                           distribution=0, alpha=0.3), len(wi))
    for i in range(len(wi)):
        theirs = _mi_matrix(bsdf.eval(mi.BSDFContext(), _mi_si(mi, wi[i]),
                                      [float(x) for x in wo[i]]))
        assert np.abs(theirs.reshape(16)[1:]).max() == 0.0 and theirs[0, 0] > 0.0
        assert np.abs(ours[i].reshape(16)[1:]).max() == 0.0 and ours[i][0, 0] > 0.0


# A conductor and a glass plane under a white sky, seen near Brewster's angle by a camera
# rolled about its axis (S1 and S2 mix), with a polarizer sheet in front of part of the view
# and another one, unseen, between the conductor and the sky (the conductor's phase shift
# turns its diagonal light elliptical: S3).
STOKES_SCENE = """<scene version="3.0.0">
    <default name="spp" value="64"/>
    <integrator type="stokes">
        <integrator type="path"><integer name="max_depth" value="6"/></integrator>
    </integrator>
    <sensor type="perspective">
        <float name="fov" value="40"/>
        <transform name="to_world">
            <lookat origin="0, -4.5, 3" target="0, 0, 0" up="0.5, 0, 1"/>
        </transform>
        <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
        <film type="hdrfilm">
            <integer name="width" value="32"/><integer name="height" value="32"/>
            <rfilter type="box"/>
        </film>
    </sensor>
    <emitter type="constant"><rgb name="radiance" value="1, 1, 1"/></emitter>
    <shape type="rectangle">
        <transform name="to_world"><scale x="1" y="3"/><translate x="-1"/></transform>
        <bsdf type="conductor"><float name="eta" value="0.2"/><float name="k" value="3.9"/></bsdf>
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><scale x="1" y="3"/><translate x="1"/></transform>
        <bsdf type="dielectric"><float name="int_ior" value="1.5"/>
            <float name="ext_ior" value="1"/></bsdf>
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><scale x="0.6" y="0.6"/><rotate x="1" angle="56"/>
            <translate x="0.3" y="-2.5" z="1.55"/></transform>
        <bsdf type="polarizer"><float name="theta" value="30"/></bsdf>
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><scale x="1.6" y="3.5"/><translate x="-1.6" y="3.5" z="2.5"/>
        </transform>
        <bsdf type="polarizer"><float name="theta" value="45"/></bsdf>
    </shape>
</scene>"""


def _block_means(img: np.ndarray, blocks: int = 4) -> np.ndarray:
    h, w = img.shape
    return img.reshape(blocks, h // blocks, blocks, w // blocks).mean(axis=(1, 3))


def test_stokes_render_matches_mitsuba(mi, tmp_path):
    """The `stokes` integrator around `path`, rendered by rdsl (mono_polarized, 64 spp) and
    by Mitsuba (llvm_ad_mono_polarized, 256 spp): S0..S3 agree per 8x8-pixel block within
    the noise of the glass's reflect-or-refract choice (0.012; S0 reaches 1, |S2| 0.38 and
    |S3| 0.11 in this scene, so a frame or sign error is far outside that)."""
    from rdsl.runtime.render.renderer import load_scene

    path = tmp_path / "stokes.xml"
    path.write_text(STOKES_SCENE)
    scene = load_scene(path, variant="mono_polarized")
    names = scene.channel_names
    assert names == ["Y"] + [f"S{i}.{c}" for i in range(4) for c in "RGB"]
    img = scene.render(spp=64)
    np.testing.assert_array_equal(img[..., 0], img[..., 1])  # Y is S0
    np.testing.assert_array_equal(img[..., 1], img[..., 3])  # mono: R = G = B

    if "DRJIT_LIBLLVM_PATH" not in os.environ:
        # Dr.Jit left to find a libLLVM by itself may load an older one and crash the
        # process (it does with Debian 12's libLLVM 14/15): only the one it supports is used
        if not Path(LLVM).exists():
            pytest.skip(f"Mitsuba's LLVM variants need {LLVM} (Debian's libllvm19)")
        os.environ["DRJIT_LIBLLVM_PATH"] = LLVM
    try:
        mi.set_variant("llvm_ad_mono_polarized")
        ref = np.array(mi.render(mi.load_file(str(path)), spp=256))
    except Exception as e:  # noqa: BLE001 - no LLVM backend: no reference render
        pytest.skip(f"mitsuba llvm_ad_mono_polarized cannot render here: {e}")
    finally:
        mi.set_variant("scalar_spectral_polarized")
    assert ref.shape == img.shape  # Mitsuba's mono layout: Y, S0.R, S0.G, S0.B, ..., S3.B
    for i in range(4):
        ours = _block_means(img[..., names.index(f"S{i}.R")])
        theirs = _block_means(ref[..., 1 + 3 * i])
        np.testing.assert_allclose(ours, theirs, atol=0.012, err_msg=f"S{i}")
        print(f"S{i}: max block difference {np.abs(ours - theirs).max():.4f}")
    assert np.abs(_block_means(ref[..., 7])).max() > 0.15   # S2 present
    assert np.abs(_block_means(ref[..., 10])).max() > 0.05  # S3 present
