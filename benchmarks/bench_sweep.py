"""Benchmark: sweep throughput with 1 and 2 local workers, and render re-use.

Runs a sweep (default ``sweeps/smoke.yaml``) from scratch (fresh output
folders, so every render is made) with ``--workers 1`` and ``--workers 2`` and
prints tasks per minute, the 2-worker scaling efficiency
(rate₂ / (2 · rate₁)), and how many tasks re-used a render instead of
rendering. Printed, not asserted: the machine is shared.

The smoke sweep alone (8 tasks, a few seconds) is dominated by starting worker
processes; ``--seeds 10`` turns it into 80 tasks on the same 2 renders, which
shows how the engine scales once there is work to share.

    .venv/bin/python benchmarks/bench_sweep.py [SWEEP.yaml] [--seeds N]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import yaml

from nearlight.evaluation.engine.run import run_sweep
from nearlight.evaluation.engine.sweep import load_sweep


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = Path(__file__).resolve().parents[1] / "sweeps" / "smoke.yaml"
    parser.add_argument("sweep", nargs="?", type=Path, default=default, help="sweep file (default: smoke)")
    parser.add_argument("--seeds", type=int, help="replace the sweep's seeds by this many")
    args = parser.parse_args()
    source: Path | dict = args.sweep
    if args.seeds:
        # an inline copy with more seeds; scene paths in it stay relative to the file
        source = yaml.safe_load(args.sweep.read_text()) | {"seeds": args.seeds}
        if isinstance(source.get("scene"), str):
            source["scene"] = str(args.sweep.parent / source["scene"])
    sweep = load_sweep(source)
    print(f"{args.sweep.name}: {len(sweep.tasks)} tasks, {len(sweep.render_keys)} physical configurations")
    rates = {}
    with tempfile.TemporaryDirectory() as tmp:
        for workers in (1, 2):
            s = run_sweep(sweep, Path(tmp) / f"w{workers}", workers=workers, progress=False)
            rates[workers] = s.ran / (s.seconds / 60.0)
            print(f"workers={workers}: {rates[workers]:.1f} tasks/min; {s.line()}")
    print(f"scaling efficiency with 2 workers: {rates[2] / (2 * rates[1]):.2f} (1.00 = perfect)")


if __name__ == "__main__":
    main()
