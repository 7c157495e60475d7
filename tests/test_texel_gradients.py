"""Gradients with respect to a bitmap's texels (``<id>.data``): ``scene.backward`` against
central finite differences with common random numbers, the same with one thread and with
two (the texel gradient rows per thread), and the errors of a wrong use."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
import rdsl
from rdsl.compiler.diagnostics import CompileError

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "inverse" / "texture.py"
TEXELS = "wall_texture.data"


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    spec = importlib.util.spec_from_file_location("inverse_texture", EXAMPLE)
    ex = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ex)
    path = ex.textured_cbox(tmp_path_factory.mktemp("tex"))
    return rdsl.load_scene(path, res=24, spp=2, max_depth=3), ex.truth_texture()


def test_texels_read_and_assign(scene):
    s, truth = scene
    np.testing.assert_array_equal(s.params[TEXELS], truth)
    img = s.render(seed=0)
    s.params[TEXELS] = truth * 0.5  # the wall is diffuse and lit directly: darker
    darker = s.render(seed=0)
    s.params[TEXELS] = truth
    assert darker.sum() < img.sum()
    np.testing.assert_array_equal(s.render(seed=0), img)  # back, no stale state


def test_texel_gradient_matches_central_differences(scene):
    s, truth = scene
    w = np.random.default_rng(0).standard_normal((24, 24, 3))
    g = s.backward(w, [TEXELS, "red.reflectance"], seed=3)
    assert g[TEXELS].shape == truth.shape
    d = np.zeros_like(truth)
    d[20:40, 16:48] = 1.0  # a block of texels, the channels in other proportions
    d[..., 1] *= -0.5
    h = 0.02
    s.params[TEXELS] = truth + h * d
    plus = float(np.sum(w * s.render(seed=3)))
    s.params[TEXELS] = truth - h * d
    minus = float(np.sum(w * s.render(seed=3)))
    s.params[TEXELS] = truth
    fd = (plus - minus) / (2 * h)  # the image is close to linear in the texels
    assert abs(fd) > 1e-3
    np.testing.assert_allclose(float(np.sum(g[TEXELS] * d)), fd, rtol=1e-3)
    one = s.backward(w, [TEXELS], seed=3, threads=1)[TEXELS]
    np.testing.assert_allclose(one, g[TEXELS], rtol=1e-5, atol=1e-7)


def test_texel_errors(scene):
    s, _ = scene
    with pytest.raises(ValueError, match=r"texels of shape \(64, 64, 3\)"):
        s.params[TEXELS] = np.zeros((32, 32, 3))
    with pytest.raises(CompileError, match="use scene.backward"):
        s.render_forward(TEXELS)
    with pytest.raises(CompileError, match="wall_texture.data"):
        s.backward(np.zeros((24, 24, 3)), ["wall_texture.dat"])
