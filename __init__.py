"""rdsl: a compiler for physically based rendering.

``rdsl.jit(source_or_path)`` compiles in process, ``rdsl.load(path)`` loads what
``rdsl compile`` wrote, ``rdsl.load_scene(path)`` loads a Mitsuba scene for rendering
(``rdsl.load_dict(d)`` one given as Mitsuba 3's Python dictionary) and
``rdsl.register_plugin(path_or_source)`` makes a plugin file available to every scene.
A mistake in a program or a scene raises ``rdsl.CompileError``, whose message names the
file and line; a wrong array passed to a kernel, a ``ValueError`` naming the parameter.
"""

__version__ = "0.1.0"


def __getattr__(name: str):
    # The runtime imports llvmlite and numpy; load it on first use so that `import rdsl`
    # stays cheap and never fails because an optional tool is missing.
    if name in ("jit", "load", "Module", "Kernel"):
        from .runtime import api

        return getattr(api, name)
    if name == "Transform4f":  # Mitsuba's ScalarTransform4f, for load_dict
        from .runtime.scene.dicts import Transform4f

        return Transform4f
    if name in ("load_scene", "load_dict", "Scene"):
        from .runtime.render import renderer

        return getattr(renderer, name)
    if name == "Build":  # a target, a colour model and a differentiation mode
        from .compiler.build import Build

        return Build
    if name == "CompileError":  # a mistake in a program or a scene
        from .compiler.diagnostics import CompileError

        return CompileError
    if name == "optim":
        from .runtime import optim

        return optim
    if name == "register_plugin":
        from .runtime import plugins

        return plugins.register_plugin
    if name in ("write_image", "read_exr"):
        from .runtime.render import image

        return getattr(image, name)
    raise AttributeError(name)
