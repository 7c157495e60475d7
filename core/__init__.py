"""The core layer: data and facts that the compiler and the runtime both need.

Modules here sit below both ``rdsl.compiler`` and ``rdsl.runtime`` and import nothing from
rdsl outside ``core`` (numpy and the standard library only): the scene specification that the
runtime builds and the ``specialize`` pass consumes (:mod:`.scene_spec`), the host-side
spectral data and fits that the compiler bakes into kernels and the runtime uses for colours
(:mod:`.spectral`), the colour model of each variant (:mod:`.color`), and the Embree C ABI that the LLVM backend emits calls against and the
runtime drives through ctypes (:mod:`.embree_abi`). ``tests/test_layering.py`` keeps it so.
"""
