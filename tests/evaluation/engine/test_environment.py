"""The environment record beside results, and the pinned set of versions the README's set-up installs."""

from __future__ import annotations

import re
from importlib.metadata import version
from pathlib import Path

from nearlight.evaluation.engine.environment import PACKAGES, collect, differences

ROOT = Path(__file__).resolve().parents[3]


def _pins() -> dict[str, str]:
    pins = {}
    for line in (ROOT / "constraints.txt").read_text().splitlines():
        m = re.match(r"^([A-Za-z0-9_.\-]+)==(\S+)$", line.strip())
        if m:
            pins[m.group(1).lower().replace("_", "-")] = m.group(2)
    return pins


def test_installed_versions_are_the_pinned_ones():
    # scripts/setup installs with `-c constraints.txt`: the baselines under reports/ were made with these
    # versions, so a drifted environment would make their verdicts say nothing.
    pins = _pins()
    numeric = [p for p in PACKAGES if p != "nearlight"]
    assert all(p.lower() in pins for p in numeric), sorted(set(p.lower() for p in numeric) - set(pins))
    drift = {p: (pins[p.lower()], version(p)) for p in numeric if version(p) != pins[p.lower()]}
    assert drift == {}, f"installed != constraints.txt (pinned, installed): {drift}; run: bash scripts/setup"


def test_environment_record_and_differences():
    env = collect()
    assert set(env) == {"code_version", "python", "platform", "cpu", "cpu_flags", "mitsuba_variant", "jit_target", "packages"}
    assert env["packages"]["numpy"] == version("numpy") and env["cpu"]
    assert differences(env, env) == []
    other = {**env, "cpu": "another CPU", "packages": {**env["packages"], "numpy": "0.0"}}
    assert differences(other, env) == [
        f"cpu: {env['cpu']!r} -> 'another CPU'",
        f"packages.numpy: {env['packages']['numpy']!r} -> '0.0'",
    ]
    assert "records none" in differences(env, None)[0]
