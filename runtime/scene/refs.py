"""``<ref id="..."/>`` resolved after the whole scene is read, as Mitsuba 3 does.

A reference may name an object declared later in the file or in a later ``<include>``, so the
XML reader (:mod:`.xml`) leaves each ``<ref>`` as a :class:`Child` whose node is a
placeholder and lists it; :func:`resolve_refs` then points each at the object with that id
(an id that never appears is an error at the ``<ref>``'s line), and rejects a reference cycle
(an object that contains, through references, itself), which would never finish building.
Whether the referenced object's category fits where it is used (a texture where a BSDF is
expected) is the loader's check, against the plugin's schema.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .errors import scene_error

if TYPE_CHECKING:
    from .xml import Child, ObjectNode

# the placeholder category of a <ref> not resolved yet
UNRESOLVED = "ref"


def resolve_refs(refs: list[Child], ids: dict[str, ObjectNode], root: ObjectNode) -> None:
    """Point each ``<ref>`` in ``refs`` at its object; then check that no object contains
    itself through references."""
    for ch in refs:
        ident = ch.node.id
        assert ident is not None and ch.node.category == UNRESOLVED
        if ident not in ids:
            known = ", ".join(ids) or "none"
            raise scene_error(f"<ref>: no object with id '{ident}' is declared in the scene "
                              f"(declared ids: {known})", ch.loc)
        ch.node = ids[ident]
    _check_cycles(root)


def _check_cycles(root: ObjectNode) -> None:
    """Depth-first over nested objects and references; a reference back to an object still
    being visited closes a cycle."""
    done: set[int] = set()
    path: list[tuple[ObjectNode, Child | None]] = []  # the objects being visited, and how

    def visit(node: ObjectNode, via: Child | None) -> None:
        if id(node) in done:
            return
        for i, (n, _) in enumerate(path):
            if n is node:
                assert via is not None  # only a reference can lead back up the tree
                names = [_name(m) for m, _ in path[i:]] + [_name(node)]
                raise scene_error(f"<ref id=\"{node.id}\">: reference cycle "
                                  f"{' -> '.join(names)}; an object cannot contain itself",
                                  via.loc)
        path.append((node, via))
        for ch in node.children:
            visit(ch.node, ch)
        path.pop()
        done.add(id(node))

    visit(root, None)


def _name(node: ObjectNode) -> str:
    return f"{node.category} '{node.id}'" if node.id else f"{node.category} '{node.type}'"
