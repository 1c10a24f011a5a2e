"""One LLVM target for every render: the same generated code on every x86-64-v3 CPU.

Dr.Jit's LLVM backend compiles each kernel for the CPU it runs on (its name,
its feature flags, its vector width). An AVX-512 CPU gets 16-lane kernels with
AVX-512's own reciprocal square root, an AVX2 CPU 8-lane ones, and the
renders differ in their last bits (up to 354 ulp measured,
docs/measurements/cross-cpu-renders.md). Those bits are enough to flip a
brightest pixel: remade on an AVX-512 Xeon instead of an AVX2 EPYC, the
first-stage study's printed median moved 54.3 → 55.2 %.

drjit 1.5's Python module does not wrap ``jit_llvm_set_target``, but
``libdrjit-core.so`` exports it (C++ linkage, :data:`SETTER`), so
:func:`apply` sets the :data:`PORTABLE` target through ctypes once the LLVM
backend is initialised and before the first kernel compiles
(:func:`nearlight.generator.llvm.mitsuba` calls it). With it, this project's
AVX-512 EPYC reproduced the AVX2 EPYC's first-stage study: all 541 numbers
within the reproduction's tolerances, no brightest pixel flipped (where the
host target flipped 45 of them). Its cost at 640×480 is a render 10–20 %
slower, a few hundredths of a second (``benchmarks/bench_jit_target.py``).

``NEARLIGHT_JIT_TARGET=host`` keeps Dr.Jit's own choice (faster on wide
CPUs, different last bits from CPU to CPU). A CPU without AVX2 and FMA (or not
x86-64) keeps the host target: a forced AVX2 kernel would not run there.
Either way :func:`planned_target` names the target, and
``environment.json`` records it (``jit_target``), so a check of two runs knows
whether they rendered with the same code.
"""

from __future__ import annotations

import ctypes
import os
import platform
import warnings
from types import ModuleType

from ..errors import UserError

#: Environment variable choosing the target: ``portable`` (the default) or ``host``.
ENV = "NEARLIGHT_JIT_TARGET"
#: Target CPU, LLVM feature string and vector width every x86-64-v3 CPU (Haswell, Zen 1 and later) runs.
PORTABLE = ("x86-64-v3", "+avx2,+fma", 8)
#: ``jit_llvm_set_target(const char *cpu, const char *features, uint32_t vector_width)`` in libdrjit-core.
SETTER = "_Z19jit_llvm_set_targetPKcS0_j"
#: The getters of the target in effect: cpu, features, vector width.
GETTERS = ("_Z19jit_llvm_target_cpuv", "_Z24jit_llvm_target_featuresv", "_Z21jit_llvm_vector_widthv")


class HostTargetWarning(UserWarning):
    """The portable target could not be set: renders use the host CPU's own target."""


def _cpu_flags() -> set[str]:
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as fh:
            for line in fh:
                key, _, value = line.partition(":")
                if key.strip() == "flags":
                    return set(value.split())
    except OSError:
        pass
    return set()


def describe(target: tuple[str, str, int]) -> str:
    """``"x86-64-v3 +avx2,+fma 8 lanes"``: a target as recorded in ``environment.json``."""
    cpu, features, width = target
    return f"{cpu} {features} {width} lanes"


def planned_target() -> str:
    """The target :func:`apply` will set, as recorded: :func:`describe` of :data:`PORTABLE`, or ``host (...)``.

    Raises
    ------
    UserError
        :data:`ENV` is neither ``portable`` nor ``host``.
    """
    choice = os.environ.get(ENV, "") or "portable"
    if choice not in ("portable", "host"):
        raise UserError(f"{ENV}: expected portable or host, got {choice!r}")
    if choice == "host":
        return f"host ({ENV}=host)"
    if platform.machine() not in ("x86_64", "AMD64") or not {"avx2", "fma"} <= _cpu_flags():
        return "host (this CPU has no AVX2 and FMA)"
    return describe(PORTABLE)


def _core() -> ctypes.CDLL:
    import drjit

    return ctypes.CDLL(os.path.join(os.path.dirname(drjit.__file__), "libdrjit-core.so"))


def current() -> str:
    """The target Dr.Jit's LLVM backend compiles for now, as :func:`describe` writes it."""
    core = _core()
    cpu, features, width = (getattr(core, name) for name in GETTERS)
    cpu.restype = features.restype = ctypes.c_char_p
    width.restype = ctypes.c_uint32
    return describe((cpu().decode(), features().decode(), int(width())))


def apply(mi: ModuleType) -> str:
    """Set :func:`planned_target` on the LLVM backend of ``mi`` (a Mitsuba with an LLVM variant set).

    Returns
    -------
    str
        What was set (:func:`planned_target`), or ``host (...)`` with the reason when libdrjit-core
        does not export :data:`SETTER` (another drjit version): then with a :class:`HostTargetWarning`.
    """
    planned = planned_target()
    if planned.startswith("host"):
        return planned
    import drjit

    drjit.eval(drjit.llvm.Float(1.0))  # initialise the backend first: initialising it sets the host target
    try:
        setter = getattr(_core(), SETTER)
    except (OSError, AttributeError):
        warnings.warn(f"drjit {drjit.__version__}'s libdrjit-core has no {SETTER}: rendering with the host "
                      "CPU's own LLVM target (renders differ in their last bits from CPU to CPU)",
                      HostTargetWarning, stacklevel=2)
        return "host (libdrjit-core exports no jit_llvm_set_target)"
    setter.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_uint32]
    setter(PORTABLE[0].encode(), PORTABLE[1].encode(), PORTABLE[2])
    return planned
