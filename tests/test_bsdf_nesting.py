"""BSDF combinators nested to any depth: `twosided`, `blendbsdf` and `mask` inside one another
are one flattened `mixture` (stdlib/bsdf/mixture.rdsl, runtime/render/bsdfs.py).

Truths: eval and pdf of each nested BSDF equal the closed form built from its blend weights
and opacities over the same BSDFs used alone (mirrored from below inside a twosided);
sample() against pdf() (chi-square, with the discrete lobes and the mask's pass-through)
and its weight against eval / pdf; a render of nested diffuse BSDFs equals the render of the
one diffuse BSDF with the blended reflectance.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rdsl.runtime.embree")

import rdsl
from rdsl.core.scene_spec import SceneSpec
from rdsl.runtime.render.bsdfs import split_leaves
from rdsl.runtime.render.renderer import load_scene
from test_bsdf_plugins import chi2_directions, pdf_fn, rng, sample, surface, tile, wi_at
from test_scene_bsdfs import BLEND_SRC, OBLIQUE, Blend, scene_xml

f32 = np.float32

D = '<bsdf type="diffuse"><rgb name="reflectance" value="0.8, 0.5, 0.2"/></bsdf>'
RC = '<bsdf type="roughconductor"><float name="alpha" value="0.2"/></bsdf>'
P = '<bsdf type="plastic"><rgb name="diffuse_reflectance" value="0.3, 0.6, 0.4"/></bsdf>'
RED = '<bsdf type="diffuse"><rgb name="reflectance" value="0.9, 0.1, 0.1"/></bsdf>'
BLUE = '<bsdf type="diffuse"><rgb name="reflectance" value="0.1, 0.2, 0.9"/></bsdf>'
RD = '<bsdf type="roughdielectric"><float name="alpha" value="0.3"/></bsdf>'
LEAVES = {"D": D, "RC": RC, "P": P, "RED": RED, "BLUE": BLUE, "RD": RD}


def blend(w: float, a: str, b: str) -> str:
    return f'<bsdf type="blendbsdf"><float name="weight" value="{w}"/>{a}{b}</bsdf>'


def twosided(*kids: str) -> str:
    return f'<bsdf type="twosided">{"".join(kids)}</bsdf>'


def mask(o: float, kid: str) -> str:
    return f'<bsdf type="mask"><float name="opacity" value="{o}"/>{kid}</bsdf>'


# name -> (XML, {leaf: coefficient} from above, from below as (leaf, coefficient, mirrored),
#          pass-through probability)
NESTED = {
    "twosided(blend(D, RC))": (twosided(blend(0.3, D, RC)), {"D": 0.7, "RC": 0.3},
                               [("D", 0.7, True), ("RC", 0.3, True)], 0.0),
    "blend(blend(D, RC), P)": (blend(0.4, blend(0.25, D, RC), P),
                               {"D": 0.45, "RC": 0.15, "P": 0.4},
                               [("D", 0.45, False), ("RC", 0.15, False), ("P", 0.4, False)],
                               0.0),
    "mask(twosided(blend(D, RC)))": (mask(0.7, twosided(blend(0.5, D, RC))),
                                     {"D": 0.35, "RC": 0.35},
                                     [("D", 0.35, True), ("RC", 0.35, True)], 0.3),
    "twosided(RED, blend(BLUE, RC))": (twosided(RED, blend(0.6, BLUE, RC)), {"RED": 1.0},
                                       [("BLUE", 0.4, True), ("RC", 0.6, True)], 0.0),
    "blend(twosided(D), RD)": (blend(0.5, twosided(D), RD), {"D": 0.5, "RD": 0.5},
                               [("D", 0.5, True), ("RD", 0.5, False)], 0.0),
}


@pytest.fixture(scope="module")
def nested(tmp_path_factory):
    """One module whose scene BSDFs are the nested ones, then every leaf alone."""
    tmp = tmp_path_factory.mktemp("nested")
    bsdfs = [xml for xml, *_ in NESTED.values()] + list(LEAVES.values())
    body = "".join(f'<shape type="sphere"><point name="center" value="{3 * i}, 0, 0"/>{b}'
                   '</shape>' for i, b in enumerate(bsdfs))
    body += ('<shape type="rectangle"><transform name="to_world"><translate z="5"/>'
             '</transform><emitter type="area"><rgb name="radiance" value="1"/></emitter>'
             '</shape>')
    path = tmp / "nested.xml"
    path.write_text(scene_xml(body, OBLIQUE))
    top, leaves = split_leaves(load_scene(path).bsdfs)
    assert len(top) == len(bsdfs) + 1  # the emitter's own default BSDF last
    src = BLEND_SRC.replace("blend.", "blend_") + "import bsdf.roughdielectric;\n"
    mod = rdsl.jit(src, target="host", scene=SceneSpec(bsdfs=top, bsdf_leaves=leaves))
    ids = {name: k for k, name in enumerate([*NESTED, *LEAVES])}
    return mod, ids


def _directions(n: int, gen: np.random.Generator) -> np.ndarray:
    d = gen.normal(size=(n, 3))
    return (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(f32)


def _mirror(d: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(d * np.array([1, 1, -1], f32))


@pytest.mark.parametrize("name", list(NESTED))
def test_eval_and_pdf_are_the_blend_of_the_nested_bsdfs(nested, name):
    mod, ids = nested
    _, above, below, _ = NESTED[name]
    gen = rng("nested-eval", name)
    n = 4000
    wi, wo = _directions(n, gen), _directions(n, gen)
    wi[: n // 2, 2] = np.abs(wi[: n // 2, 2])  # half from above, half from below
    wi[n // 2:, 2] = -np.abs(wi[n // 2:, 2])
    up = wi[:, 2] >= 0

    def call(method: str, ident: str, wi_: np.ndarray, wo_: np.ndarray) -> np.ndarray:
        out = Blend(mod, ids[ident])[f"blend.{method}"](surface(wi_), wo_)
        return np.asarray(out, np.float64).reshape(n, -1)

    f_want, p_want = np.zeros((n, 3)), np.zeros((n, 1))
    terms = [(leaf, c, False, up) for leaf, c in above.items()]
    for leaf, c, mirrored, side in terms + [(*t, ~up) for t in below]:
        wi_, wo_ = (_mirror(wi), _mirror(wo)) if mirrored else (wi, wo)
        f_want += np.where(side[:, None], c * call("eval", leaf, wi_, wo_), 0.0)
        p_want += np.where(side[:, None], c * call("pdf", leaf, wi_, wo_), 0.0)
    np.testing.assert_allclose(call("eval", name, wi, wo), f_want, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(call("pdf", name, wi, wo), p_want, rtol=1e-5, atol=1e-6)
    assert f_want[up].max() > 0
    if any(mirrored for *_, mirrored in below):  # seen from below through a twosided
        assert f_want[~up].max() > 0


@pytest.mark.parametrize("name", list(NESTED))
@pytest.mark.parametrize("theta", [0.5, np.pi - 0.9])
def test_sample_matches_pdf_and_eval(nested, name, theta):
    mod, ids = nested
    null = NESTED[name][3]
    bsdf = Blend(mod, ids[name])
    n = 200_000
    wi = wi_at(theta)
    _, bs = sample(bsdf, "blend", wi, n, rng("nested-sample", name, theta))
    delta = bs["delta"].astype(bool)
    valid = (bs["pdf"] > 0) & ~delta
    # the discrete lobes: each distinct direction with its (constant) probability
    obs, prob = [], []
    dirs, inverse = np.unique(bs["wo"][delta], axis=0, return_inverse=True)
    for k, d in enumerate(dirs):
        pdfs = bs["pdf"][delta][inverse.ravel() == k]
        np.testing.assert_allclose(pdfs, pdfs[0], rtol=1e-5)
        obs.append(len(pdfs))
        prob.append(float(pdfs[0]))
        if np.allclose(d, -wi, atol=1e-6):  # the mask's pass-through
            np.testing.assert_allclose(prob[-1], null, rtol=1e-6)
    if null > 0:
        assert any(np.allclose(d, -wi, atol=1e-6) for d in dirs)
    p = chi2_directions(bs["wo"], valid, pdf_fn(bsdf, "blend", wi), n, delta_obs=obs,
                        delta_prob=prob, lower=True)
    assert p > 1e-3, p
    if not valid.any():  # one-sided BSDFs seen from below
        assert not any(m for *_, m in NESTED[name][2]) and wi[2] < 0
        return
    si = surface(tile(wi, int(valid.sum())))
    wo = np.ascontiguousarray(bs["wo"][valid])
    f = np.asarray(bsdf["blend.eval"](si, wo)).reshape(len(wo), -1)
    pdf = np.asarray(bsdf["blend.pdf"](si, wo))
    np.testing.assert_allclose(bs["pdf"][valid], pdf, rtol=1e-4)
    np.testing.assert_allclose(bs["weight"][valid], f / pdf[:, None], rtol=2e-3, atol=1e-6)


def test_nested_diffuse_blend_renders_as_the_blended_diffuse(tmp_path):
    """blend(0.4, blend(0.25, a, b), c) of diffuse BSDFs, inside twosided and seen from
    behind, is the diffuse BSDF of reflectance 0.45 a + 0.15 b + 0.4 c: the same paths, so
    the same image up to rounding."""
    a, b, c = np.array([0.8, 0.1, 0.3]), np.array([0.2, 0.9, 0.5]), np.array([0.5, 0.4, 0.9])

    def diffuse(r: np.ndarray) -> str:
        rgb = ", ".join(map(str, r))
        return f'<bsdf type="diffuse"><rgb name="reflectance" value="{rgb}"/></bsdf>'

    def render(bsdf: str) -> np.ndarray:
        # a patch turned away from the camera and lit from the camera's side
        body = (f'<shape type="rectangle"><transform name="to_world"><scale value="3"/>'
                f'<rotate x="1" angle="180"/></transform>{bsdf}</shape>'
                '<emitter type="constant"><rgb name="radiance" value="1.5"/></emitter>')
        path = tmp_path / "scene.xml"
        path.write_text(scene_xml(body, OBLIQUE, max_depth=3, res=8))
        scene = load_scene(path)
        return scene.render(spp=16, seed=5)

    nested = render(twosided(blend(0.4, blend(0.25, diffuse(a), diffuse(b)), diffuse(c))))
    flat = render(twosided(diffuse(0.45 * a + 0.15 * b + 0.4 * c)))
    assert flat.mean() > 0.1
    np.testing.assert_allclose(nested, flat, rtol=1e-4, atol=1e-5)
