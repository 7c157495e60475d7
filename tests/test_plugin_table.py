"""docs/plugins.md's table of Mitsuba 3's plugins is what rdsl.tools.gen_plugin_table writes
from the loader's schema and the stdlib (regenerate it after adding a plugin), and a plugin
the table says rdsl has does load."""

from __future__ import annotations

import pytest
from rdsl.runtime.scene import SceneError, load_scene_description
from rdsl.tools.gen_plugin_table import DOC, MITSUBA, supported, updated


def test_the_committed_table_is_up_to_date():
    text = DOC.read_text()
    assert updated(text) == text, "run: python -m rdsl.tools.gen_plugin_table"


@pytest.mark.parametrize("name", ["cylinder", "orthographic", "ldsampler", "moment",
                                  "volpath", "projector"])
def test_the_table_says_what_the_loader_does(tmp_path, name):
    category = next(c for c, names in MITSUBA.items() if name in names)
    element = {"shape": '<shape type="{}"/>', "sensor": '<sensor type="{}"/>',
               "sampler": '<sampler type="{}"/>',
               "integrator": '<integrator type="{}"><integrator type="path"/></integrator>',
               "emitter": '<emitter type="{}"/>'}[category].format(name)
    path = tmp_path / "s.xml"
    path.write_text(f'<scene version="3.0.0">{element}</scene>')
    if supported(category, name):
        load_scene_description(path)
    else:
        with pytest.raises(SceneError, match=f"unknown {category} plugin '{name}'"):
            load_scene_description(path)
