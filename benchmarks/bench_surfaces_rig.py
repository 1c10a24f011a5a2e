"""The geometry stage on the captures that broke ``full``: a millimetre depth map's round trip, the bench rig.

Two measurements of issue 34:

* **the rig round trip with a millimetre PNG depth map** (as
  ``tests/rig/test_roundtrip.py``: an analytic board exported as raw rig
  files, full well 1e6 e⁻, depth in 1-mm steps, imported back): ``full``'s
  change of lamp against its estimate on the original, % of the camera–lamp
  distance, at 128×96, 256×192 and 320×240 (the issue's bar: ≤ 2 % at the
  last two);
* **the paper's bench rig** (``nearlight render`` of ``scenes/bookend.yaml``
  and ``scenes/torus.yaml`` with ``realism: bench``, the reproduction's real
  camera noise, seed 0; Mitsuba): ``full``'s lamp error, % of the highlight–lamp
  distance scored against the capture's own (quantised) ``P``.

Each twice: the range's error as the capture's ``rig.range`` states it (what
the import and the generator write) and as the estimator measures it with
``rig.range`` removed (``estimator.range_error.measured_range``), with the
surface the geometry stage fitted and the model it took.

Needs the ``rig`` extra (polanalyser) and Mitsuba. Printed, not asserted.

Usage::

    .venv/bin/python benchmarks/bench_surfaces_rig.py      # about a minute
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from nearlight.capture import read_capture, write_capture
from nearlight.estimator import estimate
from nearlight.estimator.geometry import surface_geometry
from nearlight.evaluation.scoring.metrics import score
from nearlight.generator.analytic import analytic_capture
from nearlight.rig.export import export_rig
from nearlight.rig.importer import import_rig

ROOT = Path(__file__).resolve().parent.parent
CAMERA = "capture.noise={full_well: 20000, read_noise: 5.0, bits: 12, saturation: auto}"  # sweeps/paper/*.yaml


def unstated(cap):
    """The capture with its ``rig.range`` removed: the estimator measures the range's error."""
    return cap.replace(rig=dataclasses.replace(cap.rig, range=None))


def how(cap) -> str:
    """The surface the geometry stage fitted and the range model it took, in a few words."""
    g = surface_geometry(cap).summary
    r = g["range"]
    err = f"q {r['quantum_m'] * 1e3:.3g} mm" if r["quantum_m"] else f"σ {r['sigma_m'] * 1e3:.3g} mm"
    return f"{g['surface']}, {err} along {r['axis']}, {r['source']}"


def round_trip(tmp: Path) -> None:
    print("rig round trip, 1-mm PNG depth: full's lamp change, % of the camera-lamp distance (rig.range stated -> "
          "measured)")
    for size in ((128, 96), (256, 192), (320, 240)):
        cap = analytic_capture(width=size[0], height=size[1])
        d = tmp / f"rt{size[0]}"
        write_capture(cap, d / "orig")
        export_rig(read_capture(d / "orig"), d / "rig", mosaic="mono", full_well=1e6, depth_scale=1e-3)
        import_rig(d / "rig" / "rig.yaml", d / "imp")
        imp = read_capture(d / "imp")
        e0 = estimate(cap, method="full").lamp_position
        ref = np.linalg.norm(e0 - cap.camera.position)
        caps = (imp, unstated(imp))
        stated, measured = (100 * np.linalg.norm(estimate(c, method="full").lamp_position - e0) / ref for c in caps)
        print(f"  {size[0]}x{size[1]}: {stated:.3g} -> {measured:.3g}   ({how(caps[0])} -> {how(caps[1])})",
              flush=True)


def bench_rig(tmp: Path) -> None:
    print("\nthe bench rig, seed 0: full's lamp error, % of the highlight-lamp distance (rig.range stated -> "
          "measured)")
    for scene in ("bookend", "torus"):
        out = tmp / scene
        subprocess.run([sys.executable, "-m", "nearlight", "render", str(ROOT / "scenes" / f"{scene}.yaml"),
                        "--out", str(out), "--set", "realism=bench", "--set", CAMERA, "--set", "capture.seed=0",
                        "--quiet"], check=True, stdout=subprocess.DEVNULL)
        cap = read_capture(out)
        truth = cap.replace(N=np.asarray(cap.extra["truth_N"]))  # scored with the exact normals the render kept
        caps = (cap, unstated(cap))
        errors = [score(truth, estimate(c, method="full"))["lamp_position_error_pct"] for c in caps]
        print(f"  {scene}: {errors[0]:.3g} -> {errors[1]:.3g}   ({how(caps[0])} -> {how(caps[1])})", flush=True)


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        round_trip(Path(tmp))
        bench_rig(Path(tmp))


if __name__ == "__main__":
    main()
