"""Derivatives in the spectral variants, where a colour parameter holds what the kernel reads:
three sigmoid-polynomial coefficients and a scale (runtime/render/differentiable.py).

`scene.backward` against central differences of the rendered loss with common random numbers
(the same seed), one coefficient at a time with a step fitted to its size (c0 multiplies the
squared wavelength, ~2.5e5 nm^2), for a diffuse wall whose colour changes no sampling
decision; and forward mode against reverse mode on the same directional derivative (same
seed) for a rough conductor's alpha, which moves sampled directions (both use detached
sampling, as Mitsuba 3's prb does, so they estimate the same quantity)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import rdsl

SCENE = """<scene version="3.0.0">
<integrator type="path"><integer name="max_depth" value="4"/></integrator>
<sensor type="perspective"><float name="fov" value="40"/>
  <transform name="to_world"><lookat origin="0,0,5" target="0,0,0" up="0,1,0"/></transform>
  <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/>
    <rfilter type="gaussian"/></film>
  <sampler type="independent"><integer name="sample_count" value="8"/></sampler></sensor>
<shape type="sphere"><bsdf type="roughconductor" id="metal">
  <float name="alpha" value="0.3"/><string name="material" value="Au"/></bsdf></shape>
<shape type="rectangle"><transform name="to_world"><scale value="3"/><translate z="-1.5"/>
  </transform><bsdf type="diffuse" id="wall"><rgb name="reflectance" value="0.6, 0.3, 0.2"/>
  </bsdf></shape>
<emitter type="constant"><rgb name="radiance" value="0.5, 0.5, 0.5"/></emitter>
<shape type="sphere"><transform name="to_world"><translate x="2" y="2" z="3"/></transform>
  <emitter type="area"><rgb name="radiance" value="5, 5, 5"/></emitter></shape>
</scene>"""
STEPS = (1e-8, 1e-5, 1e-3, 1e-3)  # c0, c1, c2, scale


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    path = tmp_path_factory.mktemp("ad_spectral") / "scene.xml"
    path.write_text(SCENE)
    return rdsl.load_scene(path, variant="spectral")


def _weights(scene) -> np.ndarray:
    img = scene.render(seed=3)
    return np.random.default_rng(0).random(img.shape)


def test_colour_coefficients_match_central_differences(scene):
    w = _weights(scene)
    x0 = scene.params["wall.reflectance"].astype(np.float64)
    assert x0.shape == (4,) and x0[3] == 1.0  # coefficients of (0.6, 0.3, 0.2), scale 1
    grad = scene.backward(w, ["wall.reflectance.value"], seed=3)["wall.reflectance.value"]

    def loss(i: int, dx: float) -> float:
        x = x0.copy()
        x[i] += dx
        scene.params["wall.reflectance"] = x.astype(np.float32)
        return float((scene.render(seed=3).astype(np.float64) * w).sum())

    try:
        fd = [(loss(i, h) - loss(i, -h)) / (2 * h) for i, h in enumerate(STEPS)]
    finally:
        scene.params["wall.reflectance"] = x0.astype(np.float32)
    assert np.all(np.abs(fd) > 1.0), fd  # every coefficient moves the image
    np.testing.assert_allclose(grad, fd, rtol=2e-3)


def test_forward_and_reverse_agree_on_alpha(scene):
    w = _weights(scene)
    grad = scene.backward(w, ["metal.alpha"], seed=3)["metal.alpha"]
    _, d_img = scene.render_forward("metal.alpha", seed=3)
    jvp = float((d_img.astype(np.float64) * w).sum())
    assert abs(jvp) > 1e-3
    np.testing.assert_allclose(grad[0], jvp, rtol=1e-4)


@pytest.mark.parametrize("variant", ["mono_polarized", "spectral_polarized"])
def test_polarized_variants_forward_and_reverse_agree(tmp_path, variant):
    # a polarized kernel carries Mueller matrices; the film takes their intensity, and both
    # modes differentiate through the conductor's polarized Fresnel term and the wall
    path = tmp_path / "scene.xml"
    path.write_text(SCENE)
    scene = rdsl.load_scene(path, variant=variant)
    w = _weights(scene)
    names = ["metal.alpha", "wall.reflectance.value"]
    grads = scene.backward(w, names, seed=3)
    rng = np.random.default_rng(2)
    for name in names:
        t = rng.uniform(0.5, 1.0, scene.params[name].size).astype(np.float32)
        _, d_img = scene.render_forward(name, seed=3, tangent=t)
        jvp = float((d_img.astype(np.float64) * w).sum())
        assert abs(jvp) > 1e-3, name
        np.testing.assert_allclose(float(np.dot(grads[name], t)), jvp, rtol=1e-4,
                                   err_msg=name)
