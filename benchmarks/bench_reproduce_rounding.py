"""Benchmark: does the paper reproduction hold its stated tolerances when the renders change in their last bits?

Another CPU renders the same scene with other last bits (Dr.Jit compiles for
the host). This script stands in for that machine: it runs ``nearlight
reproduce`` twice in one process, the second time with every float of every
clean render (analyzer stack, P, N, truth images) moved by one float32 ulp in
a seeded random direction, and checks the second run against the first with
:func:`nearlight.evaluation.paper.check.check`, the check ``reproduce
--against`` runs. It prints the check's table-by-table lines and, per metric,
the largest difference as a fraction of the allowed one (below 1 everywhere is
the goal). Printed, not asserted.

    .venv/bin/python benchmarks/bench_reproduce_rounding.py [--full]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np


def _perturbed(render_clean, seed: int):
    """``render_clean`` whose every float image is moved by ±1 float32 ulp (seeded signs)."""
    rng = np.random.default_rng(seed)

    def ulp(a):
        if a is None:
            return None
        a = np.asarray(a, dtype=np.float32)
        toward = np.where(rng.random(a.shape) < 0.5, -np.inf, np.inf).astype(np.float32)
        return np.where(np.isfinite(a), np.nextafter(a, toward), a)

    def render(*args, **kw):
        cap = render_clean(*args, **kw)
        return cap.replace(stack=ulp(cap.stack), P=ulp(cap.P), N=ulp(cap.N), specular=ulp(cap.specular),
                           diffuse=ulp(cap.diffuse), extra={k: ulp(v) for k, v in cap.extra.items()})  # fmt: skip

    return render


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--full", action="store_true", help="the full profile (640x480, 8 angles; ~25 min)")
    args = parser.parse_args()

    import nearlight.generator as generator
    from nearlight.evaluation.paper.reproduce import reproduce
    from nearlight.evaluation.paper.check import check, rows, tolerance

    docs = []
    original = generator.render_clean
    with tempfile.TemporaryDirectory() as tmp:
        for name in ("as rendered", "every render moved by 1 ulp"):
            generator.render_clean = original if not docs else _perturbed(original, seed=1)
            t0 = time.perf_counter()
            md = reproduce(Path(tmp) / name.replace(" ", "_"), quick=not args.full, progress=False)
            docs.append(json.loads((md.parent / "paper_reproduction.json").read_text()))
            print(f"{name}: {time.perf_counter() - t0:.0f} s")
    generator.render_clean = original
    lines, misses = check(docs[1], docs[0])
    print("\n".join(lines))
    worst: dict[str, float] = {}
    ref = {(n.table, n.row, n.metric): n.value for n in rows(docs[0])}
    for n in rows(docs[1]):
        base = ref.get((n.table, n.row, n.metric))
        if n.value is not None and base is not None:
            worst[n.metric] = max(worst.get(n.metric, 0.0), abs(n.value - base) / max(tolerance(n.metric, base), 1e-12))
    print("largest difference / allowed, per metric: " + ", ".join(f"{m} {f:.3g}" for m, f in worst.items()))
    print(f"{misses} number(s) outside the stated tolerance")


if __name__ == "__main__":
    main()
