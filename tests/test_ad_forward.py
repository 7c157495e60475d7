"""Forward-mode automatic differentiation (compiler/passes/ad_forward.py): Jacobian-vector
products of kernels against central finite differences in float64 (numpy) and float32
(the kernel itself), and derivatives of rendered images against finite differences with
common random numbers (the same seed, so the same paths)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import rdsl
from rdsl.compiler.build import Build
from rdsl.compiler.diagnostics import CompileError

from _scenes import CBOX

needs_cbox = pytest.mark.skipif(not CBOX.is_file(), reason=f"needs {CBOX}")

SRC = """
fn k(x: Float, y: Float) -> Float {
    var acc = 0.0;
    for i in 0..3 { acc = acc + sin(x) * y + Float(i) * exp(0.3 * x * y); }
    if x > 0.5 { acc = acc * log(x + 2.0) + cos(y); }
    let z = clamp(x / y, 0.05, 0.95);
    return acc / sqrt(y) + pow(x, y) + atan2(y, x) + acos(z) + max(x, 0.6) * tan(0.2 * y)
        + detach(x) * 7.0 + asin(z) * exp2(y) - log2(y + 1.0) + erf(x - y);
}
"""


def reference(x, y):
    """The same function in float64 numpy (detach: a constant)."""
    from scipy.special import erf

    acc = np.zeros_like(x)
    for i in range(3):
        acc = acc + np.sin(x) * y + i * np.exp(0.3 * x * y)
    acc = np.where(x > 0.5, acc * np.log(x + 2.0) + np.cos(y), acc)
    z = np.clip(x / y, 0.05, 0.95)
    return (acc / np.sqrt(y) + x ** y + np.arctan2(y, x) + np.arccos(z)
            + np.maximum(x, 0.6) * np.tan(0.2 * y) + np.arcsin(z) * np.exp2(y)
            - np.log2(y + 1.0) + erf(x - y))


@pytest.mark.parametrize("target", ["scalar", "avx2"])
def test_jvp_matches_finite_differences(target):
    rng = np.random.default_rng(5)
    x = rng.uniform(0.1, 1.5, 64).astype(np.float32)
    y = rng.uniform(0.3, 2.5, 64).astype(np.float32)
    dx = rng.uniform(-1, 1, 64).astype(np.float32)
    dy = rng.uniform(-1, 1, 64).astype(np.float32)
    mod = rdsl.jit(SRC, build=Build.of(target, "rgb", ad="forward"))
    value, tangent = mod.k(x, y, dx, dy)
    plain = rdsl.jit(SRC, build=Build.of(target, "rgb")).k(x, y)
    np.testing.assert_array_equal(value, plain)  # the value is the plain kernel's, exactly
    X, Y = x.astype(np.float64), y.astype(np.float64)
    h = 1e-6
    fd = (reference(X + h * dx, Y + h * dy) - reference(X - h * dx, Y - h * dy)) / (2 * h)
    # the detached term contributes nothing; away from the kinks (clamp, max, x = 0.5)
    z = X / Y
    smooth = (np.abs(X - 0.5) > 1e-3) & (np.abs(z - 0.05) > 1e-3) & (np.abs(z - 0.95) > 1e-3) \
        & (np.abs(X - 0.6) > 1e-3)
    assert smooth.sum() > 50
    np.testing.assert_allclose(tangent[smooth], fd[smooth], rtol=2e-4, atol=2e-4)


def test_without_ad_derivative_is_zero_and_detach_is_the_value():
    src = "fn k(x: Float) -> Float { return derivative(x * x) + detach(x) * 2.0; }"
    out = rdsl.jit(src, target="scalar").k(np.float32([1.5, -2.0]))
    np.testing.assert_array_equal(out, [3.0, -4.0])


def test_jvp_of_functions_computed_through_their_bits():
    """rsqrt and erfinv reduce their argument through its bits (no derivative there): their
    tangents come from the analytic partials (rsqrt_d0, erfinv_d0), not from the code."""
    from scipy.special import erfinv

    src = "fn k(x: Float) -> Float { return rsqrt(x) + erfinv(0.5 * x - 0.3); }"
    x = np.linspace(0.05, 2.5, 200).astype(np.float32)
    dx = np.ones_like(x)
    _, tangent = rdsl.jit(src, build=Build.of("scalar", "rgb", ad="forward")).k(x, dx)
    X = x.astype(np.float64)
    exact = -0.5 * X**-1.5 + 0.5 * np.sqrt(np.pi) / 2 * np.exp(erfinv(0.5 * X - 0.3) ** 2)
    np.testing.assert_allclose(tangent, exact, rtol=1e-5)


def _fd_image(scene, name, h, seed):
    base = scene.params[name]
    scene.params[name] = base + h
    plus = scene.render(seed=seed)
    scene.params[name] = base - h
    minus = scene.render(seed=seed)
    scene.params[name] = base
    return (plus - minus) / (2 * h)


@needs_cbox
@pytest.mark.parametrize("variant, name, h", [
    ("rgb", "red.reflectance.value", 0.01),
    ("rgb", "light.emitter.radiance.value", 0.5),
    ("mono", "white.reflectance.value", 0.002),
])
def test_render_forward_matches_finite_differences(variant, name, h):
    """max_depth 4 < rr_depth: no Russian roulette, so a parameter change keeps every path
    and the central difference of two renders (one seed) is the derivative of the same
    estimate, to float32 rounding."""
    scene = rdsl.load_scene(CBOX, variant=variant, res=24, spp=8, max_depth=4)
    img, d_img = scene.render_forward(name, seed=3)
    assert img.shape == d_img.shape
    np.testing.assert_array_equal(img, scene.render(seed=3))
    fd = _fd_image(scene, name, h, 3)
    scale = np.abs(fd).max()
    assert scale > 0
    np.testing.assert_allclose(d_img, fd, atol=2e-3 * scale)
    np.testing.assert_allclose(d_img.sum(), fd.sum(), rtol=1e-4)


@needs_cbox
def test_params_and_render_forward_mistakes():
    scene = rdsl.load_scene(CBOX, res=8, spp=1)
    assert "red.reflectance" in scene.params and "path.max_depth" in scene.params
    with pytest.raises(CompileError, match="no parameter `red.albedo`.*red.reflectance.value"):
        scene.render_forward("red.albedo")
    with pytest.raises(ValueError, match="holds 3 value"):
        scene.params["red.reflectance"] = [0.1, 0.2]
    with pytest.raises(ValueError, match="tangent of `red.reflectance` has 3"):
        scene.render_forward("red.reflectance", tangent=[1.0, 0.0])
    with pytest.raises(ValueError, match="`red.reflectance`: expected a number or an array "
                                         "of numbers, got 'red'"):
        scene.params["red.reflectance"] = "red"
    # the integrator's Int and Bool params are whole numbers (a bounce count of 2.5 was
    # truncated by the kernel's cast); they stay as they were
    for name, bad in (("path.max_depth", 2.5), ("path.rr_depth", float("nan"))):
        before = scene.params[name].copy()
        with pytest.raises(ValueError, match=f"`{name}` is a whole-number setting"):
            scene.params[name] = bad
        np.testing.assert_array_equal(scene.params[name], before)
    scene.params["path.max_depth"] = 3
    assert scene.params["path.max_depth"][0] == 3
    spectral = rdsl.load_scene(CBOX, variant="spectral", res=8, spp=1)
    assert spectral.params["red.reflectance"].shape == (4,)
    with pytest.raises(ValueError, match="holds 4 value.*coefficients and a scale"):
        spectral.params["red.reflectance"] = [0.1, 0.2, 0.3]


@needs_cbox
def test_assigning_a_parameter_renders_without_compiling_again():
    scene = rdsl.load_scene(CBOX, res=16, spp=4, max_depth=3)
    before = scene.render(seed=1)
    scene.params["light.emitter.radiance"] = scene.params["light.emitter.radiance"] * 2
    doubled = scene.render(seed=1)
    compiled = scene.compile()
    scene.params["light.emitter.radiance"] = scene.params["light.emitter.radiance"] / 2
    again = scene.render(seed=1)
    assert scene.compile() is compiled  # one generic kernel served both values
    np.testing.assert_allclose(doubled, 2 * before, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(again, before, rtol=1e-6, atol=1e-7)


def test_adam_steps_towards_the_minimum():
    opt = rdsl.optim.Adam(lr=0.1)
    opt["x"] = [3.0, -2.0]
    for _ in range(200):
        opt.step({"x": 2 * (opt["x"] - np.float32([1.0, 0.5]))})
    np.testing.assert_allclose(opt["x"], [1.0, 0.5], atol=0.02)
    with pytest.raises(KeyError, match="no gradient for `x`"):
        opt.step({})
    with pytest.raises(ValueError, match="learning rate"):
        rdsl.optim.Adam(lr=0.0)


@needs_cbox
def test_albedo_example_recovers_the_walls():
    """examples/inverse/albedo.py at a small size: the recovered albedos are within 4% of the
    truth (vector norm; the dominant components within 3%) from a grey start."""
    import importlib.util

    path = Path(__file__).resolve().parents[1] / "examples" / "inverse" / "albedo.py"
    spec = importlib.util.spec_from_file_location("albedo_example", path)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    r = example.recover(res=32, spp=32, iterations=80, log=lambda line: None)
    for wall, channel in (("red.reflectance", 0), ("green.reflectance", 1)):
        got, truth = r[wall], r[f"truth.{wall}"]
        assert np.linalg.norm(got - truth) / np.linalg.norm(truth) < 0.04, (wall, got, truth)
        assert abs(got[channel] - truth[channel]) / truth[channel] < 0.03, (wall, got, truth)


def test_a_parameter_read_by_a_table_cannot_change_at_run_time(tmp_path):
    """roughplastic's alpha feeds its precomputed coating table: assigning it is a clear
    error (not a silently stale table); its colours change freely."""
    text = CBOX.read_text().replace(
        '<bsdf type="diffuse" id="red">',
        '<bsdf type="roughplastic" id="red"><float name="alpha" value="0.2"/>').replace(
        '<rgb name="reflectance" value="0.570068', '<rgb name="diffuse_reflectance" '
        'value="0.570068')
    (tmp_path / "cbox.xml").write_text(text)
    scene = rdsl.load_scene(tmp_path / "cbox.xml", res=8, spp=1)
    scene.params["red.diffuse_reflectance"] = [0.5, 0.1, 0.1]
    assert np.isfinite(scene.render()).all()
    with pytest.raises(CompileError, match="read by the precomputed table"):
        scene.params["red.alpha"] = 0.3
