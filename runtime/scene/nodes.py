"""Small helpers on the XML object tree shared by the loader's parts: where a parameter was
written, and a string parameter as written."""

from __future__ import annotations

from ...compiler.ir import Loc
from .xml import ObjectNode


def param_str(node: ObjectNode, name: str) -> str:
    """A string parameter as the scene wrote it (the caller checked it is present)."""
    return str(node.props[name].value)


def param_loc(node: ObjectNode, name: str) -> Loc:
    """The line of parameter ``name`` if the scene gave it, else the object's line."""
    if name in node.props:
        return node.props[name].loc
    for ch in node.children:
        if ch.name == name:
            return ch.loc
    return node.loc
