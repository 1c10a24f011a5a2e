"""Import Mitsuba 3 with a working Dr.Jit LLVM backend, or fall back to scalar.

Dr.Jit's LLVM backend aborts (uncatchably) with Debian's default libLLVM 14/15;
LLVM >= 17 works (docs/physics.md, "Facts measured"). :func:`mitsuba` points
``DRJIT_LIBLLVM_PATH`` at such a library *before* the first ``import mitsuba``
when the user has not set it, and selects the variant the generator renders
with:

- ``llvm_ad_mono_polarized`` (default): vectorised; rendered once per colour
  channel, which reproduces RGB exactly.
- ``scalar_spectral_polarized`` (fallback, with a warning): when no LLVM >= 17
  is found. All spectra the generator builds are wavelength-independent, so any
  one wavelength of a spectral render is the exact mono value. Slow: pixels
  are traced one by one in Python.

``NEARLIGHT_MITSUBA_VARIANT`` (one of the two names) forces a variant, e.g. to
check the fallback on a machine that has LLVM. The LLVM variant compiles for
one portable target on every x86-64-v3 CPU (:mod:`nearlight.generator.jit_target`).
"""

from __future__ import annotations

import glob
import os
import re
import warnings
from functools import cache
from types import ModuleType

from ..errors import UserError, require_extra
from . import jit_target

LLVM_VARIANT = "llvm_ad_mono_polarized"
SCALAR_VARIANT = "scalar_spectral_polarized"
#: Oldest LLVM major version Dr.Jit 1.5 works with on these machines.
MIN_LLVM = 17
_SEARCH = ("/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/usr/lib64", "/usr/lib", "/usr/local/lib")


class ScalarFallbackWarning(UserWarning):
    """Rendering falls back to Mitsuba's slow scalar variant (no usable LLVM)."""


def find_libllvm() -> str | None:
    """Path of the newest ``libLLVM`` with major version >= 17, or None."""
    best: tuple[int, str] | None = None
    for folder in _SEARCH:
        for path in glob.glob(os.path.join(folder, "libLLVM*.so*")) + glob.glob("/usr/lib/llvm-*/lib/libLLVM*.so*"):
            m = re.search(r"libLLVM(?:-|\.so\.)(\d+)", os.path.basename(path))
            if m and int(m.group(1)) >= MIN_LLVM and (best is None or int(m.group(1)) > best[0]):
                best = (int(m.group(1)), path)
    return None if best is None else best[1]


def planned_variant() -> tuple[str, str | None]:
    """The variant :func:`mitsuba` will select, and the libLLVM it will use, without importing Mitsuba.

    Returns
    -------
    variant : str
        :data:`LLVM_VARIANT` or :data:`SCALAR_VARIANT`.
    libllvm : str or None
        ``DRJIT_LIBLLVM_PATH`` when the user set it, else the library
        :func:`find_libllvm` found (None for the scalar variant).

    Raises
    ------
    UserError
        ``NEARLIGHT_MITSUBA_VARIANT`` names neither variant.
    """
    forced = os.environ.get("NEARLIGHT_MITSUBA_VARIANT")
    if forced not in (None, "", LLVM_VARIANT, SCALAR_VARIANT):
        raise UserError(f"NEARLIGHT_MITSUBA_VARIANT: expected {LLVM_VARIANT} or {SCALAR_VARIANT}, got {forced!r}")
    if forced == SCALAR_VARIANT:
        return SCALAR_VARIANT, None
    lib = os.environ.get("DRJIT_LIBLLVM_PATH") or find_libllvm()
    if forced == LLVM_VARIANT or lib is not None:
        return LLVM_VARIANT, lib
    return SCALAR_VARIANT, None


@cache
def mitsuba() -> ModuleType:
    """The ``mitsuba`` module with the generator's variant set (see module doc).

    Returns
    -------
    module
        ``mitsuba``; ``mitsuba.variant()`` is :data:`LLVM_VARIANT` or
        :data:`SCALAR_VARIANT`.

    Raises
    ------
    MissingExtra
        Mitsuba or Dr.Jit is not installed (``pip install 'nearlight[render]'``).
    """
    require_extra("render")  # a plain install has no renderer: one line naming the extra
    variant, lib = planned_variant()
    if lib is not None and "DRJIT_LIBLLVM_PATH" not in os.environ:
        os.environ["DRJIT_LIBLLVM_PATH"] = lib
    import mitsuba as mi

    if variant == SCALAR_VARIANT and not os.environ.get("NEARLIGHT_MITSUBA_VARIANT"):
        warnings.warn(
            f"no libLLVM >= {MIN_LLVM} found (set DRJIT_LIBLLVM_PATH); rendering with the slow "
            f"{SCALAR_VARIANT} variant",
            ScalarFallbackWarning,
            stacklevel=2,
        )
    mi.set_variant(variant)
    if variant == LLVM_VARIANT:
        jit_target.apply(mi)
    from . import bsdfs, lamp

    bsdfs.register(mi)
    lamp.register(mi)
    return mi


def is_scalar(mi: ModuleType) -> bool:
    """Whether ``mi`` runs a scalar (one ray at a time) variant."""
    return mi.variant().startswith("scalar")
