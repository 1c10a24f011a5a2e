"""Paper reproduction: the paper's experiments on physically-based renders.

``nearlight reproduce`` renders paper-like scenes with the generator, runs the
estimator's methods on them, and writes ``paper_reproduction.md`` (tables and
figures) and ``paper_reproduction.json`` (every number of the report) into one
folder. Every number in the report comes from the run; the paper's own numbers
are quoted in :data:`PAPER` with their section.

Experiments (Hara, Nishino, Nakazawa, Ikeuchi 2002):

* ``board`` — §4.1: a large Ward board in the middle of the image, lamp at the
  paper's (13, 2, 3). The paper gives neither unit nor camera; our layout is
  in ``scenes/ward_board.yaml`` (one paper unit = :data:`PAPER_UNIT_M` metres,
  the board centre at the origin, so the paper's coordinates are ours
  divided by the unit). Fig. 3: input specular vs. re-synthesis.
* ``bookend`` — §4.3: the blue bent plate with the paper's fitted σ** and Ks**
  as the truth, Torrance–Sparrow, separated from the analyzer stack
  (Fig. 5: original, diffuse, specular; Fig. 6: re-synthesis, composite).
* ``curved`` — Fig. 7: a curved object, the same four panels.
* ``near_vs_distant`` — the paper's motivation (its Fig. 1), measured: the
  Torrance–Sparrow board with the lamp moved along a ray from near to far; the
  ``distant`` baseline against the near-field methods.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from ..capture import Capture
from ..errors import UserError
from ..files.figures import panel_grid, save_png, tonemap
from ..files.jsonable import jsonable
from ..physics.polarization import through_polarizer

#: The paper's own numbers, quoted with their section (never computed here).
PAPER: dict[str, dict[str, Any]] = {
    "board": {
        "section": "§4.1",
        "lamp_true": (13.0, 2.0, 3.0),
        "lamp_first_stage": (11.81, 2.16, 3.051),  # L* after the initial estimation
        "sigma": 0.057,  # σ** after refinement (Ward truth: not comparable, as the paper says)
        "ks": (0.84, 0.85, 0.84),  # Ks** after refinement
    },
    "bookend": {
        "section": "§4.3",
        "lamp_first_stage": (-9.89, 6.95, 15.62),  # real object: no ground truth
        "sigma": 0.079,
        "ks": (0.29, 0.40, 0.34),
    },
}

#: Metres per paper unit for the §4.1 layout of ``scenes/ward_board.yaml``.
PAPER_UNIT_M = 0.05

#: The camera of the real-object experiments (§4.3): a 12-bit sensor with a
#: 20 000 e⁻ full well and 5 e⁻ read noise, the brightest pixel at 90 % of
#: the full well. The §4.1 board stays noise-free, as the paper's render was.
REAL_CAMERA = {"full_well": 20000.0, "read_noise": 5.0, "bits": 12, "saturation": "auto"}

#: Methods run on every paper scene: report label -> (method, options), in report order.
#: ``paper`` is the faithful reading of eq. 18 (E measured once, at the first
#: stage's t*); ``paper (radiance)`` is the same alternating minimisation on the
#: image itself, the reading under which refinement cannot favour a lamp that
#: moves onto the surface (see nearlight.estimator.paper).
NEAR_METHODS: dict[str, tuple[str, dict[str, Any]]] = {
    "paper-init": ("paper-init", {}),
    "paper": ("paper", {}),
    "paper (radiance)": ("paper", {"energy": "radiance"}),
    "full": ("full", {}),
}
ALL_METHODS: dict[str, tuple[str, dict[str, Any]]] = {"distant": ("distant", {}), **NEAR_METHODS}


@dataclasses.dataclass(frozen=True)
class Profile:
    """How big a run is.

    Attributes
    ----------
    name : str
    resolution : (int, int)
        Image width and height, pixels.
    analyzer_angles_deg : tuple of float
    distances_m : tuple of float
        Lamp distances of the near-vs-distant study, metres from the highlight.
    """

    name: str
    resolution: tuple[int, int]
    analyzer_angles_deg: tuple[float, ...]
    distances_m: tuple[float, ...]


#: ``--quick``: what the tests run (small images, a 4-angle polarization camera).
QUICK = Profile("quick", (160, 120), (0.0, 45.0, 90.0, 135.0), (0.15, 0.3, 0.6, 1.2))
#: The full run committed under ``reports/``.
FULL = Profile(
    "full",
    (640, 480),
    (0.0, 22.5, 45.0, 67.5, 90.0, 112.5, 135.0, 157.5),
    (0.1, 0.15, 0.2, 0.3, 0.45, 0.6, 0.9, 1.2, 2.0),
)


def scene_path(name: str) -> Path:
    """Path of a shipped scene file (``scenes/NAME``)."""
    from importlib.resources import files

    path = Path(str(files("nearlight.scenes") / name))
    if not path.is_file():
        raise UserError(f"{path}: shipped scene missing (reinstall nearlight)")
    return path


# --------------------------------------------------------------------------- running


class _Run:
    """Shared state of one reproduction: profile, folders, renders, progress."""

    def __init__(self, out: Path, profile: Profile, progress: bool):
        from tqdm.auto import tqdm

        self.out, self.profile = out, profile
        self.figures = out / "figures"
        self.cache = out / ".render-cache"
        self.bar = tqdm(total=3 + len(profile.distances_m), desc="reproduce", unit="scene", disable=not progress)

    def render(self, scene_file: str, overrides: Mapping[str, Any] | None = None) -> Capture:
        """Noise-free capture of a shipped scene at this profile's size.

        Samples per pixel stay the scene's: the generator traces pixel-centre
        rays, so one sample is exact for direct lighting.
        """
        from ..generator import load_scene, render_clean

        p = self.profile
        sets = {
            "camera.resolution": list(p.resolution),
            "capture.analyzer_angles_deg": list(p.analyzer_angles_deg),
            **(overrides or {}),
        }
        scene = load_scene(scene_path(scene_file), overrides=sets)
        self.bar.set_postfix_str(scene_file)
        return render_clean(scene, cache_dir=self.cache, progress=False)

    def estimate(self, capture: Capture, methods: Mapping[str, tuple[str, dict[str, Any]]]) -> dict[str, Any]:
        """``{label: Estimate}`` for each labelled ``(method, options)``."""
        from ..estimator import estimate

        return {label: estimate(capture, method=m, **opts) for label, (m, opts) in methods.items()}

    def figure(self, name: str, panels: list, **kw: Any) -> str:
        """Write a panel figure; return its path relative to the report."""
        return str(panel_grid(panels, self.figures / name, **kw).relative_to(self.out))


def _errors(capture: Capture, est: Any) -> dict[str, float]:
    """Lamp and reflectance errors of one estimate against the capture's truth."""
    from .tasks import score

    s = score(capture, est)
    return {k: (None if math.isnan(s[k]) else float(s[k])) for k in (
        "lamp_position_error_m", "lamp_position_error_pct", "direction_error_deg", "distance_error_m",
        "sigma_rel_error", "ks_rel_error", "specular_rmse_rel", "lamp_distance_true_m")}  # fmt: skip


def _method_row(capture: Capture, est: Any) -> dict[str, Any]:
    """One method's estimate and errors; ``None`` where a metric does not apply
    (σ and Ks errors against a Ward truth).

    Estimators fold the (unknown) lamp intensity reaching the surface into Ks;
    ``ks_in_truth_units`` divides it back out with the true intensity
    (``I_lamp / 2`` behind the ideal polarizer) so that it reads beside the
    truth and the paper's Ks**.
    """
    reaching = through_polarizer(capture.truth["lamp_intensity"])
    return {
        "lamp_position": [float(v) for v in est.lamp_position],
        "sigma": float(est.sigma),
        "ks": [float(v) for v in est.ks],
        "ks_in_truth_units": [float(v) for v in np.asarray(est.ks) / reaching],
        "runtime_s": float(sum(est.timings.values())),
        **_errors(capture, est),
    }


def _specular_views(capture: Capture) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Original (no analyzer), separated diffuse and specular images, ``[H, W, 3]`` each."""
    from ..estimator import separate

    spec, diff = separate(capture.stack, capture.analyzer_angles_deg, method="fit")
    return spec + diff, diff, spec


def _resynth(capture: Capture, est: Any) -> np.ndarray:
    from ..estimator import render_specular

    return np.nan_to_num(np.asarray(render_specular(capture, est), dtype=float))


def board_experiment(run: _Run) -> dict[str, Any]:
    """§4.1: the Ward board, lamp at the paper's (13, 2, 3) units."""
    cap = run.render("ward_board.yaml")
    ests = run.estimate(cap, NEAR_METHODS)
    _, _, spec = _specular_views(cap)
    white = float(np.percentile(spec[spec > 0], 99.5))
    fig = run.figure(
        "fig3_board.png",
        [("(a) input specular", tonemap(spec, white=white))]
        + [(f"(b) re-synthesised, {m}", tonemap(_resynth(cap, e), white=white)) for m, e in ests.items()],
        title="§4.1 Ward board (paper Fig. 3)",
    )
    return {
        "scene": "scenes/ward_board.yaml",
        "truth": {"lamp_position": cap.truth["lamp_position"], "bsdf": cap.truth["bsdf"]},
        "paper_unit_m": PAPER_UNIT_M,
        "methods": {m: _method_row(cap, e) for m, e in ests.items()},
        "figures": [fig],
    }


def _object_experiment(run: _Run, scene_file: str, key: str, title: str) -> dict[str, Any]:
    """Separation, estimation, re-synthesis and composite of one object (paper Figs. 5–7),
    seen by :data:`REAL_CAMERA` (noise seed 0)."""
    from ..generator import add_camera_noise

    cap = add_camera_noise(run.render(scene_file), noise=REAL_CAMERA, seed=0)
    ests = run.estimate(cap, NEAR_METHODS)
    original, diffuse, spec = _specular_views(cap)
    white = float(np.percentile(original[original > 0], 99.5))
    synth = _resynth(cap, ests["full"])
    figs = [
        run.figure(
            f"{key}_separation.png",
            [("(a) original", tonemap(original, white=white)), ("(b) diffuse", tonemap(diffuse, white=white)),
             ("(c) specular", tonemap(spec, white=white))],  # fmt: skip
            title=f"{title}: polarization separation",
        ),
        run.figure(
            f"{key}_synthesis.png",
            [("input specular", tonemap(spec, white=white)), ("synthesised specular (full)", tonemap(synth, white=white)),
             ("synthesised + separated diffuse", tonemap(synth + diffuse, white=white)),
             ("original", tonemap(original, white=white))],  # fmt: skip
            title=f"{title}: re-synthesis",
        ),
    ]
    return {
        "scene": f"scenes/{scene_file}",
        "truth": {"lamp_position": cap.truth["lamp_position"], "bsdf": cap.truth["bsdf"]},
        "camera_noise": REAL_CAMERA,
        "methods": {m: _method_row(cap, e) for m, e in ests.items()},
        "figures": figs,
    }


def bookend_experiment(run: _Run) -> dict[str, Any]:
    """§4.3: the blue bookend (Figs. 5 and 6)."""
    return _object_experiment(run, "bookend.yaml", "bookend", "§4.3 bookend (paper Figs. 5–6)")


def curved_experiment(run: _Run) -> dict[str, Any]:
    """§4.3, Fig. 7: a curved object."""
    return _object_experiment(run, "torus.yaml", "curved", "§4.3 curved object (paper Fig. 7)")


def near_vs_distant_experiment(run: _Run) -> dict[str, Any]:
    """The lamp moved along a ray from the board's highlight; error vs distance per method."""
    from ..generator import load_scene

    base = load_scene(scene_path("ts_board.yaml"))
    centre = np.asarray(base.object.position, dtype=float)
    direction = np.asarray(base.lamp.position, dtype=float) - centre
    direction /= np.linalg.norm(direction)
    rows = []
    for d in run.profile.distances_m:
        lamp = centre + d * direction
        cap = run.render("ts_board.yaml", {"lamp.position": lamp.tolist()})
        for m, est in run.estimate(cap, ALL_METHODS).items():
            rows.append({"distance_m": d, "method": m, **_method_row(cap, est)})
        run.bar.update()
    fig = _distance_plot(rows, run.figures / "near_vs_distant.png")
    return {
        "scene": "scenes/ts_board.yaml",
        "ray": {"from": centre.tolist(), "direction": direction.tolist()},
        "rows": rows,
        "figures": [str(fig.relative_to(run.out))],
    }


def _distance_plot(rows: list[dict[str, Any]], path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for m in ALL_METHODS:
        sel = [r for r in rows if r["method"] == m]
        d = [r["distance_m"] for r in sel]
        axes[0].plot(d, [r["lamp_position_error_pct"] for r in sel], "o-", label=m)
        axes[1].plot(d, [r["direction_error_deg"] for r in sel], "o-", label=m)
    for ax, label in zip(axes, ("lamp position error (% of distance)", "direction error (deg)")):
        ax.set_xscale("log")
        ax.set_yscale("symlog", linthresh=0.1)
        ax.set_xlabel("lamp distance from the highlight (m)")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend()
    fig.suptitle("Near vs. distant: the paper's motivation (Fig. 1), measured")
    fig.tight_layout()
    return save_png(fig, path)


EXPERIMENTS: dict[str, Callable[[_Run], dict[str, Any]]] = {
    "board": board_experiment,
    "bookend": bookend_experiment,
    "curved": curved_experiment,
    "near_vs_distant": near_vs_distant_experiment,
}


#: Every file ``reproduce`` writes into its folder, with its kind (see
#: :mod:`nearlight.files.outputs`): an existing file there is replaced only when it
#: is of that kind; other files in the folder are left alone.
REPORT_FILES: dict[str, str] = {
    "paper_reproduction.json": "reproduction-json",
    "paper_reproduction.md": "reproduction-md",
    **{f"figures/{name}": "png" for name in ("fig3_board.png", "bookend_separation.png", "bookend_synthesis.png",
                                             "curved_separation.png", "curved_synthesis.png", "near_vs_distant.png")},
}  # fmt: skip


def reproduce(out: str | Path, *, quick: bool = False, progress: bool = True) -> Path:
    """Run every experiment and write the report.

    Parameters
    ----------
    out : path-like
        Report folder (created). An earlier report there is replaced, file by
        file (:data:`REPORT_FILES`), only where each file is of the kind
        ``reproduce`` writes; anything else there is refused before any work
        and left untouched. Renders are re-used from its ``.render-cache``.
    quick : bool, optional
        Small images and a 4-angle camera (:data:`QUICK`), for tests.
    progress : bool, optional
        Show a progress bar on stderr.

    Returns
    -------
    Path
        ``out / "paper_reproduction.md"``.
    """
    from ..files.outputs import check_files_in, check_folder, make_folder

    out = Path(out)
    check_folder(out, what="report folder")
    check_folder(out / "figures", what="figures folder")
    check_folder(out / ".render-cache", what="render cache folder")
    check_files_in(out, REPORT_FILES)
    make_folder(out, what="report folder")
    profile = QUICK if quick else FULL
    run = _Run(out, profile, progress)
    start = time.perf_counter()
    results: dict[str, Any] = {}
    for name, experiment in EXPERIMENTS.items():
        results[name] = experiment(run)
        if name != "near_vs_distant":
            run.bar.update()
    run.bar.close()
    from .environment import code_version
    from .environment import collect

    doc = {
        "nearlight_version": __version__,
        "code_version": code_version(),
        "environment": collect(),
        "profile": dataclasses.asdict(profile),
        "elapsed_s": time.perf_counter() - start,
        "paper": PAPER,
        "experiments": results,
    }
    (out / "paper_reproduction.json").write_text(json.dumps(jsonable(doc), indent=2) + "\n")
    md = out / "paper_reproduction.md"
    from .reproduce_report import markdown

    md.write_text(markdown(doc))
    return md


def finite_numbers(doc: Any) -> bool:
    """True when every number in a (nested) JSON document is finite."""
    if isinstance(doc, Mapping):
        return all(finite_numbers(v) for v in doc.values())
    if isinstance(doc, (list, tuple)):
        return all(finite_numbers(v) for v in doc)
    if isinstance(doc, float):
        return math.isfinite(doc)
    return True
