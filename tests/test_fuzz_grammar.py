"""Mutation fuzzing of the frontend: a mangled program compiles or gives a CompileError.

Valid programs (snippets of the stdlib and the samples below) get a few random token edits
(delete, duplicate, swap, insert punctuation, truncate) with a fixed seed.  ``compile_to_ir``
must either succeed or raise :class:`CompileError` whose diagnostic has a location; any other
exception is a frontend bug.
"""

from __future__ import annotations

import random
import re
from pathlib import Path

import pytest
import rdsl
from rdsl.compiler.diagnostics import CompileError
from rdsl.dsl import compile_to_ir

STDLIB = Path(rdsl.__file__).parent / "stdlib"

SAMPLES = [
    """
struct Foo { a: Float, b: Vec3 }
fn both(x: Float) -> (Float, Float) { return (x, -x); }
fn sum(b: [Float], n: Int) -> Float {
    var acc = 0.0;
    for i in 0..n {
        if b[i] < 0.0 { continue; }
        if acc > 100.0 { break; }
        acc += b[i];
    }
    b[0] = acc;
    return acc;
}
fn vecs(v: Vec3, s: Float) -> Vec3 {
    var w = v * s + 1;
    w.x = 3;
    var f = Foo { b: w, a: 1 };
    f.b.y = 2.0;
    let (p, q) = both(f.a);
    let t = both(q);
    return w + f.b * t.0 + Vec3(p, 1, 2) + normalize(v);
}
""",
    """
bsdf diffuse {
    param reflectance: Texture = 0.5;
    param tint: Spectrum = Spectrum(0.1, 0.2, 0.3);
    fn eval(si: Surface, wo: Vec3) -> Spectrum {
        if si.wi.z <= 0.0 || wo.z <= 0.0 { return Spectrum(0.0); }
        var r = reflectance(si) * tint * inv_pi();
        if const polarized { r = r * 2.0; } else { r = r + 0.0; }
        return r;
    }
    fn pdf(si: Surface, wo: Vec3) -> Float { return max(wo.z, 0.0) * inv_pi(); }
    fn sample(si: Surface, u1: Float, u2: Vec2) -> BsdfSample {
        let wo = Vec3(u2.x, u2.y, sqrt(max(0.0, 1.0 - u2.x * u2.x - u2.y * u2.y)));
        return BsdfSample { wo: wo, pdf: pdf(si, wo), eta: 1.0, weight: eval(si, wo),
                            delta: false };
    }
}
""",
    """
import render.integrator;
fn hash(x: UInt) -> UInt {
    var h = x ^ 0x2545F491u;
    h = (h ^ (h >> 16u)) * 0x45d9f3bu;
    return h ^ (h << 5u);
}
fn early(x: Float) -> Float {
    if x < 0 { return 0; }
    var y = x;
    while y > 1.0 && !(y == 3.0) {
        y = y * 0.5;
        if y < 0.3 { return y; }
    }
    return select(y > 0.5, y, -y) + Float(Int(y)) + mean(Spectrum(y));
}
integrator depth {
    param max_depth: Int = 4;
    fn sample(scene: Scene, ray: Ray, sampler: Sampler) -> Spectrum {
        let si = scene.trace(ray);
        if !si.valid { return Spectrum(0.0); }
        let (s1, u) = sampler.next_1d();
        return Spectrum(si.t + u * 1e-9);
    }
}
""",
]

TOKEN = re.compile(r"//[^\n]*|/\*.*?\*/|\s+|\d+\.\d*|\.\d+|\w+|&&|\|\||[=!<>]=|<<|>>|\.\.|"
                   r"->|[+\-*/%]=|.", re.DOTALL)
PUNCT = list("{}()[];,.:=+-*/<>!&|^~%") + ["..", "->", "&&", "||", "==", "let", "fn", "if",
                                            "return", "0", "1.5", "x", "7u", "Vec3", "else"]


def _compiles(text: str, filename: str) -> bool:
    try:
        compile_to_ir(text, filename=filename)
        return True
    except CompileError:
        return False


_SNIPPETS: list[tuple[str, str]] = []
_DROPPED: list[str] = []  # stdlib pieces that did not compile on their own


def _snippets() -> list[tuple[str, str]]:
    """(filename, text) of valid programs: the samples, pieces of math.rdsl (which resolve
    against the prelude's copy) and the other stdlib files that compile on their own."""
    if _SNIPPETS:
        return _SNIPPETS
    out = [(f"sample{i}.rdsl", t) for i, t in enumerate(SAMPLES)]
    math = STDLIB / "math.rdsl"
    if math.is_file():
        items = re.split(r"\n(?=fn\b)", math.read_text())
        out += [(f"math{i}.rdsl", "\n".join(items[i:i + 8])) for i in range(0, len(items), 8)]
    for path in sorted(STDLIB.rglob("*.rdsl")):
        if path.name not in ("math.rdsl", "types.rdsl"):
            out.append((str(path.with_name("fuzzed_" + path.name)), path.read_text()))
    for f, t in out:
        if f.startswith("sample") or _compiles(t, f):
            _SNIPPETS.append((f, t))
        else:
            _DROPPED.append(f)
    return _SNIPPETS


def _mutate(text: str, rng: random.Random) -> str:
    toks = TOKEN.findall(text)
    for _ in range(rng.randint(1, 3)):
        if not toks:
            break
        kind = rng.random()
        i = rng.randrange(len(toks))
        if kind < 0.3:
            del toks[i]
        elif kind < 0.45:
            toks.insert(i, toks[i])
        elif kind < 0.6:
            j = rng.randrange(len(toks))
            toks[i], toks[j] = toks[j], toks[i]
        elif kind < 0.9:
            toks.insert(i, rng.choice(PUNCT))
        else:
            toks = toks[:i]
    return "".join(toks)


def _cases(n: int, seed: int) -> list[tuple[int, str, str]]:
    rng = random.Random(seed)
    snippets = _snippets()
    out = []
    for k in range(n):
        filename, text = rng.choice(snippets)
        out.append((k, filename, _mutate(text, rng)))
    return out


def test_snippets_are_valid() -> None:
    """The samples compile, and so does every stdlib piece on its own (``_snippets``
    compiled each once already: a second compile of those checked nothing new)."""
    snippets = _snippets()
    assert not _DROPPED, f"stdlib code that does not compile on its own: {_DROPPED}"
    assert len(snippets) >= len(SAMPLES) + 60
    for filename, text in snippets:
        if filename.startswith("sample"):
            compile_to_ir(text, filename=filename)


@pytest.mark.parametrize("chunk", range(4))
def test_mutations_never_crash(chunk: int) -> None:
    cases = _cases(400, seed=1234)[chunk::4]
    errors = 0
    for k, filename, text in cases:
        try:
            # keep the real path of stdlib files so that their imports resolve
            compile_to_ir(text, filename=filename)
        except CompileError as e:
            errors += 1
            d = e.diagnostics[0]
            assert d.message and d.loc is not None, text
            assert str(e).startswith(d.loc.file)
        except Exception as e:  # noqa: BLE001
            pytest.fail(f"{type(e).__name__}: {e}\n--- program {k} ---\n{text}")
    assert errors > 0
