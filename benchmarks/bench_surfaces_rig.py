"""The fitted surface on the captures that broke ``full``: a millimetre depth map's round trip, the bench rig.

Two measurements of issue 34, before the stage is wired into the estimators:

* **the rig round trip with a millimetre PNG depth map** (as
  ``tests/rig/test_roundtrip.py``: an analytic board exported as raw rig
  files, full well 1e6 e⁻, depth in 1-mm steps, imported back): ``full``'s
  change of lamp against its estimate on the original, % of the camera–lamp
  distance, with the normals derived today and with the fitted surface's
  points and normals (``estimator.surfaces.fit_surface``), at 128×96,
  256×192 and 320×240 (the issue's bar: ≤ 2 % at the last two);
* **the paper's bench rig** (``nearlight render`` of ``scenes/bookend.yaml``
  and ``scenes/torus.yaml`` with ``realism: bench``, the reproduction's real
  camera noise, seed 0; Mitsuba): ``full``'s lamp error, % of the highlight–lamp
  distance scored against the capture's own (quantised) ``P``, as the capture
  is and with the fitted surface.

Needs the ``rig`` extra (polanalyser) and Mitsuba. Printed, not asserted.

Usage::

    .venv/bin/python benchmarks/bench_surfaces_rig.py      # about a minute
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from nearlight.capture import read_capture, write_capture
from nearlight.estimator import estimate
from nearlight.estimator.geometry import capture_rays
from nearlight.estimator.surfaces import fit_surface
from nearlight.evaluation.scoring.metrics import score
from nearlight.generator.analytic import analytic_capture
from nearlight.rig.export import export_rig
from nearlight.rig.importer import import_rig

ROOT = Path(__file__).resolve().parent.parent
CAMERA = "capture.noise={full_well: 20000, read_noise: 5.0, bits: 12, saturation: auto}"  # sweeps/paper/*.yaml


def fitted(cap):
    """The capture with the fitted surface's points and normals in place of its own."""
    fs = fit_surface(cap.P, cap.camera.position, capture_rays(cap))
    return cap.replace(P=fs.P.astype(np.float32), N=fs.N), fs


def round_trip(tmp: Path) -> None:
    print("rig round trip, 1-mm PNG depth: full's lamp change, % of the camera-lamp distance (today -> fitted)")
    for size in ((128, 96), (256, 192), (320, 240)):
        cap = analytic_capture(width=size[0], height=size[1])
        d = tmp / f"rt{size[0]}"
        write_capture(cap, d / "orig")
        export_rig(read_capture(d / "orig"), d / "rig", mosaic="mono", full_well=1e6, depth_scale=1e-3)
        import_rig(d / "rig" / "rig.yaml", d / "imp")
        imp = read_capture(d / "imp")
        e0 = estimate(cap, method="full").lamp_position
        ref = np.linalg.norm(e0 - cap.camera.position)
        fit, fs = fitted(imp)
        today, new = (100 * np.linalg.norm(estimate(c, method="full").lamp_position - e0) / ref for c in (imp, fit))
        print(f"  {size[0]}x{size[1]}: {today:.3g} -> {new:.3g}   ({fs.kind}, {fs.model})", flush=True)


def bench_rig(tmp: Path) -> None:
    print("\nthe bench rig, seed 0: full's lamp error, % of the highlight-lamp distance (as captured -> fitted)")
    for scene in ("bookend", "torus"):
        out = tmp / scene
        subprocess.run([sys.executable, "-m", "nearlight", "render", str(ROOT / "scenes" / f"{scene}.yaml"),
                        "--out", str(out), "--set", "realism=bench", "--set", CAMERA, "--set", "capture.seed=0",
                        "--quiet"], check=True, stdout=subprocess.DEVNULL)
        cap = read_capture(out)
        truth = cap.replace(N=np.asarray(cap.extra["truth_N"]))  # scored with the exact normals the render kept
        fit, fs = fitted(cap)
        errors = [score(truth, estimate(c, method="full"))["lamp_position_error_pct"] for c in (cap, fit)]
        print(f"  {scene}: {errors[0]:.3g} -> {errors[1]:.3g}   ({fs.kind}, {fs.model})", flush=True)


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        round_trip(Path(tmp))
        bench_rig(Path(tmp))


if __name__ == "__main__":
    main()
