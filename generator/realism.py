"""Realism profiles: one scene key, ``realism``, naming a set of nuisance values.

``realism: none`` (the default) is the ideal world every scene had before
nuisances existed. ``lab``, ``bench`` and ``rough`` read like a tidy lab
setup, a careful real bench (what Hara et al. §4.2 describe: a halogen lamp
"small enough" to be a point, a light-stripe range finder, a colour CCD behind
a rotated filter) and a hurried setup. A profile fills in the scene keys it
names; any key the scene sets itself wins (``--set realism=bench --set
nuisances.analyzer.jitter_deg=0`` is the bench without jitter). Where each
number comes from: ``docs/scene-files.md``, "Nuisances".
"""

from __future__ import annotations

import copy
from typing import Any

#: Profile name -> scene keys (nested like the scene file) it sets.
PROFILES: dict[str, dict[str, Any]] = {
    "none": {},
    "lab": {
        "lamp": {"polarizer_extinction_ratio": 1000.0, "radius": 0.002},
        "nuisances": {
            "analyzer": {"extinction_ratio": 1000.0, "offset_deg": 0.1, "jitter_deg": 0.05},
            "camera": {"vignetting": 0.05, "flicker": 0.002},
            "range": {"shift_px": [0.1, 0.0], "quantum_m": 0.00005},
            "calibration": {"position_m": [0.0005, 0.0, 0.0], "rotation_deg": [0.05, 0.0, 0.0]},
        },
    },
    "bench": {
        "lamp": {"polarizer_extinction_ratio": 300.0, "anisotropy_k": 1.0, "radius": 0.005},
        "nuisances": {
            "analyzer": {"extinction_ratio": 300.0, "offset_deg": 0.5, "jitter_deg": 0.3},
            "camera": {"vignetting": 0.15, "flicker": 0.01, "white_balance": [1.05, 1.0, 0.95]},
            "range": {"holes_shiny_above": 0.9, "holes_dark_below": 0.02, "shift_px": [0.3, 0.2], "quantum_m": 0.0002},
            "calibration": {"position_m": [0.002, -0.001, 0.001], "rotation_deg": [0.2, -0.1, 0.1]},
        },
    },
    "rough": {
        "lamp": {"polarizer_extinction_ratio": 100.0, "anisotropy_k": 3.0, "radius": 0.015},
        "nuisances": {
            "analyzer": {"extinction_ratio": 100.0, "offset_deg": 2.0, "jitter_deg": 1.0},
            "camera": {"vignetting": 0.3, "gamma": 2.2, "flicker": 0.03, "white_balance": [1.2, 1.0, 0.85]},
            "range": {"holes_shiny_above": 0.6, "holes_dark_below": 0.05, "shift_px": [0.7, -0.5], "quantum_m": 0.001},
            "calibration": {"position_m": [0.005, -0.003, 0.003], "rotation_deg": [0.5, -0.3, 0.3]},
        },
    },
}


def _merge(profile: dict[str, Any], scene: dict[str, Any]) -> dict[str, Any]:
    """``scene`` with ``profile``'s keys filled in where ``scene`` has none (nested sections merged)."""
    out = dict(scene)
    for key, value in profile.items():
        if key not in out:
            out[key] = copy.deepcopy(value)
        elif isinstance(value, dict) and isinstance(out[key], dict):
            out[key] = _merge(value, out[key])
    return out


def expand(data: Any) -> Any:
    """A scene document with its ``realism`` profile's values filled in (explicit keys win).

    The profile's ``lamp`` keys go into ``lamp``, or into every lamp of a ``lamps`` list.

    Anything that is not a mapping with a known profile name is returned as is
    (the scene schema then names what is wrong).
    """
    if not isinstance(data, dict):
        return data
    name = data.get("realism", "none")
    if not isinstance(name, str) or name not in PROFILES or not PROFILES[name]:
        return data
    profile = PROFILES[name]
    lamps = data.get("lamps")
    if "lamp" in data or not isinstance(lamps, list):
        return _merge(profile, data)
    # several lamps (``lamps:``): the profile's lamp keys fill in every lamp
    out = _merge({k: v for k, v in profile.items() if k != "lamp"}, data)
    out["lamps"] = [_merge(profile.get("lamp", {}), lamp) if isinstance(lamp, dict) else lamp for lamp in lamps]
    return out
