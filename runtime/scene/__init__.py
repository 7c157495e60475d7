"""Mitsuba 3 XML scenes: parsing, validation and mesh loading (pure Python, no rendering).

``load_scene_description(path, **defaults)`` returns a :class:`SceneDescription`;
``defaults`` play the role of ``-D name=value``.  Every malformed or unsupported scene is a
:class:`SceneError` (a ``CompileError``) pointing at the file and line.
"""

from .errors import SceneError
from .loader import Plugin, SceneDescription, Sensor, Shape, load_scene_description
from .meshes import Mesh
from .spectra import Color
from .xml import parse_defines

__all__ = ["Color", "Mesh", "Plugin", "SceneDescription", "SceneError", "Sensor", "Shape",
           "load_scene_description", "parse_defines"]
