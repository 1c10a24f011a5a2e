"""The portable LLVM target (:mod:`nearlight.generator.jit_target`): chosen, set, recorded, refused."""

from __future__ import annotations

import pytest

from nearlight.errors import UserError
from nearlight.generator import jit_target


def test_the_portable_target_is_planned_on_an_avx2_cpu(monkeypatch):
    monkeypatch.delenv(jit_target.ENV, raising=False)
    monkeypatch.setattr(jit_target, "_cpu_flags", lambda: {"avx", "avx2", "fma", "avx512f"})
    monkeypatch.setattr(jit_target.platform, "machine", lambda: "x86_64")
    assert jit_target.planned_target() == "x86-64-v3 +avx2,+fma 8 lanes"


@pytest.mark.parametrize("flags, machine", [({"avx", "sse4_2"}, "x86_64"), ({"avx2", "fma"}, "aarch64")])
def test_a_cpu_that_cannot_run_it_keeps_the_host_target(monkeypatch, flags, machine):
    monkeypatch.delenv(jit_target.ENV, raising=False)
    monkeypatch.setattr(jit_target, "_cpu_flags", lambda: flags)
    monkeypatch.setattr(jit_target.platform, "machine", lambda: machine)
    assert jit_target.planned_target() == "host (this CPU has no AVX2 and FMA)"


def test_host_on_request_and_a_bad_value_is_one_line(monkeypatch):
    monkeypatch.setenv(jit_target.ENV, "host")
    assert jit_target.planned_target() == "host (NEARLIGHT_JIT_TARGET=host)"
    monkeypatch.setenv(jit_target.ENV, "avx512")
    with pytest.raises(UserError, match=r"^NEARLIGHT_JIT_TARGET: expected portable or host, got 'avx512'$"):
        jit_target.planned_target()


def test_the_renderer_compiles_for_the_planned_target():
    # The setter's effect, read back from Dr.Jit's own getters after the generator set up Mitsuba.
    pytest.importorskip("mitsuba")
    from nearlight.evaluation.engine.environment import collect
    from nearlight.generator.llvm import mitsuba

    mitsuba()
    planned = jit_target.planned_target()
    if planned.startswith("host"):
        pytest.skip(f"this machine keeps the host target: {planned}")
    assert jit_target.current() == planned == collect()["jit_target"]
