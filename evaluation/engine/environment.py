"""The environment a sweep ran in, recorded beside its results, and what differs between two.

A regression check on another machine is only as good as what it knows about
the two machines: Dr.Jit's LLVM backend compiles for the host CPU (vector
width, FMA, AVX-512 ``rsqrt14``), so renders differ in their last bits between
CPUs, and package versions change estimator internals. :func:`collect` names
what matters without importing Mitsuba (the variant is the one the generator
will choose, :func:`nearlight.generator.llvm.planned_variant`);
:func:`differences` lists what two records disagree on, for ``compare``.
"""

from __future__ import annotations

import functools
import os
import platform
import subprocess
from collections.abc import Mapping
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

from ... import __version__

#: The package's root folder (the repository root in a checkout): this file's folder, one level up per
#: dot of its module name below ``nearlight``.
PACKAGE_ROOT = Path(__file__).resolve().parents[__name__.count(".") - 1]
#: Distributions whose versions can change a number in a result row.
PACKAGES = ("nearlight", "mitsuba", "drjit", "numpy", "scipy", "pandas", "OpenEXR", "pyarrow", "threadpoolctl")
#: CPU features that change Dr.Jit's generated code (and so a render's last bits).
CPU_FLAGS = ("sse4_2", "avx", "avx2", "fma", "avx512f", "avx512er")


@functools.lru_cache(maxsize=1)
def code_version() -> str:
    """``<package version>+g<commit>[.dirty]`` of the running nearlight (commit when in a git checkout).

    ``.dirty`` when a tracked file outside ``reports/`` differs from the commit.
    """
    try:
        commit = subprocess.run(
            ["git", "-C", str(PACKAGE_ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True, timeout=10
        ).stdout.strip()
        if commit and subprocess.run(
            # reports/ holds outputs, not code: regenerating a committed report in place
            # (its old files deleted first) must not stamp its own rows ".dirty"
            ["git", "-C", str(PACKAGE_ROOT), "status", "--porcelain", "--untracked-files=no",
             "--", ".", ":(exclude)reports"],
            capture_output=True, text=True, timeout=10,
        ).stdout.strip():
            commit += ".dirty"
    except (OSError, subprocess.SubprocessError):
        commit = ""
    return f"{__version__}+g{commit}" if commit else __version__


def _cpu() -> tuple[str, list[str]]:
    model, flags = platform.processor() or platform.machine(), set()
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as fh:
            for line in fh:
                key, _, value = line.partition(":")
                if key.strip() == "model name":
                    model = value.strip()
                elif key.strip() in ("flags", "Features"):
                    flags = set(value.split())
                    break
    except OSError:
        pass
    return model, [f for f in CPU_FLAGS if f in flags]


def machine() -> str:
    """One line naming the machine: CPU model, cores, operating system and architecture (a scorecard's
    ``machine``, as a results file's header states it)."""
    return f"{_cpu()[0]}, {os.cpu_count()} cores, {platform.system()} {platform.machine()}"


def collect() -> dict[str, Any]:
    """The environment of this process, as a JSON-ready dict.

    Returns
    -------
    dict
        ``code_version`` (package version and git commit), ``python``,
        ``platform``, ``cpu`` (model name), ``cpu_flags`` (those of
        :data:`CPU_FLAGS` present), ``mitsuba_variant`` (what the generator
        will render with), ``jit_target`` (the LLVM target its kernels are
        compiled for, :func:`nearlight.generator.jit_target.planned_target`;
        absent for the scalar variant), ``packages`` (name -> version, None
        when absent).
    """
    from ...generator.jit_target import planned_target
    from ...generator.llvm import LLVM_VARIANT, planned_variant

    model, flags = _cpu()
    variant = planned_variant()[0]
    packages: dict[str, str | None] = {}
    for name in PACKAGES:
        try:
            packages[name] = version(name)
        except PackageNotFoundError:
            packages[name] = None
    return {
        "code_version": code_version(),
        "python": platform.python_version(),
        "platform": f"{platform.system()} {platform.machine()}",
        "cpu": model,
        "cpu_flags": flags,
        "mitsuba_variant": variant,
        **({"jit_target": planned_target()} if variant == LLVM_VARIANT else {}),
        "packages": packages,
    }


def _flat(env: Mapping[str, Any]) -> dict[str, Any]:
    out = {k: v for k, v in env.items() if k != "packages"}
    out.update({f"packages.{k}": v for k, v in env.get("packages", {}).items()})
    return out


def differences(new: Mapping[str, Any] | None, base: Mapping[str, Any] | None) -> list[str]:
    """What differs between two :func:`collect` records, one printable line each.

    Parameters
    ----------
    new, base : mapping or None
        None when a results folder holds no record (made before records existed).

    Returns
    -------
    list of str
        ``"key: base value -> new value"``; empty when they agree.
    """
    if new is None or base is None:
        which = "baseline" if base is None else "new results"
        return [f"environment: the {which} folder records none (made before nearlight recorded it)"]
    a, b = _flat(base), _flat(new)
    return [f"{k}: {a.get(k)!r} -> {b.get(k)!r}" for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)]
