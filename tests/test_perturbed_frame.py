"""The perturbed shading frame of `normalmap` and `bumpmap` (stdlib/render/integrator.rdsl:
`perturbed_interaction` and the checks of `bsdf_eval`, `bsdf_pdf`, `bsdf_sample`), called
through the integrator's own functions on a one-BSDF scene: eval and pdf against Mitsuba 3's
`normalmap` BSDF (scalar_rgb, a 1 x 1 raw bitmap holding the normal) at the same shading
point, with its options on and off; the chi-square of the sampled directions against pdf;
the sample's weight against eval / pdf."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import rdsl
from _mitsuba_render import mitsuba_variant
from rdsl.core.scene_spec import Instance, SceneSpec, SpectrumValue
from rdsl.runtime.testkit.chi2 import chi2_directions

f32 = np.float32

SOURCE = """import render.integrator;
import bsdf.diffuse;
import bsdf.roughconductor;

// a shading point with the identity frame, perturbed to normal n
fn perturbed_at(wi: Vec3, pn: Vec4) -> Interaction {
    let z = Vec3(0.0, 0.0, 1.0);
    let si = Surface { p: Vec3(0.0), n: z, sh_n: z, uv: Vec2(0.5, 0.5), wi: wi, t: 1.0,
                       valid: true, prim: -1, bary: Vec2(0.0) };
    let it = Interaction { si: si, frame: Frame { s: Vec3(1.0, 0.0, 0.0), t: Vec3(0.0, 1.0, 0.0),
                                                  n: z },
                           ng: z, shape: 0, bsdf: 0, emitter: -1, dp_du: Vec3(1.0, 0.0, 0.0),
                           dp_dv: Vec3(0.0, 1.0, 0.0), perturbed: false, shadowing: false };
    return perturbed_interaction(it, pn);
}

fn p_eval(wi: Vec3, wo: Vec3, pn: Vec4, F: [Float], I: [Int]) -> Spectrum {
    let it = perturbed_at(wi, pn);
    return bsdf_eval(SCENE, it, to_local(it.frame, wo));
}

fn p_pdf(wi: Vec3, wo: Vec3, pn: Vec4, F: [Float], I: [Int]) -> Float {
    let it = perturbed_at(wi, pn);
    return bsdf_pdf(SCENE, it, to_local(it.frame, wo));
}

fn p_sample(wi: Vec3, u1: Float, u2: Vec2, pn: Vec4, F: [Float], I: [Int]) -> BsdfSample {
    let it = perturbed_at(wi, pn);
    var bs = bsdf_sample(SCENE, it, u1, u2);
    bs.wo = to_world(it.frame, bs.wo);
    return bs;
}
"""



def _scene_literal() -> str:
    """A `Scene` whose buffers are the kernels' dummies F and I, whatever buffers the
    stdlib's `Scene` declares."""
    text = (Path(rdsl.__file__).resolve().parent / "stdlib" / "render"
            / "integrator.rdsl").read_text()
    body = re.search(r"struct Scene \{(.*?)\n\}", text, re.S).group(1)
    buffers = re.findall(r"(\w+): \[(Float|Int)\]", body)
    fields = ", ".join(f"{n}: {'F' if t == 'Float' else 'I'}" for n, t in buffers)
    return f"Scene {{ {fields}, nemitter: 0, env: -1, up: Vec3(0.0, 0.0, 1.0) }}"


# a struct holding buffers cannot be returned: the scene is built where it is used
SOURCE = SOURCE.replace("SCENE", _scene_literal())

NESTED = {
    "roughconductor": ({"type": "roughconductor", "alpha": 0.3, "distribution": "ggx",
                        "eta": {"type": "rgb", "value": [0.2, 0.9, 1.1]},
                        "k": {"type": "rgb", "value": [3.9, 2.4, 2.2]}},
                       Instance("roughconductor", {"alpha": 0.3, "distribution": 0,
                                                   "eta": SpectrumValue((0.2, 0.9, 1.1)),
                                                   "k": SpectrumValue((3.9, 2.4, 2.2))})),
    "diffuse": ({"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.7, 0.5, 0.3]}},
                Instance("diffuse", {"reflectance": SpectrumValue((0.7, 0.5, 0.3))})),
}
NORMALS = [(0.6, 0.5, 0.9), (0.2, 0.7, 0.8), (0.5, 0.5, 1.0)]  # texel colours, n = 2c - 1
# (flip_invalid_normals, use_shadowing_function, in a twosided)
FLAGS = [(True, True, False), (False, False, False), (True, False, False), (True, True, True),
         (False, True, True)]


@pytest.fixture(scope="module", params=sorted(NESTED))
def kernels(request):
    inst = NESTED[request.param][1]
    return request.param, rdsl.jit(SOURCE, target="host", variant="rgb",
                                   scene=SceneSpec(bsdfs=[inst]))


def _sph(n: int, seed: int) -> np.ndarray:
    g = np.random.default_rng(seed)
    z = g.uniform(-1, 1, n)
    phi = g.uniform(0, 2 * np.pi, n)
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], -1).astype(f32)


def _pn(colour, flags, n: int) -> np.ndarray:
    c = 2 * np.asarray(colour, f32) - 1
    code = 4 + int(flags[0]) + 2 * int(flags[1]) + 8 * int(flags[2])
    return np.tile(np.array([*c, code], f32), (n, 1))


def _bufs():
    return np.zeros(4, f32), np.zeros(4, np.int32)


def _mitsuba(mi, nested: dict, colour, flags):
    bitmap = mi.Bitmap(np.asarray(colour, np.float32).reshape(1, 1, 3))
    bsdf = {"type": "normalmap", "bsdf": nested,
            "normalmap": {"type": "bitmap", "bitmap": bitmap, "raw": True,
                          "filter_type": "nearest"},
            "flip_invalid_normals": flags[0], "use_shadowing_function": flags[1]}
    return mi.load_dict({"type": "twosided", "bsdf": bsdf} if flags[2] else bsdf)


@pytest.mark.parametrize("colour", NORMALS)
@pytest.mark.parametrize("flags", FLAGS)
def test_eval_and_pdf_match_mitsuba(kernels, colour, flags):
    name, mod = kernels
    n = 64
    wis = _sph(n, 1)
    wis[:, 2] = np.abs(wis[:, 2]) * np.where(np.arange(n) % 4 == 0, -1, 1)  # some from below
    wos = _sph(n, 2)
    pn = _pn(colour, flags, n)
    ours = np.asarray(mod["p_eval"](wis, wos, pn, *_bufs()))
    ours_pdf = np.asarray(mod["p_pdf"](wis, wos, pn, *_bufs()))
    with mitsuba_variant("scalar_rgb") as mi:
        bsdf = _mitsuba(mi, NESTED[name][0], colour, flags)
        ctx = mi.BSDFContext()
        theirs, theirs_pdf = [], []
        for wi, wo in zip(wis, wos):
            si = mi.SurfaceInteraction3f()
            si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
            si.n = mi.Vector3f(0, 0, 1)
            si.dp_du, si.dp_dv = mi.Vector3f(1, 0, 0), mi.Vector3f(0, 1, 0)
            si.uv = mi.Point2f(0.5, 0.5)
            si.wi = mi.Vector3f(*map(float, wi))
            w = mi.Vector3f(*map(float, wo))
            theirs.append(np.array(bsdf.eval(ctx, si, w)))
            theirs_pdf.append(float(bsdf.pdf(ctx, si, w)))
    theirs = np.array(theirs)
    assert (theirs > 0).any(axis=1).sum() > 10  # the cases are not all black
    np.testing.assert_allclose(ours, theirs, rtol=2e-3, atol=2e-5)
    np.testing.assert_allclose(ours_pdf, np.array(theirs_pdf), rtol=2e-3, atol=2e-5)


# a one-sided BSDF (FLAGS[0]) reflects nothing from below: only the two-sided one there
SAMPLING_CASES = [(t, f) for f in (FLAGS[0], FLAGS[3]) for t in (0.3, 1.0, 1.45, np.pi - 1.0)
                  if t < np.pi / 2 or f[2]]


@pytest.mark.parametrize(("theta", "flags"), SAMPLING_CASES)
def test_sampling_matches_pdf(kernels, theta, flags):
    """chi-square of sample() against pdf(), and weight == eval / pdf, in the unperturbed
    frame (the directions a path integrator sees)."""
    name, mod = kernels
    n = 200_000
    wi = np.array([np.sin(theta) * np.cos(0.4), np.sin(theta) * np.sin(0.4), np.cos(theta)], f32)
    g = np.random.default_rng(3)
    pn = _pn(NORMALS[0], flags, n)
    bs = mod["p_sample"](np.tile(wi, (n, 1)), g.random(n, dtype=f32), g.random((n, 2), dtype=f32),
                         pn, *_bufs())
    wo, pdf = np.asarray(bs["wo"]), np.asarray(bs["pdf"])
    valid = pdf > 0

    def pdf_of(d: np.ndarray) -> np.ndarray:
        m = len(d)
        return np.asarray(mod["p_pdf"](np.tile(wi, (m, 1)), d, _pn(NORMALS[0], flags, m),
                                       *_bufs()))

    assert chi2_directions(wo, valid, pdf_of, n) > 1e-3
    k = np.flatnonzero(valid)[:2000]
    f = np.asarray(mod["p_eval"](np.tile(wi, (len(k), 1)), wo[k], pn[k], *_bufs()))
    np.testing.assert_allclose(np.asarray(bs["weight"])[k], f / pdf[k][:, None], rtol=2e-3,
                               atol=1e-6)
    assert (np.asarray(bs["weight"])[k] <= 1.0 + 1e-4).all() or name == "diffuse"


TEXTURE_SOURCE = """import render.scene;
import texture.bitmap;
fn t_grad(si: Surface, T: [Float]) -> Vec2 { return scene_texture_eval_1_grad(0, si, T); }
fn t_rgb(si: Surface, T: [Float]) -> Vec3 { return scene_texture_eval_3(0, si, T); }
"""
TO_UV = np.array([[2.0, 0.5, 0.0, 0.1], [-0.3, 3.0, 0.0, 0.2], [0, 0, 1, 0], [0, 0, 0, 1]])


@pytest.mark.parametrize("wrap", ["repeat", "mirror", "clamp"])
@pytest.mark.parametrize("filt", ["bilinear", "nearest"])
def test_bitmap_gradient_and_rgb_match_mitsuba(wrap: str, filt: str):
    """The lookups a bumpmap (eval_1_grad: the luminance's uv gradient) and a normalmap
    (eval_3: linear RGB) make, against Mitsuba's bitmap at random uvs, with a to_uv
    transform, for every filter and wrap mode."""
    from rdsl.runtime.render.textures import BITMAP_FILTERS, BITMAP_WRAPS, _uv_rows

    img = np.random.default_rng(5).random((5, 7, 3)).astype(f32)
    inst = Instance("bitmap", {**_uv_rows(TO_UV), "offset": 0, "width": 7, "height": 5,
                               "filter": BITMAP_FILTERS[filt], "wrap": BITMAP_WRAPS[wrap],
                               "average": SpectrumValue((0.5, 0.5, 0.5)), "emitted": False,
                               "scale": 1.0})
    mod = rdsl.jit(TEXTURE_SOURCE, target="host", variant="rgb", scene=SceneSpec(textures=[inst]))
    n = 200
    uv = np.random.default_rng(6).uniform(-1.5, 2.5, (n, 2)).astype(f32)
    z = np.tile(np.array([0, 0, 1], f32), (n, 1))
    si = {"p": np.zeros((n, 3), f32), "n": z, "sh_n": z, "uv": uv, "wi": z,
          "t": np.ones(n, f32), "valid": np.ones(n, bool)}
    T = np.ascontiguousarray(img.reshape(-1))
    grad, rgb = np.asarray(mod["t_grad"](si, T)), np.asarray(mod["t_rgb"](si, T))
    with mitsuba_variant("scalar_rgb") as mi:
        tex = mi.load_dict({"type": "bitmap", "bitmap": mi.Bitmap(img), "raw": True,
                            "filter_type": filt, "wrap_mode": wrap,
                            "to_uv": mi.ScalarTransform4f(TO_UV.tolist())})
        want_grad, want_rgb = [], []
        for u, v in uv:
            s = mi.SurfaceInteraction3f()
            s.uv = mi.Point2f(float(u), float(v))
            want_grad.append(np.array(tex.eval_1_grad(s)))
            want_rgb.append(np.array(tex.eval_3(s)))
    np.testing.assert_allclose(rgb, np.array(want_rgb), rtol=1e-4, atol=1e-5)
    want = np.array(want_grad)
    if filt == "bilinear":
        assert np.abs(want).max() > 0.5  # a gradient worth comparing
    # a lookup within float rounding of a texel centre may fall in either cell
    close = np.isclose(grad, want, rtol=1e-3, atol=1e-3).all(axis=1)
    assert close.mean() > 0.97, (grad[~close][:5], want[~close][:5])
