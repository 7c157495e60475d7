"""The test suite's kernel tier (and a check that xdist groups what it should).

Kernels compile at LLVM O0 (``RDSL_QUICK=1``, the quick tier of ``rdsl.jit``) in the tests
of rendering and plugins: O0 and O3 give the same results bit for bit (no fast-math, no
contraction; ``tests/test_quick_tier.py`` checks a render of each), and O0 compiles in about
60% of the time, which is most of this suite's.  The tests of code generation itself build
the full tier, as users get it: the backend's op semantics, the differential corpus, the
kernel ABI and layouts, the bit-identical reference images, the record loads (which only
the full tier has) and the tiers' own test.  Run
``RDSL_QUICK=0 pytest tests`` to build everything at the full tier.

Assigning a scene parameter does not start a speculative build of the adjoint kernel
(``RDSL_PREBUILD=0``, runtime/render/prebuild.py) but in tests/test_prebuild.py: the
suite's workers keep both cores busy, and most tests that assign parameters never call
``backward``.

A small render of a scene whose kernels are not cached renders with the generic build's
kernels standing in (runtime/render/stand_in.py) but in tests/test_stand_in.py
(``RDSL_GENERIC_FIRST=0``): the generic build agrees with the specialized one to float
rounding, not bit for bit, and which one a test got would depend on what the tests before
it left in the worker's shared kernel cache.
"""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("RDSL_QUICK", "1")
os.environ.setdefault("RDSL_PREBUILD", "0")
os.environ.setdefault("RDSL_GENERIC_FIRST", "0")

FULL_TIER = {"test_llvm_backend", "test_differential", "test_c_abi", "test_kernel_layouts",
             "test_bit_identical", "test_quick_tier", "test_llvm_records"}


@pytest.fixture(scope="module", autouse=True)
def _kernel_tier(request: pytest.FixtureRequest):
    if request.module.__name__.rsplit(".", 1)[-1] not in FULL_TIER:
        yield
        return
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("RDSL_QUICK", "0")
        yield


def pytest_configure(config: pytest.Config) -> None:
    """``--dist loadgroup`` must group: a compat sheet's cases share one render per worker
    (``xdist_group``).  pytest-xdist up to 3.8 groups by rewriting a node id attribute that
    pytest 9 no longer reads, and then renders each sheet on every worker, silently."""
    if config.getoption("dist", "no") != "loadgroup" or hasattr(config, "workerinput"):
        return
    from importlib.metadata import version

    xdist = version("pytest-xdist")  # the distribution --dist comes from (the test extra)
    xdist_version = tuple(int(x) for x in xdist.split(".")[:2] if x.isdigit())
    if pytest.version_tuple[0] >= 9 and xdist_version <= (3, 8):
        raise pytest.UsageError(f"pytest-xdist {xdist} cannot group tests "
                                f"(--dist loadgroup) under pytest {pytest.__version__}: "
                                "install pytest<9, as pyproject.toml's test extra says")
