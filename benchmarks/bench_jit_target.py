"""Benchmark: what the portable LLVM target changes in a render, what it costs, and whether it is deterministic.

Renders ``scenes/ts_board.yaml`` at its full 640×480 (8 analyzer angles) in
fresh processes (a target applies to the kernels of the process that sets
it): with the portable target (:mod:`nearlight.generator.jit_target`, the
default) twice, and with ``NEARLIGHT_JIT_TARGET=host``. Each process renders
``REPEATS`` times (Dr.Jit's kernel cache warm after the first) and reports
its fastest. Prints each run's target, stack hash and time; how many values
the portable target changes against the host's (and by how many ulp); the
time ratio portable / host; whether two portable processes agree bit for bit.

On one machine it cannot show that the portable target gives the same bits
on another CPU: the committed references (``reports/references/``) and
``tests/evaluation/paper/test_references.py`` check that on every machine.

    .venv/bin/python benchmarks/bench_jit_target.py
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "ts_board.yaml"
REPEATS = 5


def _render(out: str) -> None:
    """In this process: render ``REPEATS`` times, save the stack to ``out``, print target, hash, fastest time."""
    from nearlight.generator import jit_target, load_scene, render_clean
    from nearlight.generator.llvm import mitsuba

    mitsuba()
    scene = load_scene(SCENE)
    times = []
    for _ in range(REPEATS):
        t = time.perf_counter()
        stack = np.asarray(render_clean(scene, progress=False).stack)
        times.append(time.perf_counter() - t)
    np.save(out, stack)
    target = jit_target.current()
    print(f"{os.environ.get(jit_target.ENV) or 'portable':8s} target {target[:40]}{'...' if len(target) > 40 else ''}; "
          f"fastest of {REPEATS} renders {min(times):.3f} s; stack sha256 "
          f"{hashlib.sha256(stack.tobytes()).hexdigest()[:16]}", flush=True)
    print(f"seconds {min(times)!r}", flush=True)


def _run(mode: str, out: str) -> float:
    env = {**os.environ, "NEARLIGHT_JIT_TARGET": mode}
    done = subprocess.run([sys.executable, __file__, out], env=env, check=True, capture_output=True, text=True)
    lines = done.stdout.splitlines()
    print(lines[0])
    return float(lines[1].split()[1])


def main() -> None:
    if len(sys.argv) == 2:
        _render(sys.argv[1])
        return
    with tempfile.TemporaryDirectory() as tmp:
        seconds, stacks = {}, {}
        for run in ("host", "portable", "portable again"):
            out = os.path.join(tmp, run.replace(" ", "_") + ".npy")
            seconds[run] = _run(run.split()[0], out)
            stacks[run] = np.load(out)
    a, b, c = stacks["host"], stacks["portable"], stacks["portable again"]
    ulp = np.abs(a.astype(np.float64) - b) / np.spacing(np.maximum(np.abs(a), np.finfo(np.float32).tiny))
    lit = np.abs(a) > 0
    print(f"host vs portable: {int((a != b).sum())} of {a.size} values differ "
          f"({100 * float((a != b).mean()):.1f} %), at most {float(ulp.max()):.0f} ulp, "
          f"{float((np.abs(a - b)[lit] / np.abs(a[lit])).max()):.2g} relative")
    print(f"portable vs portable again (two processes): {int((b != c).sum())} values differ")
    print(f"render time portable / host: {seconds['portable'] / seconds['host']:.2f} "
          f"({seconds['portable']:.3f} s / {seconds['host']:.3f} s, fastest of {REPEATS})")


if __name__ == "__main__":
    main()
