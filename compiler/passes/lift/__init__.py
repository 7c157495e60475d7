"""``lift(model)``: give the abstract ``Spectrum`` a concrete representation.

Expects: an inlined module (no calls) whose values may have type ``spectrum`` or aggregates
containing it, ``spec.*`` ops, and ``const trait "<name>"`` booleans from ``if const``.

Guarantees: no value has a ``spectrum`` type; no ``spec.*`` op and no trait constant
remains, and the branches of ``if const`` that the variant does not take are gone (so code
valid in one variant only may sit inside them).  What each variant's spectrum becomes is
described by its :class:`~rdsl.core.color.ColorModel`.

Spectral variants (``n = 4``) carry the four wavelengths of a sample as an implicit value
set by ``set_wavelengths(wl)`` in the kernel's top-level block.  The trait ``wavelengths``
(``if const wavelengths``) is true in a kernel that sets them, so that code needing them can
fall back in one that does not (a plugin compiled on its own).

The package, one job per module:

* ``model``: the IR types of a colour model's ``Spectrum`` (plain, Mueller);
* ``driver``: the :class:`Lift` pass, the walk over the module (types, traits, wavelengths);
* ``unpolarized``: the spectrum ops on unpolarized values (mono, RGB; spectral delegates);
* ``mueller``: the polarized variants' Mueller matrices and their known zeros;
* ``spectral``: colours as four wavelength samples (upsampling, tables, CIE, D65).
"""

from .driver import Lift
from .model import MUELLER_FIELDS, concrete_type, mueller_type, unpolarized_type

__all__ = ["MUELLER_FIELDS", "Lift", "concrete_type", "mueller_type", "unpolarized_type"]
