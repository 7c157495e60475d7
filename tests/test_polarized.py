"""The polarized variants (`mono_polarized`, `spectral_polarized`): Stokes vectors and Mueller
matrices, checked against closed forms.

1. Malus's law: two ideal linear polarizers (stdlib/mueller.rdsl's `polarizer_mueller`, the
   polarizer plugin's matrix) at relative angle t transmit I0 cos^2 t, I0 = 1/2 of
   unpolarized light; crossed ones transmit nothing.
2. A quarter-wave plate turns linear light at -45 degrees (a polarizer whose absorbing axis
   is turned 45 degrees from v towards u transmits along u - v) into circular light
   (|S3| = S0); a half-wave plate mirrors it to +45 degrees.
3. Paper fig. 4: a dielectric (or conductor) reflection between crossed polarizers makes
   light visible, with the intensity of the complex Fresnel amplitudes computed in numpy
   (Mitsuba 3.9's conventions: Verdet's sign of a_p, IOR n - i k).
6. The `stokes` integrator's errors and channels (against Mitsuba 3:
   tests/test_polarized_bsdfs_mitsuba.py and tests/test_polarized_mitsuba.py).
4. The lift rules: Mueller products against numpy; unpolarized builds hold no Mueller
   arithmetic; polarized-only operations get a diagnostic at the user's line.
5. Plugins: the polarizer halves light in unpolarized variants (as Mitsuba 3), and a scene
   using one in an unpolarized render warns saying so.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import rdsl
from _scenes import CBOX
from rdsl.compiler.build import Build
from rdsl.compiler.diagnostics import CompileError
from rdsl.compiler.driver import frontend, pipeline, run_passes
from rdsl.compiler.printer import print_module
from test_polarized_bsdfs_mitsuba import STOKES_SCENE

STDLIB = Path(rdsl.__file__).resolve().parent / "stdlib"
POLARIZED = ["mono_polarized", "spectral_polarized"]
f32 = np.float32

KERNELS = """
import mueller;
// unpolarized light of intensity 1 through polarizers at t1 then t2 (degrees), normal
// incidence on surfaces facing the sensor: the Stokes vector seen by the sensor
fn malus(t1: Float, t2: Float) -> Vec4 {
    var out = Vec4(0.0);
    if const polarized {
        let fwd = Vec3(0.0, 0.0, 1.0);
        let p1 = polarizer_mueller(fwd, t1 * deg_to_rad(), 1.0);
        let p2 = polarizer_mueller(fwd, t2 * deg_to_rad(), 1.0);
        out = stokes(p2 * p1 * Spectrum(1.0));
    }
    return out;
}
// a polarizer at 45 degrees, then a retarder (theta = 0, phase delta degrees)
fn plate(delta: Float) -> Vec4 {
    var out = Vec4(0.0);
    if const polarized {
        let fwd = Vec3(0.0, 0.0, 1.0);
        let p = polarizer_mueller(fwd, 45.0 * deg_to_rad(), 1.0);
        let r = retarder_mueller(fwd, 0.0, delta * deg_to_rad());
        out = stokes(r * p * Spectrum(1.0));
    }
    return out;
}
// a specular reflection (in the s/p basis) between polarizers at t and t + 90 degrees
fn crossed(t: Float, cos_i: Float, eta: Float, k: Float) -> Vec4 {
    var out = Vec4(0.0);
    if const polarized {
        let p1 = rotated_element(t * deg_to_rad(), linear_polarizer(1.0));
        let p2 = rotated_element((t + 90.0) * deg_to_rad(), linear_polarizer(1.0));
        let r = specular_reflection(cos_i, Unpolarized(eta), Unpolarized(k));
        out = stokes(p2 * r * p1 * Spectrum(1.0));
    }
    return out;
}
// the product of two general matrices: entries a + i and b - 2 i (row-major index i)
fn product(a: Float, b: Float) -> Vec4 {
    var out = Vec4(0.0);
    if const polarized {
        let x = mueller(a, a + 1.0, a + 2.0, a + 3.0, a + 4.0, a + 5.0, a + 6.0, a + 7.0,
                        a + 8.0, a + 9.0, a + 10.0, a + 11.0, a + 12.0, a + 13.0, a + 14.0,
                        a + 15.0);
        let y = mueller(b, b - 2.0, b - 4.0, b - 6.0, b - 8.0, b - 10.0, b - 12.0, b - 14.0,
                        b - 16.0, b - 18.0, b - 20.0, b - 22.0, b - 24.0, b - 26.0, b - 28.0,
                        b - 30.0);
        let m = x * y + Spectrum(2.0) - y;
        out = Vec4(mean(mueller_entry(m, 0, 0)), mean(mueller_entry(m, 1, 2)),
                   mean(mueller_entry(m, 3, 3)), mean(m));
    }
    return out;
}
// unpolarized light of intensity 1 through n elements, carried by a loop as the path
// tracer carries its throughput: the first `depol` are depolarizers of transmittance 1/2,
// the others ideal polarizers, the k-th turned by k * step degrees
fn chain(n: Int, depol: Int, step: Float) -> Vec4 {
    var out = Vec4(0.0);
    if const polarized {
        let fwd = Vec3(0.0, 0.0, 1.0);
        var t = Spectrum(1.0);
        var k = 0;
        while k < n {
            var m = depolarizer(Unpolarized(0.5));
            if k >= depol {
                m = polarizer_mueller(fwd, Float(k) * step * deg_to_rad(), 1.0);
            }
            t = m * t;
            k += 1;
        }
        out = stokes(t);
    }
    return out;
}
"""


@pytest.fixture(scope="module", params=POLARIZED)
def kern(request):
    return rdsl.jit(KERNELS, target="host", variant=request.param)


def test_malus_law_sweep(kern):
    t = np.linspace(0.0, 180.0, 37).astype(f32)
    for t1 in (0.0, 30.0, 117.0):
        s = kern.malus(np.full_like(t, t1), t1 + t)
        expect = 0.5 * np.cos(np.radians(t.astype(np.float64))) ** 2
        assert np.abs(s[:, 0] - expect).max() < 2e-6
        # the transmitted light is fully linearly polarized along the second polarizer
        np.testing.assert_allclose(np.hypot(s[:, 1], s[:, 2]), s[:, 0], atol=2e-6)
        np.testing.assert_allclose(s[:, 3], 0.0, atol=1e-7)


def test_crossed_polarizers_transmit_nothing(kern):
    t1 = np.array([0.0, 10.0, 45.0, 90.0, 133.0], f32)
    s = kern.malus(t1, t1 + 90.0)
    assert np.abs(s).max() < 1e-6
    aligned = kern.malus(t1, t1)
    np.testing.assert_allclose(aligned[:, 0], 0.5, rtol=1e-6)


def test_quarter_wave_plate_makes_circular_light(kern):
    s = kern.plate(np.array([90.0, 180.0, 0.0], f32))
    qwp, hwp, none = s
    assert abs(abs(qwp[3] / qwp[0]) - 1.0) < 1e-6  # S3 / S0 = +-1: circular
    assert abs(qwp[1]) < 1e-6 and abs(qwp[2]) < 1e-6
    assert qwp[3] / qwp[0] == pytest.approx(1.0, abs=1e-6)  # Mitsuba's retarder sign
    assert hwp[2] / hwp[0] == pytest.approx(1.0, abs=1e-6)  # -45 deg -> +45 deg
    assert none[2] / none[0] == pytest.approx(-1.0, abs=1e-6)


def test_loop_carried_matrix_widens_when_polarizers_appear(kern):
    """The lift pass assumes a loop-carried matrix keeps its initial value's zeros until the
    loop body shows otherwise: here the throughput is a scalar, then a depolarizer, and only
    from iteration `depol` on a full matrix.  Wrong assumptions would drop the polarization
    the polarizers build up; the result must follow Malus's law through the chain:
    I = 0.5^depol * 0.5 * cos^2(step)^(number of polarizers - 1), fully linearly polarized."""
    n = np.array([0, 1, 3, 3, 5, 6, 6], np.int32)
    depol = np.array([0, 0, 0, 2, 1, 3, 6], np.int32)
    step = np.array([10.0, 20.0, 30.0, 40.0, 25.0, 50.0, 5.0], f32)
    s = kern.chain(n, depol, step)
    polarizers = np.maximum(n - depol, 0)
    expect = 0.5 ** np.minimum(depol, n) * np.where(
        polarizers > 0, 0.5 * np.cos(np.radians(step.astype(np.float64))) ** (
            2 * np.maximum(polarizers - 1, 0)), 1.0)
    np.testing.assert_allclose(s[:, 0], expect, rtol=2e-6)
    linear = np.hypot(s[:, 1], s[:, 2])
    np.testing.assert_allclose(linear, np.where(polarizers > 0, s[:, 0], 0.0), atol=1e-6)
    np.testing.assert_allclose(s[:, 3], 0.0, atol=1e-7)


def _fresnel_amplitudes(cos_i: np.ndarray, eta: complex) -> tuple[np.ndarray, np.ndarray]:
    """Complex reflection amplitudes as Mitsuba 3.9: Verdet's sign for a_p (a_p = -a_s at
    normal incidence) and waves exp(+i omega t), so the IOR is n - i k and Im cos_t <= 0."""
    eta = eta.conjugate()
    ci = cos_i.astype(np.complex128)
    ct = np.sqrt(1 - (1 - ci * ci) / eta ** 2)
    ct = np.where(ct.imag > 0, ct.conjugate(), ct)
    a_s = (ci - eta * ct) / (ci + eta * ct)
    a_p = (eta * ci - ct) / (eta * ci + ct)
    return a_s, a_p


@pytest.mark.parametrize("eta,k", [(1.5, 0.0), (0.2, 3.9)])
def test_reflection_between_crossed_polarizers_is_visible(kern, eta, k):
    """Mitsuba 2 paper fig. 4: crossed polarizers at 45/135 degrees to the plane of incidence
    let the light through a reflection: I = (r_s + r_p - 2 Re(a_p conj(a_s))) / 8 (both
    polarizers given in the s/p basis of the reflection; with Verdet's a_p that includes
    normal incidence, where the mirror image turns +45 degrees into -45)."""
    cos_i = np.array([1.0, 0.8, 0.5, 0.2, 0.05], f32)
    n = len(cos_i)
    got = kern.crossed(np.full(n, 45.0, f32), cos_i, np.full(n, eta, f32), np.full(n, k, f32))
    a_s, a_p = _fresnel_amplitudes(cos_i.astype(np.float64), complex(eta, k))
    expect = (abs(a_s) ** 2 + abs(a_p) ** 2 - 2 * (a_p * np.conj(a_s)).real) / 8
    np.testing.assert_allclose(got[:, 0], expect, rtol=2e-4, atol=1e-6)
    assert (got[:, 0] > 1e-3).all()  # visible
    # with the polarizers along s and p instead, a reflection keeps them crossed
    aligned = kern.crossed(np.zeros(n, f32), cos_i, np.full(n, eta, f32), np.full(n, k, f32))
    assert np.abs(aligned[:, 0]).max() < 1e-6


def test_mueller_product_matches_numpy(kern):
    a, b = np.array([0.5, -1.25], f32), np.array([2.0, 0.75], f32)
    got = kern.product(a, b)
    for row, (x0, y0) in zip(got, zip(a, b)):
        x = (x0 + np.arange(16)).reshape(4, 4).astype(np.float64)
        y = (y0 - 2.0 * np.arange(16)).reshape(4, 4).astype(np.float64)
        m = x @ y + 2.0 * np.eye(4) - y
        np.testing.assert_allclose(row, [m[0, 0], m[1, 2], m[3, 3], m[0, 0]], rtol=1e-5)


# ---------------------------------------------------------------------- the IR


def _ir(path_or_src, variant: str, after: str = "lift") -> str:
    module = frontend(path_or_src)
    passes = pipeline(Build.of("scalar", variant))
    run_passes(module, passes, stop_after=after)
    return print_module(module)


def _count(text: str) -> int:
    return len(re.findall(r"^\s+%\S+ = ", text, re.MULTILINE))


@pytest.mark.parametrize("plugin", ["polarizer", "retarder", "conductor", "dielectric",
                                    "roughconductor", "diffuse"])
def test_unpolarized_builds_have_no_mueller_arithmetic(plugin):
    path = str(STDLIB / "bsdf" / f"{plugin}.rdsl")
    for variant in ("mono", "rgb", "spectral"):
        text = _ir(path, variant)
        assert "Mueller" not in text and "spec." not in text, variant
    for variant in POLARIZED:
        text = _ir(path, variant)
        assert "%Mueller" in text and "spec." not in text and "spectrum" not in text


def test_depolarizing_scene_compiles_to_the_mono_kernel(tmp_path):
    """A scene whose BSDFs all depolarize (the Cornell box: diffuse only) needs no Mueller
    arithmetic in mono_polarized: the zeros of the BSDF matrices, known in each plugin, survive
    the scene's BSDF dispatch, the BSDF sample struct and the path loop's throughput, and the
    Stokes frame rotations vanish.  The kernel must then be the mono kernel, op for op, and
    render the same image."""
    from collections import Counter

    from rdsl.compiler.driver import compile_kernels

    cbox = CBOX
    if not cbox.is_file():
        pytest.skip(f"{cbox} is not present")
    pytest.importorskip("rdsl.runtime.embree")
    ops, images = {}, {}
    for variant in ("mono", "mono_polarized"):
        scene = rdsl.load_scene(cbox, variant=variant, res=24)
        images[variant] = scene.render(spp=4, seed=3)
        module, _ = compile_kernels(scene.kernel_src, Build.of("scalar", variant),
                                    scene=scene.scene_spec)
        ops[variant] = Counter(i.op.value for i in module.functions["render_sample"].walk())
    assert sum(ops["mono"].values()) > 1000
    assert ops["mono_polarized"] == ops["mono"]
    np.testing.assert_array_equal(images["mono_polarized"], images["mono"])


def test_polarized_kernel_size():
    """The polarizer's sample kernel after optimize: polarized costs more, but known zeros
    are skipped (a dense 4x4 product chain would be far larger)."""
    path = str(STDLIB / "bsdf" / "polarizer.rdsl")
    sizes = {v: _count(_ir(path, v, None)) for v in ("mono", "mono_polarized")}
    assert sizes["mono"] < 40
    assert sizes["mono_polarized"] < 600


def test_polarized_only_operation_outside_polarized_is_a_diagnostic():
    src = "fn k(a: Float) -> Float {\n    let m = mueller(a, 0, 0, 0, 0, a, 0, 0, 0, 0, a, 0, " \
          "0, 0, 0, a);\n    return mean(m);\n}\n"
    for variant in ("rgb", "spectral"):
        with pytest.raises(CompileError) as e:
            rdsl.jit(src, target="host", variant=variant, filename="user.rdsl")
        text = str(e.value)
        assert "user.rdsl:2:" in text and "polarized" in text
    got = rdsl.jit(src, target="host", variant="mono_polarized").k(np.array([3.0], f32))
    assert got[0] == 3.0


def test_elementwise_op_on_a_mueller_matrix_is_a_diagnostic():
    src = """
import mueller;
fn k(a: Float) -> Float {
    var x = 0.0;
    if const polarized {
        let p = linear_polarizer(a);
        let q = sqrt(p);
        x = mean(q);
    }
    return x;
}
"""
    with pytest.raises(CompileError) as e:
        rdsl.jit(src, target="host", variant="mono_polarized", filename="user.rdsl")
    assert "user.rdsl:7:" in str(e.value) and "Mueller" in str(e.value)
    # u * identity is unpolarized: elementwise operations stay allowed there
    ok = "fn k(a: Float) -> Float { return mean(sqrt(Spectrum(a)) / Spectrum(2.0)); }"
    got = rdsl.jit(ok, target="host", variant="mono_polarized").k(np.array([16.0], f32))
    assert got[0] == 2.0


# ---------------------------------------------------------------------- plugins and scenes


def _weight00(bs) -> np.ndarray:
    w = bs["weight"]
    if isinstance(w, dict):
        w = w["m00"]
    return np.asarray(w).reshape(len(bs["pdf"]), -1)[:, 0]


def test_polarizer_plugin_in_unpolarized_and_polarized_variants():
    n = 4
    z = np.tile(np.array([0, 0, 1], f32), (n, 1))
    si = {"p": np.zeros((n, 3), f32), "n": z, "sh_n": z, "uv": np.zeros((n, 2), f32),
          "wi": z.copy(), "t": np.ones(n, f32), "valid": np.ones(n, bool)}
    u1, u2 = np.zeros(n, f32), np.zeros((n, 2), f32)
    path = str(STDLIB / "bsdf" / "polarizer.rdsl")
    for variant in ("rgb", "mono", "mono_polarized"):
        mod = rdsl.jit(path, target="host", variant=variant)
        extra = {}
        if variant.endswith("polarized"):  # a Spectrum parameter is a Mueller matrix
            extra["transmittance"] = {f"m{i}{j}": float(i == j) for i in range(4)
                                      for j in range(4)}
        bs = mod["polarizer.sample"](si, u1, u2, theta=30.0, **extra)
        np.testing.assert_allclose(_weight00(bs), 0.5, rtol=1e-6)  # I0 = 1/2, as Mitsuba
        np.testing.assert_allclose(np.asarray(bs["wo"]), -z)
        if variant.endswith("polarized"):  # the transmitted light: linear at 30 degrees
            s = [np.asarray(bs["weight"][f"m{i}0"]) for i in range(3)]
            np.testing.assert_allclose(np.hypot(s[1], s[2]), s[0], rtol=1e-5)


def test_polarizer_in_unpolarized_render_warns(tmp_path):
    from rdsl.runtime.render.renderer import load_scene

    xml = """<scene version="3.0.0">
    <integrator type="path"><integer name="max_depth" value="4"/></integrator>
    <sensor type="perspective"><float name="fov" value="30"/>
        <transform name="to_world"><lookat origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/>
        </transform>
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/>
        </film></sensor>
    <shape type="rectangle"><transform name="to_world"><translate z="1"/></transform>
        <bsdf type="polarizer"><float name="theta" value="20"/></bsdf></shape>
    <shape type="rectangle"><transform name="to_world"><scale value="4"/></transform>
        <emitter type="area"><rgb name="radiance" value="1, 1, 1"/></emitter></shape>
</scene>"""
    path = tmp_path / "pol.xml"
    path.write_text(xml)
    with pytest.warns(UserWarning, match=r"polarizer.*50%.*mono_polarized"):
        load_scene(path, variant="rgb")


MALUS_SCENE = """<scene version="3.0.0">
    <default name="theta" value="0"/>
    <default name="fov" value="1"/>
    <integrator type="path"><integer name="max_depth" value="4"/></integrator>
    <sensor type="perspective"><float name="fov" value="$fov"/>
        <transform name="to_world"><lookat origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/>
        </transform>
        <sampler type="independent"><integer name="sample_count" value="4"/></sampler>
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/>
            <rfilter type="box"/></film>
    </sensor>
    <shape type="rectangle"><transform name="to_world"><scale value="3"/><translate z="1"/>
        </transform><bsdf type="polarizer"><float name="theta" value="0"/></bsdf></shape>
    <shape type="rectangle"><transform name="to_world"><scale value="3"/><translate z="0.5"/>
        </transform><bsdf type="polarizer"><float name="theta" value="$theta"/></bsdf></shape>
    <shape type="rectangle"><transform name="to_world"><scale value="6"/></transform>
        <emitter type="area"><rgb name="radiance" value="1, 1, 1"/></emitter></shape>
</scene>"""


def test_malus_law_in_a_rendered_scene(tmp_path):
    """The path tracer through two polarizer sheets in front of a white area light: each
    pixel sees L = 1/2 cos^2 theta (the frames of both sheets and the camera rays differ,
    so this exercises the world-frame rotations of path.rdsl).  Malus's law is exact at
    normal incidence only: the polarizers' axes are projected for oblique rays (Korger et
    al., as Mitsuba 3.9), which at a 20 degree field of view changes L by up to 6%
    (test_stokes_render_matches_mitsuba covers that case), so the camera sees the sheets
    within 0.5 degrees of the normal."""
    from rdsl.runtime.render.renderer import load_scene

    path = tmp_path / "malus.xml"
    path.write_text(MALUS_SCENE)
    for theta in (0.0, 60.0, 90.0):
        img = load_scene(path, variant="mono_polarized", theta=str(theta)).render(spp=4)
        expect = 0.5 * np.cos(np.radians(theta)) ** 2
        np.testing.assert_allclose(img[..., 0], expect, atol=5e-5)


def test_stokes_integrator_in_unpolarized_variant_is_an_error(tmp_path):
    """Mitsuba 3 refuses the `stokes` integrator outside polarized variants; so does rdsl,
    at the integrator's line, saying why and what to do."""
    from rdsl.runtime.render.renderer import load_scene

    path = tmp_path / "stokes.xml"
    path.write_text(STOKES_SCENE)
    for variant in ("rgb", "mono", "spectral"):
        with pytest.raises(CompileError) as e:
            load_scene(path, variant=variant)
        text = str(e.value)
        assert "stokes.xml:3:" in text and f"`{variant}`" in text
        assert "mono_polarized" in text and "polarized mode" in text


def test_stokes_integrator_needs_one_nested_integrator(tmp_path):
    from rdsl.runtime.render.renderer import load_scene
    from rdsl.runtime.scene.errors import SceneError

    path = tmp_path / "bad.xml"
    path.write_text(STOKES_SCENE.replace(
        '<integrator type="path"><integer name="max_depth" value="6"/></integrator>', ""))
    with pytest.raises((SceneError, CompileError), match=r"stokes.*1 nested <integrator>"):
        load_scene(path, variant="mono_polarized")


def test_stokes_channels_in_spectral_polarized(tmp_path):
    """spectral_polarized writes the Stokes components as linear sRGB, R G B then S0..S3;
    S0 is the image itself."""
    from rdsl.runtime.render.renderer import load_scene

    path = tmp_path / "stokes.xml"
    path.write_text(STOKES_SCENE.replace('value="32"', 'value="8"'))
    scene = load_scene(path, variant="spectral_polarized")
    assert scene.channel_names == ["R", "G", "B"] + [f"S{i}.{c}" for i in range(4)
                                                      for c in "RGB"]
    img = scene.render(spp=4)
    np.testing.assert_allclose(img[..., 3:6], img[..., :3], rtol=1e-6, atol=1e-7)
    assert np.abs(img[..., 6:]).max() > 0.01  # polarized light somewhere
