"""Benchmark: do renders change with Dr.Jit's LLVM target, and is a forced target deterministic?

Dr.Jit compiles every kernel for the CPU it runs on (target CPU, features,
vector width), so two CPUs emit different code and the renders differ in
their last bits. drjit 1.5's Python module does not wrap
``jit_llvm_set_target``, but ``libdrjit-core.so`` exports it (C++ names
``jit_llvm_set_target(const char*, const char*, uint32_t)`` and the three
getters), so ctypes can force one target. This script renders
``scenes/ts_board.yaml`` at 160×120 in fresh processes (a target applies to
kernels compiled after it is set): with the target left alone, and twice
forced to ``x86-64-v3`` / ``+avx2,+fma`` / 8 lanes, a target every x86-64
CPU of the last decade runs. It prints each run's target and stack hash,
how many values the forced target changes (and by how many ulp), and whether
two forced runs agree bit for bit.

What it cannot show on one machine: that the forced target gives the same
bits on another CPU (Embree, which Mitsuba's ray tests use, picks its own
instruction set at run time as well). Printed, not asserted.

    .venv/bin/python benchmarks/bench_jit_target.py
"""

from __future__ import annotations

import ctypes
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
FORCED = (b"x86-64-v3", b"+avx2,+fma", 8)
# libdrjit-core's C++ entry points (the Python module does not wrap them)
SET_TARGET = "_Z19jit_llvm_set_targetPKcS0_j"
GETTERS = ("_Z19jit_llvm_target_cpuv", "_Z24jit_llvm_target_featuresv", "_Z21jit_llvm_vector_widthv")


def _render(mode: str, out: str) -> None:
    """In this process: force the target (``mode == "forced"``), render, save the stack to ``out``."""
    import drjit
    import mitsuba as mi

    from nearlight.generator import load_scene, render_clean

    core = ctypes.CDLL(os.path.join(os.path.dirname(drjit.__file__), "libdrjit-core.so"))
    cpu, features, width = (getattr(core, name) for name in GETTERS)
    cpu.restype = features.restype = ctypes.c_char_p
    width.restype = ctypes.c_uint32
    mi.set_variant("llvm_ad_mono_polarized")
    drjit.eval(drjit.llvm.Float(1.0))  # the LLVM backend is initialised: a target set now stays
    if mode == "forced":
        setter = getattr(core, SET_TARGET)
        setter.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_uint32]
        setter(*FORCED)
    scene = load_scene(SCENE, overrides={"camera.resolution": [160, 120]})
    t = time.perf_counter()
    stack = np.asarray(render_clean(scene, progress=False).stack)
    seconds = time.perf_counter() - t
    np.save(out, stack)
    print(f"{mode:8s} target {cpu().decode()}, {width()} lanes, features {features().decode()[:40]}...; "
          f"render {seconds:.2f} s (with Dr.Jit's kernel cache); stack sha256 "
          f"{hashlib.sha256(stack.tobytes()).hexdigest()[:16]}")


def main() -> None:
    if len(sys.argv) == 3:
        _render(sys.argv[1], sys.argv[2])
        return
    with tempfile.TemporaryDirectory() as tmp:
        stacks = {}
        for run in ("default", "forced", "forced again"):
            out = os.path.join(tmp, run.replace(" ", "_") + ".npy")
            subprocess.run([sys.executable, __file__, run.split()[0], out], check=True)
            stacks[run] = np.load(out)
    a, b, c = stacks["default"], stacks["forced"], stacks["forced again"]
    ulp = np.abs(a.astype(np.float64) - b) / np.spacing(np.maximum(np.abs(a), np.finfo(np.float32).tiny))
    lit = np.abs(a) > 0
    print(f"default vs forced: {int((a != b).sum())} of {a.size} values differ "
          f"({100 * float((a != b).mean()):.1f} %), at most {float(ulp.max()):.0f} ulp, "
          f"{float((np.abs(a - b)[lit] / np.abs(a[lit])).max()):.2g} relative")
    print(f"forced vs forced again (two processes): {int((b != c).sum())} values differ")


if __name__ == "__main__":
    main()
