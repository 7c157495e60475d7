"""The checks of an integrator plugin: it renders a small test scene, which has every kind of
surface and light an integrator meets (a diffuse floor, a rough conductor, a glass sphere,
an area light, a constant environment), with no NaN or infinite sample and no negative
radiance, for the given parameters and at extreme values of each; and the same seed gives
the same image.

An integrator's estimate has no closed form in general (an AO integrator's is not radiance),
so what it should converge to is the author's to test (tests/test_integrator_plugins.py
checks the example AO integrator against its closed form).  The scene is rendered with the
generic build, so every parameter case reuses one compiled kernel.
"""

from __future__ import annotations

import tempfile
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from .common import Options, finite_rows
from .harness import Declaration
from .report import FAIL, PASS, Row

SIZE, SPP = 24, 4
_SCENE = """<scene version="3.0.0">
    <integrator type="{name}">{props}
    </integrator>
    <sensor type="perspective">
        <float name="fov" value="45"/>
        <transform name="to_world"><lookat origin="0, 1.2, 4" target="0, 0.4, 0" up="0, 1, 0"/>
        </transform>
        <sampler type="independent"><integer name="sample_count" value="{spp}"/></sampler>
        <film type="hdrfilm"><integer name="width" value="{size}"/>
            <integer name="height" value="{size}"/><rfilter type="box"/></film>
    </sensor>
    <emitter type="constant"><rgb name="radiance" value="0.5"/></emitter>
    <shape type="rectangle">
        <transform name="to_world"><rotate x="1" angle="-90"/><scale value="3"/></transform>
    </shape>
    <shape type="sphere">
        <point name="center" x="-0.6" y="0.5" z="0"/><float name="radius" value="0.5"/>
        <bsdf type="roughconductor"><float name="alpha" value="0.2"/></bsdf>
    </shape>
    <shape type="sphere">
        <point name="center" x="0.6" y="0.5" z="0"/><float name="radius" value="0.5"/>
        <bsdf type="dielectric"/>
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><rotate x="1" angle="90"/><translate y="2.5"/></transform>
        <emitter type="area"><rgb name="radiance" value="4"/></emitter>
    </shape>
</scene>
"""


def _property(name: str, ptype: str, value: Any) -> str:
    if ptype == "Bool":
        return f'<boolean name="{name}" value="{str(bool(value)).lower()}"/>'
    if ptype in ("Int", "UInt", "UInt64"):
        return f'<integer name="{name}" value="{int(value)}"/>'
    if isinstance(value, tuple) and ptype.startswith("Vec"):
        return f'<vector name="{name}" x="{value[0]}" y="{value[1]}" z="{value[2]}"/>'
    if isinstance(value, tuple):
        return f'<rgb name="{name}" value="{", ".join(str(v) for v in value)}"/>'
    return f'<float name="{name}" value="{float(value)}"/>'


def _render(decl: Declaration, variant: str, target: Any, params: dict[str, Any],
            folder: Path, seed: int = 0) -> tuple[np.ndarray, int, int]:
    """The test scene's image, its count of NaN/Inf samples and its colour channels."""
    from ..render.renderer import load_scene

    types = {p.name: p.type for p in decl.params}
    props = "".join(f"\n        {_property(k, types[k], v)}" for k, v in params.items())
    path = folder / "scene.xml"
    path.write_text(_SCENE.format(name=decl.name, props=props, spp=SPP, size=SIZE))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the plugin may shadow a stdlib integrator
        scene = load_scene(path, variant=variant, target=target, specialize=False,
                           plugins=[decl.path])
        img = scene.render(seed=seed)
    return img, scene.nonfinite, 1 if scene.build.model.mono else 3


def check_integrator(decl: Declaration, variant: str, target: Any, opts: Options) -> list[Row]:
    """Every check of the integrator ``decl``, as table rows."""
    with tempfile.TemporaryDirectory(prefix="rdsl-test-plugin-") as tmp:
        folder = Path(tmp)

        def bad(params: dict[str, Any]) -> str:
            img, nonfinite, colours = _render(decl, variant, target, params, folder)
            if nonfinite or not np.all(np.isfinite(img)):
                return f"{nonfinite} NaN or infinite samples"
            if np.any(img[..., :colours] < 0):
                return "negative radiance"
            return ""

        what = f"{SIZE}x{SIZE} px, {SPP} spp"
        rows = finite_rows(decl, opts, bad, what)
        a = _render(decl, variant, target, opts.params, folder, seed=7)[0]
        b = _render(decl, variant, target, opts.params, folder, seed=7)[0]
        same = np.array_equal(a, b, equal_nan=True)
        rows.append(Row("deterministic", "given params", f"2 x {what}, seed 7",
                        "same image", PASS if same else FAIL,
                        "" if same else "two renders with one seed differ"))
    return rows
