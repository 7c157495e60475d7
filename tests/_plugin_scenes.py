"""Small scenes for the plugin-coverage tests (samplers, sensors, shapes, integrators), each
rendered by rdsl and by Mitsuba 3 with tests/_mitsuba_compare.py."""

from __future__ import annotations

from pathlib import Path

LOOKAT = '<transform name="to_world"><lookat origin="{o}" target="{t}" up="0, 1, 0"/></transform>'


def film(res: int = 32, height: int | None = None, rfilter: str = "box") -> str:
    return (f'<film type="hdrfilm"><integer name="width" value="{res}"/>'
            f'<integer name="height" value="{height or res}"/><rfilter type="{rfilter}"/></film>')


def perspective(origin: str = "0, 0, 4", target: str = "0, 0, 0", fov: float = 40,
                res: int = 32, extra: str = "") -> str:
    return (f'<sensor type="perspective"><float name="fov" value="{fov}"/>'
            f'{LOOKAT.format(o=origin, t=target)}{film(res)}{extra}</sensor>')


# a wall behind the origin, a sphere light out of the cameras' view, a dim environment
ROOM = """
  <shape type="rectangle">
    <transform name="to_world"><scale value="3"/><translate z="-1"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.8, 0.6, 0.4"/></bsdf>
  </shape>
  <shape type="sphere">
    <transform name="to_world"><scale value="0.4"/><translate x="2.5" y="2.5" z="2"/></transform>
    <emitter type="area"><rgb name="radiance" value="30, 30, 30"/></emitter>
  </shape>
  <emitter type="constant"><rgb name="radiance" value="0.3, 0.3, 0.3"/></emitter>"""


def write_slide(path: Path, height: int = 16, width: int = 16, background: int = 0) -> Path:
    """An 8-bit PNG to project, asymmetric so that a flip shows: the left half red, the top
    half green, a blue rectangle in the middle, over ``background``."""
    import numpy as np
    from PIL import Image

    x = np.full((height, width, 3), background, np.uint8)
    x[:, :width // 2, 0], x[:height // 2, :, 1] = 255, 200
    x[height // 4:3 * height // 4, width // 4:3 * width // 4, 2] = 255
    Image.fromarray(x).save(path)
    return path


def write_scene(tmp_path: Path, body: str, sensor: str | None = None, max_depth: int = 4,
                integrator: str | None = None, name: str = "scene.xml",
                room: bool = True) -> Path:
    """A scene file: ``integrator`` (a path tracer of ``max_depth`` by default), ``sensor``
    (a perspective camera at z = 4 by default), ``body`` and the ROOM around it (unless
    ``room`` is false)."""
    integ = integrator or (f'<integrator type="path"><integer name="max_depth" '
                           f'value="{max_depth}"/></integrator>')
    path = tmp_path / name
    path.write_text(f'<scene version="3.0.0">\n  {integ}\n  {sensor or perspective()}\n'
                    f'  {body}\n{ROOM if room else ""}\n</scene>\n')
    return path


def median_rmse(path: Path, spp: int, seeds: int = 3, ref_spp: int = 4096,
                variant: str = "rgb") -> tuple[float, float]:
    """Median RMSEs of rdsl (``variant``) and Mitsuba (its scalar one) at ``spp`` over
    ``seeds`` seeds, against a ``ref_spp`` Mitsuba render (a rare firefly moves a mean, not
    a median)."""
    import numpy as np
    import rdsl
    from _mitsuba_compare import mitsuba_render as render

    def mitsuba_render(path: Path, spp: int, seed: int) -> np.ndarray:
        return render(path, spp, seed, f"scalar_{variant}")

    ref = mitsuba_render(path, ref_spp, seed=100)
    scene = rdsl.load_scene(path, variant=variant)

    def err(img: np.ndarray) -> float:
        return float(np.sqrt(np.mean((np.asarray(img, np.float64)[..., :3] - ref) ** 2)))

    mine = np.median([err(scene.render(spp=spp, seed=k)) for k in range(seeds)])
    theirs = np.median([err(mitsuba_render(path, spp, seed=10 + k)) for k in range(seeds)])
    return float(mine), float(theirs)


def check_bad(tmp_path: Path, body: str, message: str) -> None:
    """``body`` on line 3 of a scene fails to load with ``message``, naming that line."""
    import pytest
    from rdsl.runtime.scene import SceneError, load_scene_description

    path = tmp_path / "bad.xml"
    path.write_text(f'<scene version="3.0.0">\n  <shape type="sphere"/>\n  {body}\n</scene>\n')
    with pytest.raises(SceneError) as exc:
        load_scene_description(path)
    text = str(exc.value)
    assert message in text and text.startswith(f"{path}:3:"), text
