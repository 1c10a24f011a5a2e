"""Benchmark: smoke-sweep throughput with 1 and 2 local workers, and render re-use.

Runs ``sweeps/smoke.yaml`` from scratch (fresh output folders, so every render
is made) with ``--workers 1`` and ``--workers 2`` and prints tasks per minute,
the 2-worker scaling efficiency (rate₂ / (2 · rate₁)), and how many tasks
re-used a render instead of rendering. Printed, not asserted: the machine is
shared.

    .venv/bin/python benchmarks/bench_sweep.py [SWEEP.yaml]
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

from nearlight.evaluation.engine import run_sweep
from nearlight.evaluation.sweep import load_sweep


def main() -> None:
    path = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parents[1] / "sweeps" / "smoke.yaml"
    sweep = load_sweep(path)
    print(f"{path.name}: {len(sweep.tasks)} tasks, {len(sweep.render_keys)} physical configurations")
    rates = {}
    with tempfile.TemporaryDirectory() as tmp:
        for workers in (1, 2):
            s = run_sweep(sweep, Path(tmp) / f"w{workers}", workers=workers, progress=False)
            rates[workers] = s.ran / (s.seconds / 60.0)
            print(
                f"workers={workers}: {s.ran} tasks in {s.seconds:.1f} s = {rates[workers]:.1f} tasks/min; "
                f"renders: {s.rendered} rendered, {s.reused} tasks re-used a render; {s.failed} failed"
            )
    print(f"scaling efficiency with 2 workers: {rates[2] / (2 * rates[1]):.2f} (1.00 = perfect)")


if __name__ == "__main__":
    main()
