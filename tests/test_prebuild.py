"""Speculative builds of the adjoint kernel (runtime/render/prebuild.py): assigning a
parameter starts building, in a background process, the kernel that ``backward`` with the
assigned names runs; ``backward`` then loads it from the cache, with the same gradients
as a kernel it compiles itself."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import rdsl
from rdsl.runtime.render import prebuild
from rdsl.runtime.render.backward import TAPE, tape_covers
from rdsl.runtime.render.differentiable import ad_twin, seeds_of

CBOX = Path(__file__).resolve().parents[1] / "examples" / "cbox" / "cbox.xml"
RED, GREEN = "red.reflectance.value", "green.reflectance.value"


@pytest.fixture
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """An empty kernel cache, and speculation on (tests/conftest.py turns it off)."""
    monkeypatch.setenv("RDSL_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv(prebuild.PREBUILD_ENV, "1")
    monkeypatch.setattr(prebuild.os, "cpu_count", lambda: 2)
    return tmp_path / "cache"


def _scene():
    return rdsl.load_scene(CBOX, res=16, spp=2, max_depth=3)


def _gradient(scene) -> np.ndarray:
    d = np.linspace(-1.0, 1.0, 16 * 16 * 3).reshape(16, 16, 3)
    return scene.backward(d, [RED], seed=3)[RED]


def test_backward_loads_the_speculated_kernel(cache: Path,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    scene = _scene()
    scene.params[RED] = [0.4, 0.1, 0.1]
    twin, job = scene._speculating
    assert job.quick and job.proc.pid > 0
    got = _gradient(scene)
    assert twin._module.from_cache  # built by the job, not by backward
    assert job.proc.returncode == 0

    # the same gradient from a kernel backward compiles itself, in another empty cache
    monkeypatch.setenv("RDSL_CACHE_DIR", str(cache.parent / "other"))
    monkeypatch.setenv(prebuild.PREBUILD_ENV, "0")
    own = _scene()
    own.params[RED] = [0.4, 0.1, 0.1]
    assert getattr(own, "_speculating", None) is None
    want = _gradient(own)
    assert not ad_twin(own, "reverse", 0, TAPE, seeds_of(own, [RED]), tape_covers(own, TAPE))._module.from_cache
    np.testing.assert_array_equal(got, want)
    assert np.all(np.isfinite(want)) and np.any(want != 0)


def test_a_new_name_replaces_the_job(cache: Path) -> None:
    scene = _scene()
    scene.params[RED] = 0.5
    first_twin, first = scene._speculating
    scene.params[RED] = 0.6  # the same name again: the same job goes on
    assert scene._speculating[1] is first
    scene.params[GREEN] = 0.3
    twin, job = scene._speculating
    try:
        assert job is not first and twin is not first_twin
        assert first.proc.poll() is not None  # stopped (or ended)
        assert first_twin._speculated is None
        assert twin is ad_twin(scene, "reverse", 0, TAPE, seeds_of(scene, [RED, GREEN]),
                              tape_covers(scene, TAPE))
    finally:
        job.stop()


def test_integer_settings_of_the_integrator_are_not_speculated_on(cache: Path) -> None:
    # backward refuses them (no derivative), so a kernel for them would never be asked for
    scene = _scene()
    scene.params["path.max_depth"] = 2
    assert getattr(scene, "_speculating", None) is None
    scene.params[RED] = 0.5
    twin, job = scene._speculating
    try:
        assert twin is ad_twin(scene, "reverse", 0, TAPE, seeds_of(scene, [RED]),
                               tape_covers(scene, TAPE))
    finally:
        job.stop()


def test_no_speculation_when_off_or_on_one_core(cache: Path,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(prebuild.PREBUILD_ENV, "0")
    scene = _scene()
    scene.params[RED] = 0.5
    assert getattr(scene, "_speculating", None) is None
    monkeypatch.setenv(prebuild.PREBUILD_ENV, "1")
    monkeypatch.setattr(prebuild.os, "cpu_count", lambda: 1)
    scene = _scene()
    scene.params[RED] = 0.5
    assert getattr(scene, "_speculating", None) is None


class _Job:
    def __init__(self, quick: bool) -> None:
        self.quick, self.calls = quick, []

    def finish(self) -> bool:
        self.calls.append("finish")
        return True

    def stop(self) -> None:
        self.calls.append("stop")


@pytest.mark.parametrize("job_quick,asked_quick,call", [
    (True, True, "finish"), (False, True, "finish"), (False, False, "finish"),
    (True, False, "stop")])
def test_a_compile_waits_only_for_a_tier_it_uses(job_quick: bool, asked_quick: bool,
                                                 call: str) -> None:
    class Twin:
        _speculated = _Job(job_quick)

    twin = Twin()
    job = twin._speculated
    prebuild.wait_for_speculated(twin, asked_quick)
    assert job.calls == [call] and twin._speculated is None
    prebuild.wait_for_speculated(twin, asked_quick)  # once only
    assert job.calls == [call]
