"""What makes compiles cheaper must not change what they produce: the IR walk's order, the
clone's values, and the table samples kept on disk across processes (keyed by the printed
IR, the values and the compiler, written atomically under the cache folder only)."""

from __future__ import annotations

import numpy as np
import pytest
from rdsl.compiler import precompute
from rdsl.compiler.driver import STDLIB, frontend
from rdsl.compiler.ir import Block, clone_block
from rdsl.compiler.precompute import table_params, tabulate
from rdsl.core.scene_spec import Instance, TextureRef


def _recursive_walk(block: Block):
    for ins in block.instrs:
        yield ins
        for r in ins.regions:
            yield from _recursive_walk(r)


@pytest.fixture(scope="module")
def roughplastic():
    return frontend(STDLIB / "bsdf" / "roughplastic.rdsl")


def test_walk_is_program_order_through_nested_regions(roughplastic):
    nested = 0
    for fn in roughplastic.functions.values():
        got = list(fn.walk())
        assert got == list(_recursive_walk(fn.body)), fn.name
        nested += sum(1 for i in got if i.regions and any(r.instrs for r in i.regions))
    assert nested > 10  # the check went through ifs and loops


def test_walk_sees_a_region_replaced_while_walking():
    module = frontend(STDLIB / "bsdf" / "roughplastic.rdsl")  # its own: this one is cut
    fn = next(f for f in module.functions.values()
              if any(len(i.regions) == 2 for i in f.body.instrs))
    seen = []
    for ins in fn.walk():
        seen.append(ins)
        if len(ins.regions) == 2 and ins.regions[1].instrs:
            ins.regions[1].instrs = ins.regions[1].instrs[-1:]  # only the yield left
    assert seen == list(_recursive_walk(fn.body))


def test_clone_maps_every_value(roughplastic):
    fn = max(roughplastic.functions.values(), key=lambda f: sum(1 for _ in f.walk()))
    mapping = {p.value: p.value for p in fn.params}
    copy = clone_block(fn.body, mapping)
    old, new = list(_recursive_walk(fn.body)), list(_recursive_walk(copy))
    assert len(old) == len(new)
    for a, b in zip(old, new):
        assert (a.op, a.attrs, a.loc) == (b.op, b.attrs, b.loc) and a is not b
        assert [mapping.get(v, v) for v in a.operands] == b.operands
        assert [(r.type, r.name) for r in a.results] == [(r.type, r.name) for r in b.results]
        assert all(r.owner is b for r in b.results) and all(mapping[r] is s for r, s in
                                                             zip(a.results, b.results))
        assert b.attrs is not a.attrs


def _table(module, alpha):
    read = module.functions["roughplastic.external_transmittance.read"]
    params = table_params(read, Instance("roughplastic", {"alpha": alpha}))
    return read.attrs["table"], params


def test_table_samples_are_kept_on_disk(roughplastic, tmp_path, monkeypatch):
    monkeypatch.setenv("RDSL_CACHE_DIR", str(tmp_path))
    opts, params = _table(roughplastic, 0.3)
    first = tabulate(roughplastic, opts, params)
    entries = list((tmp_path / "tables").iterdir())
    # one entry of samples (and the kernel's, if this process built it), no temporary file
    assert sorted(p.suffix for p in entries) in ([".npy"], [".npy", ".pickle"]), entries
    entries = [p for p in entries if p.suffix == ".npy"]
    assert all(p.parent == tmp_path / "tables" for p in tmp_path.rglob("*.npy"))

    def no_kernel(*a, **k):
        raise AssertionError("compiled although the samples are on disk")

    with monkeypatch.context() as mp:  # a hit reads the file: no kernel is built or run
        mp.setattr(precompute, "_kernel", no_kernel)
        again = tabulate(roughplastic, opts, params)
        assert again.tobytes() == first.tobytes() and again.dtype == np.float32
        with pytest.raises(AssertionError, match="compiled"):  # other values: another key
            tabulate(roughplastic, *_table(roughplastic, 0.31))
    entries[0].write_bytes(b"not an array")  # a damaged entry is computed again
    assert tabulate(roughplastic, opts, params).tobytes() == first.tobytes()
    assert np.load(entries[0]).tobytes() == first.tobytes()


def test_table_key_follows_the_code_and_values(roughplastic, tmp_path, monkeypatch):
    monkeypatch.setenv("RDSL_CACHE_DIR", str(tmp_path))
    opts, params = _table(roughplastic, 0.3)
    fn = roughplastic.functions[opts["fn"]]
    _, text = precompute._source(roughplastic, fn, True)
    xs = precompute.sample_points(opts)
    key = precompute._disk_entry(text, xs, params)
    assert key.parent == tmp_path / "tables"
    assert precompute._disk_entry(text + " ", xs, params) != key  # the code
    assert precompute._disk_entry(text, xs[:-1], params) != key  # the points
    assert precompute._disk_entry(text, xs, dict(params, alpha=0.3000001)) != key
    from rdsl.core import cachedir
    monkeypatch.setattr(cachedir, "compiler_fingerprint", lambda: "another compiler")
    assert precompute._disk_entry(text, xs, params) != key  # the compiler
    # a texture: what the kernel call diagnoses, never read from disk
    assert precompute._disk_entry(text, xs, dict(params, alpha=TextureRef(0))) is None


PLUGIN = """
import bsdf.common;
bsdf tinted {
    param tint: Float = TINT;
    fn eval(si: Surface, wo: Vec3) -> Spectrum { return Spectrum(tint * cos_theta(wo)); }
    fn pdf(si: Surface, wo: Vec3) -> Float { return 0.0; }
    fn sample(si: Surface, u1: Float, u2: Vec2) -> BsdfSample {
        return BsdfSample { wo: Vec3(0.0, 0.0, 1.0), pdf: 0.0, eta: 1.0,
                            weight: Spectrum(0.0), delta: false };
    }
}
"""


def test_plugin_signatures_are_kept_on_disk_by_the_texts(tmp_path, monkeypatch):
    """A process that meets a plugin another one checked reads its params from the cache
    (no check), and an edit of the file, or of a file it imports, is checked again."""
    from rdsl.runtime import plugins

    monkeypatch.setenv("RDSL_CACHE_DIR", str(tmp_path / "cache"))
    path = tmp_path / "tinted.rdsl"
    path.write_text(PLUGIN.replace("TINT", "0.25"))

    def params() -> dict:
        plugins._checked.cache_clear()  # as a new process would
        decl = plugins.index_file(path)[0]
        return {k: p.default for k, p in decl.params().items()}

    assert params() == {"tint": 0.25}
    checks = []
    real = plugins._check_file
    monkeypatch.setattr(plugins, "_check_file", lambda *a: checks.append(a) or real(*a))
    assert params() == {"tint": 0.25} and checks == []  # from the disk, unchecked
    path.write_text(PLUGIN.replace("TINT", "0.75"))
    assert params() == {"tint": 0.75} and len(checks) == 1
    # an imported file's text is part of the key: a copy of bsdf.common next to the plugin
    # (imports resolve next to the importing file first) gets the plugin checked again
    (tmp_path / "bsdf").mkdir()
    common = STDLIB / "bsdf" / "common.rdsl"
    (tmp_path / "bsdf" / "common.rdsl").write_text(common.read_text() + "\n// edited\n")
    assert params() == {"tint": 0.75} and len(checks) == 2
    for entry in (tmp_path / "cache" / "signatures").iterdir():  # a damaged entry: checked
        entry.write_bytes(b"not a pickle")
    assert params() == {"tint": 0.75} and len(checks) == 3


def test_the_parser_tables_are_kept_on_disk(tmp_path):
    """A new process loads the grammar's LALR tables (the same parses) instead of analysing
    the grammar, and a damaged file is analysed again."""
    import os
    import subprocess
    import sys

    # the AST the transformer builds from the parse (not through the AST cache), hashed
    script = ("import hashlib; from rdsl.dsl import parser as P; "
              "src = open(P._GRAMMAR.parent.parent / 'stdlib' / 'bsdf' / 'plastic.rdsl').read();"
              "print(hashlib.sha256(repr(P._parse(src, 'plastic.rdsl')).encode()).hexdigest())")
    env = dict(os.environ, RDSL_CACHE_DIR=str(tmp_path))
    runs = [subprocess.run([sys.executable, "-c", script], env=env, capture_output=True,
                           text=True, check=True).stdout.split() for _ in range(2)]
    (tables,) = (tmp_path / "lark").iterdir()
    tables.write_bytes(b"damaged")
    runs.append(subprocess.run([sys.executable, "-c", script], env=env, capture_output=True,
                               text=True, check=True).stdout.split())
    assert runs[0][0] == runs[1][0] == runs[2][0]  # the same parse tree each time
    assert tables.stat().st_size > 10_000  # written again whole
