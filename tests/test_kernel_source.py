"""Golden texts of the generated render kernel (runtime/render/kernel_source.py filling
stdlib/render/kernel.rdsl.in): the Cornell box in RGB and in a spectral polarized build, and
the materials scene, compared byte for byte with tests/golden/kernel_source/.

After an intended change to the kernel's text, regenerate them with
``python tests/test_kernel_source.py --update`` and review the diff.
"""

from __future__ import annotations

import re
import sys
import warnings
from pathlib import Path

import pytest
from _scenes import CBOX
from rdsl.core.color import MODELS

ROOT = Path(__file__).resolve().parents[1]
MATERIALS = ROOT / "bench" / "scenes" / "materials.xml"
GOLDEN = Path(__file__).with_name("golden") / "kernel_source"

# golden file name -> (scene, variant)
CASES = {
    "cbox_rgb": (CBOX, "rgb"),
    "cbox_spectral_polarized": (CBOX, "spectral_polarized"),
    "materials_rgb": (MATERIALS, "rgb"),
    "materials_mono_polarized": (MATERIALS, "mono_polarized"),
}


def generate(scene: Path, variant: str) -> str:
    """The kernel text ``Scene.compile`` would build for ``scene`` in ``variant``."""
    from rdsl.runtime.render.kernel_source import kernel_source
    from rdsl.runtime.render.renderer import flatten
    from rdsl.runtime.scene import load_scene_description

    desc = load_scene_description(scene)
    with warnings.catch_warnings():  # polarizer warnings are not this test's business
        warnings.simplefilter("ignore")
        bufs, bsdfs, emitters = flatten(desc, False, MODELS[variant])
    return kernel_source(desc, bufs, bsdfs, emitters, MODELS[variant])


@pytest.mark.parametrize("name", sorted(CASES))
def test_kernel_source_matches_golden(name: str) -> None:
    scene, variant = CASES[name]
    if not scene.is_file():
        pytest.skip(f"{scene} is not present")
    expected = (GOLDEN / f"{name}.rdsl").read_text()
    assert generate(scene, variant) == expected, \
        f"regenerate with `python {Path(__file__).name} --update` if the change is intended"


def test_template_notes_and_empty_lines() -> None:
    """The template's ``//#`` notes never reach the kernel, and a lone hole left empty
    drops its line instead of leaving a blank one."""
    from rdsl.runtime.render.kernel_source import TEMPLATE, fill

    holes = {name: "x" for name in re.findall(r"\$(\w+)", TEMPLATE.read_text())}
    assert "imports" in holes and "camera" in holes
    text = fill({**holes, "imports": ""})
    assert "//#" not in text and "$" not in text
    assert "import render.film;\n\nstruct FilmSample" in text
    assert fill({**holes, "imports": "import y;"}).count("import y;") == 1
    with pytest.raises(KeyError):
        fill({k: v for k, v in holes.items() if k != "camera"})


if __name__ == "__main__" and "--update" in sys.argv:
    GOLDEN.mkdir(parents=True, exist_ok=True)
    for name, (scene, variant) in sorted(CASES.items()):
        if scene.is_file():
            (GOLDEN / f"{name}.rdsl").write_text(generate(scene, variant))
            print(f"wrote {GOLDEN / name}.rdsl")
        else:
            print(f"skipped {name}: {scene} is not present")
