"""Paper reproduction: the paper's experiments as sweep files, run by the sweep engine.

``nearlight reproduce`` runs the sweeps of ``sweeps/paper/`` (:data:`EXPERIMENTS`)
with :func:`nearlight.evaluation.engine.run.run_sweep` into ``OUT/sweeps/<profile>/<sweep
name>/`` (one render cache per results folder, the engine's ``lamp_distance``
axis, the task's seed through the generator's one seed rule, every row with the
code version and commit, ``environment.json`` beside them), then writes
``paper_reproduction.json`` (a view of those rows: every number of the report)
and ``paper_reproduction.md`` (generated from the JSON) with figures that
re-load each render from the engine's cache and re-synthesise each row's
estimate. A second run resumes: finished tasks are not run again. The paper's
own numbers are quoted in :data:`PAPER` with their section.

Experiments (Hara, Nishino, Nakazawa, Ikeuchi 2002), one sweep file each:

* ``board`` (``sweeps/paper/board.yaml``) — §4.1: a large Ward board in the
  middle of the image, lamp at the paper's (13, 2, 3). The paper gives neither
  unit nor camera; our layout is in ``scenes/ward_board.yaml`` (one paper unit
  = :data:`PAPER_UNIT_M` metres, the board centre at the origin, so the
  paper's coordinates are ours divided by the unit). Fig. 3: input specular
  vs. re-synthesis.
* ``bookend`` (``bookend.yaml``) — §4.3: the blue bent plate with the paper's
  fitted σ** and Ks** as the truth, Torrance–Sparrow, seen by a noisy camera
  and separated from the analyzer stack (Fig. 5: original, diffuse, specular;
  Fig. 6: re-synthesis, composite).
* ``curved`` (``curved.yaml``) — Fig. 7: a curved object, the same four panels.
* ``near_vs_distant`` (``near_vs_distant.yaml``) — the paper's motivation (its
  Fig. 1), measured: the Torrance–Sparrow board with the lamp moved along the
  ray from the board centre (the engine's ``lamp_distance`` axis) from near to
  far; the ``distant`` baseline against the near-field methods.
* ``first_stage`` (``first_stage.yaml``) — §4.1's first stage as a distribution:
  the Ward board from a declared family of camera layouts × sub-pixel
  shifts of the camera, ``paper-init`` as printed (origin=peak), from a sub-pixel
  peak and from the true mirror point (ORACLE); median, spread and the paper's
  8.9 % within it, the :mod:`~nearlight.evaluation.paper.fidelity` tables, and
  E_p(t) along the peak and the true mirror ray.
* ``first_stage_corrected`` (``first_stage_corrected.yaml``) — the corrected
  variants (DEPARTURES: origin=model; origin=model with am=bounded) on a subset
  of the same jitters.

Profiles: the sweep files as written are the ``full`` run (640×480, 8
analyzer angles); ``--quick`` applies each file's ``quick`` profile (160×120, 4
angles, fewer distances).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ... import __version__
from ...errors import UserError
from ...estimator import render_specular, separate_capture
from ...files.atomic import write_json, write_text
from ...files.dotted import get_dotted
from ...files.figures import panel_grid, pyplot, save_png, tonemap
from ...files.jsonable import jsonable
from ...files.outputs import check_files_in, check_folder, make_folder
from ...files.yamlfile import load_yaml_file
from ...physics.polarization import through_polarizer
from ..engine.environment import PACKAGE_ROOT, code_version, collect
from ..engine.provenance import record
from ..engine.run import check_resumable, row_estimate, run_sweep, sweep_inputs, task_captures
from ..engine.store import RENDERS, read_results
from ..engine.sweep import load_sweep
from ..scoring.metrics import capture_name, one_lamp_position
from . import fidelity as pf
from .markdown import markdown

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

#: The sweep files' profile ``--quick`` applies; without it the files run as written (``full``).
QUICK = "quick"
FULL = "full"

#: Metric columns of a result row that the report shows (NaN rows become null).
REPORTED = ("lamp_position_error_m", "lamp_position_error_pct", "direction_error_deg", "distance_error_m",
            "sigma_rel_error", "ks_rel_error", "specular_rmse_rel", "lamp_distance_true_m")  # fmt: skip


def sweeps_folder() -> Path:
    """``sweeps/paper/`` of the checkout nearlight runs from (the package's root folder)."""
    folder = PACKAGE_ROOT / "sweeps" / "paper"
    if not folder.is_dir():
        raise UserError(f"{folder}: the paper's sweep files are missing (reproduce runs from a checkout of "
                        "nearlight: `bash scripts/setup` installs it editable)")
    return folder


# --------------------------------------------------------------------------- one experiment's rows


@dataclasses.dataclass
class Experiment:
    """One finished sweep of the reproduction: its tasks, result rows and folder.

    Attributes
    ----------
    key : str
        The experiment's name in the report (``board``, ...).
    sweep : Sweep
    folder : Path
        Its results folder (rows, ``environment.json``, render cache).
    rows : pandas.DataFrame
        Every task's row, in task order.
    report_dir : Path
        The report folder (paths in the document are relative to it).
    cache_dir : path-like, True or None
        The render cache the sweep ran with (True: the results folder's).
    """

    key: str
    sweep: Any
    folder: Path
    rows: Any
    report_dir: Path
    cache_dir: str | Path | None | bool = True

    def task(self, row: Any) -> Any:
        return self.sweep.tasks[int(row["task_index"])]

    def captures(self, row: Any) -> tuple[Any, Any]:
        """The noise-free render of ``row`` (from the engine's cache) and the capture its method saw."""
        return task_captures(self.sweep, self.task(row), self.folder, self.cache_dir)

    def figure(self, name: str, panels: list, **kw: Any) -> str:
        """Write a panel figure into ``figures/``; return its path relative to the report."""
        return str(panel_grid(panels, self.report_dir / "figures" / name, **kw).relative_to(self.report_dir))

    def header(self) -> dict[str, Any]:
        """Where the experiment's numbers come from: sweep file, results folder, scene, code versions."""
        source, *scene_file = sweep_inputs(self.sweep)
        root = sweeps_folder().parent.parent
        if scene_file:
            scene = str(scene_file[0].resolve().relative_to(root))
        else:  # an inline scene
            scene = load_yaml_file(source, what="sweep file")["scene"]
        return {
            "sweep": str(source.relative_to(root)),
            "results": str(self.folder.relative_to(self.report_dir)),
            "scene": scene,
            "code_versions": sorted(set(self.rows["code_version"].astype(str))),
        }


def _number(x: Any) -> float | None:
    x = float(x)
    return None if math.isnan(x) else x


def _method_row(row: Any, truth: Mapping[str, Any]) -> dict[str, Any]:
    """One result row as the report shows it: the estimate, its errors (``None`` where a metric
    does not apply, e.g. σ and Ks against a Ward truth), status and provenance.

    Estimators fold the (unknown) lamp intensity reaching the surface into Ks;
    ``ks_in_truth_units`` divides it back out with the true intensity (``I_lamp / 2``
    behind the ideal polarizer) so that it reads beside the truth and the paper's Ks**.
    """
    est = row_estimate(row)
    reaching = through_polarizer(truth["lamp_intensity"])
    return {
        "status": str(row["status"]),
        **({"error": str(row["error"])} if row["status"] != "ok" else {}),
        "lamp_position": [_number(v) for v in est.lamp_position],
        "sigma": _number(est.sigma),
        "ks": [_number(v) for v in est.ks],
        "ks_in_truth_units": [_number(v) for v in np.asarray(est.ks) / reaching],
        "runtime_s": _number(row["runtime_s"]),
        **{k: _number(row[k]) for k in REPORTED},
        "task_id": str(row["task_id"]),
        "code_version": str(row["code_version"]),
    }


def _specular_views(capture: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Original (no analyzer), separated diffuse and specular images, ``[H, W, 3]`` each (corrected for the
    extinction ratios the capture's ``rig`` states, as the estimators' separation is)."""
    spec, diff = separate_capture(capture)
    return spec + diff, diff, spec


def _resynth(capture: Any, row: Any) -> np.ndarray:
    """The specular image a row's estimate predicts (black for a failed task)."""
    if row["status"] != "ok":
        return np.zeros((capture.height, capture.width, 3))
    return np.nan_to_num(np.asarray(render_specular(capture, row_estimate(row)), dtype=float))


def _truth(capture: Any) -> dict[str, Any]:
    """The truth a section records: the one lamp and the BSDF (a one-line UserError for several lamps)."""
    one_lamp_position(capture.truth, where=capture_name(capture), what="the paper reproduction")
    return {"lamp_position": capture.truth["lamp_position"], "bsdf": capture.truth["bsdf"]}


# --------------------------------------------------------------------------- report sections (views of rows)


def board_view(ex: Experiment) -> dict[str, Any]:
    """§4.1: the Ward board, lamp at the paper's (13, 2, 3) units (Fig. 3)."""
    rows = [r for _, r in ex.rows.iterrows()]
    _, seen = ex.captures(rows[0])
    _, _, spec = _specular_views(seen)
    white = float(np.percentile(spec[spec > 0], 99.5))
    fig = ex.figure(
        "fig3_board.png",
        [("(a) input specular", tonemap(spec, white=white))]
        + [(f"(b) re-synthesised, {r['method']}", tonemap(_resynth(seen, r), white=white)) for r in rows],
        title="§4.1 Ward board (paper Fig. 3)",
    )
    return {
        **ex.header(),
        "truth": _truth(seen),
        "paper_unit_m": PAPER_UNIT_M,
        "methods": {r["method"]: _method_row(r, seen.truth) for r in rows},
        "figures": [fig],
    }


def object_view(ex: Experiment, title: str) -> dict[str, Any]:
    """Separation, estimation, re-synthesis (``full``) and composite of one object (paper Figs. 5–7).

    With a ``set`` axis, its first label is the experiment (figures, ``methods``) and each further label
    a diagnostic variant of it (``variants``: label -> its overrides and rows per method).
    """
    every = [r for _, r in ex.rows.iterrows()]
    labels = list(dict.fromkeys(str(r["set"]) for r in every)) if "set" in ex.rows else [None]
    rows = [r for r in every if labels[0] is None or str(r["set"]) == labels[0]]
    task = ex.task(rows[0])
    _, seen = ex.captures(rows[0])
    original, diffuse, spec = _specular_views(seen)
    white = float(np.percentile(original[original > 0], 99.5))
    synth = _resynth(seen, next(r for r in rows if r["method"] == "full"))
    figs = [
        ex.figure(
            f"{ex.key}_separation.png",
            [("(a) original", tonemap(original, white=white)), ("(b) diffuse", tonemap(diffuse, white=white)),
             ("(c) specular", tonemap(spec, white=white))],  # fmt: skip
            title=f"{title}: polarization separation",
        ),
        ex.figure(
            f"{ex.key}_synthesis.png",
            [("input specular", tonemap(spec, white=white)), ("synthesised specular (full)", tonemap(synth, white=white)),
             ("synthesised + separated diffuse", tonemap(synth + diffuse, white=white)),
             ("original", tonemap(original, white=white))],  # fmt: skip
            title=f"{title}: re-synthesis",
        ),
    ]
    return {
        **ex.header(),
        "truth": _truth(seen),
        "camera_noise": task.noise,
        "realism": str(task.scene.get("realism", "none")),
        "seed": task.seed,
        "methods": {r["method"]: _method_row(r, seen.truth) for r in rows},
        "variants": {label: {"set": dict(ex.sweep.axes["set"])[label],
                             "methods": {r["method"]: _method_row(r, ex.captures(r)[1].truth)
                                         for r in every if str(r["set"]) == label}}
                     for label in labels[1:]},  # fmt: skip
        "figures": figs,
    }


def near_vs_distant_view(ex: Experiment) -> dict[str, Any]:
    """Error vs the lamp's distance from the board centre (the ``lamp_distance`` axis), per method."""
    out, truths = [], {}
    for _, r in ex.rows.iterrows():
        task = ex.task(r)
        if task.render_key not in truths:
            truths[task.render_key] = ex.captures(r)[0].truth
        out.append({"lamp_distance_m": float(r["lamp_distance"]), "method": r["method"],
                    **_method_row(r, truths[task.render_key])})  # fmt: skip
    first = ex.sweep.tasks[0].scene
    centre = ex.sweep.renderer.object_centre(first)
    direction = np.asarray(get_dotted(first, ex.sweep.renderer.lamp_key), dtype=float) - centre
    fig = _distance_plot(out, [m.label for m in ex.sweep.methods], ex.report_dir / "figures" / "near_vs_distant.png")
    return {
        **ex.header(),
        "distance": "lamp_distance_m: metres from the board centre along the ray to the lamp (the sweep's "
        "lamp_distance axis); lamp_distance_true_m: from the highlight point, which the errors are relative to",
        "ray": {"from": centre.tolist(), "direction": (direction / np.linalg.norm(direction)).tolist()},
        "rows": out,
        "figures": [str(fig.relative_to(ex.report_dir))],
    }


def _distance_plot(rows: list[dict[str, Any]], methods: list[str], path: Path) -> Path:
    plt = pyplot()
    import matplotlib.ticker

    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8))
    refused = {}
    for m in methods:
        sel = [r for r in rows if r["method"] == m]
        d = [r["lamp_distance_m"] for r in sel]
        line, = axes[0].plot(d, [r["lamp_position_error_pct"] for r in sel], "o-", label=m)
        axes[1].plot(d, [r["direction_error_deg"] for r in sel], "o-", label=m, color=line.get_color())
        refused[m] = ([r["lamp_distance_m"] for r in sel if r["status"] != "ok"], line.get_color())
    for ax, label in zip(axes, ("lamp position error (% of distance)", "direction error (deg)")):
        ax.set_xscale("log")
        ax.set_yscale("symlog", linthresh=0.1)  # 0 and small errors linear, large ones logarithmic
        ax.set_ylim(bottom=0.0)  # an error is never negative: symlog's default would show −10¹
        top = ax.get_ylim()[1]
        for d, colour in (v for v in refused.values() if v[0]):  # no number: a cross on the top edge
            ax.plot(d, [top] * len(d), "x", color=colour, markersize=9, mew=2, clip_on=False)
        ax.set_ylim(0.0, top)
        distances = sorted({r["lamp_distance_m"] for r in rows})
        ax.set_xticks(distances, [f"{d:g}" for d in distances])
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_xlabel("lamp distance from the board centre (m)")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
    fig.suptitle("Near vs. distant: the paper's motivation (Fig. 1), measured")
    fig.tight_layout(rect=(0.0, 0.0, 0.8, 1.0))
    fig.legend(*axes[0].get_legend_handles_labels(), loc="center right", fontsize=9,
               title="×: refused, no number", title_fontsize=8)
    return save_png(fig, path)


# --------------------------------------------------------------------------- §4.1 first stage as a distribution

#: The first-stage sweeps' axes: camera layout and sub-pixel jitter of the look-at point.
LAYOUT, JITTER = "camera.position", "camera.look_at"
#: Each first-stage variant's kind, for the report (PRINTED: the paper as printed; ORACLE: reads the truth;
#: DEPARTURE: a change to the printed method). Labels are the sweep files' method names.
VARIANT_KIND = {
    "paper-init": "PRINTED (origin=peak)",
    "paper-init (subpixel)": "printed stage, sub-pixel peak (origin=subpixel)",
    "paper-init (ORACLE mirror point)": "ORACLE (origin=mirror-oracle: the true mirror point)",
    "paper-init (model origin)": "DEPARTURE (origin=model)",
    "paper (model origin, bounded AM)": "DEPARTURE (origin=model, am=bounded)",
}


def paper_first_stage_pct() -> float:
    """The paper's §4.1 first-stage error, % of |L_true| (its L* against (13, 2, 3), from its origin)."""
    b = PAPER["board"]
    true = np.asarray(b["lamp_true"])
    return float(100.0 * np.linalg.norm(np.asarray(b["lamp_first_stage"]) - true) / np.linalg.norm(true))


def _distributions(ex: Experiment) -> dict[str, Any]:
    """Per method: the error distribution over every (layout, jitter) sample, per layout, and over the two
    halves of the jitter samples (first half of the jitter labels vs the second: how stable it is)."""
    ref = paper_first_stage_pct()
    jitters = [label for label, _ in ex.sweep.axes[JITTER]]
    halves = (jitters[: len(jitters) // 2], jitters[len(jitters) // 2:])
    out = {}
    for label in [m.label for m in ex.sweep.methods]:
        sel = ex.rows[ex.rows["method"] == label]
        err = lambda df: [float(v) if s == "ok" else math.nan  # noqa: E731
                          for v, s in zip(df["lamp_position_error_pct"], df["status"])]
        out[label] = {
            "kind": VARIANT_KIND.get(label, label),
            "all": pf.distribution(err(sel), reference=ref),
            "layouts": {str(lay): pf.distribution(err(sel[sel[LAYOUT] == lay]), reference=ref)
                        for lay, _ in ex.sweep.axes[LAYOUT]},
            "halves": [{"jitters": h, **pf.distribution(err(sel[sel[JITTER].isin(h)]), reference=ref)}
                       for h in halves if h],
        }
    return out


def _samples(ex: Experiment) -> list[dict[str, Any]]:
    """Every row: its layout, jitter, method and errors (what the distributions are made of)."""
    truths: dict[str, Any] = {}
    out = []
    for _, r in ex.rows.iterrows():
        task = ex.task(r)
        if task.render_key not in truths:
            truths[task.render_key] = {"lamp_intensity": task.scene["lamp"]["intensity"]}
        out.append({"layout": str(r[LAYOUT]), "jitter": str(r[JITTER]), "method": r["method"],
                    **_method_row(r, truths[task.render_key])})
    return out


def _layouts(ex: Experiment) -> dict[str, Any]:
    return {str(label): {"camera_position": list(value)} for label, value in ex.sweep.axes[LAYOUT]}


def first_stage_view(ex: Experiment) -> dict[str, Any]:
    """§4.1 first stage over camera layouts × sub-pixel jitter; the paper_fidelity numbers; the E_p figure."""
    layout = "paper-33deg" if "paper-33deg" in set(ex.rows[LAYOUT]) else ex.rows[LAYOUT].iloc[0]
    first = ex.rows[ex.rows[LAYOUT] == layout].iloc[0]  # the scene's own layout (the mirror direction)
    _, seen = ex.captures(first)
    curves = pf.ep_curves(seen)
    delta_px = curves.pop("delta_px")
    fig = _ep_figure(curves, ex.report_dir / "figures" / "first_stage_ep.png",
                     where=f"layout {first[LAYOUT]}, jitter {first[JITTER]}")
    return {
        **ex.header(),
        "paper_unit_m": PAPER_UNIT_M,
        "paper_first_stage_pct": paper_first_stage_pct(),
        "resolution": [seen.width, seen.height],
        "layouts": _layouts(ex),
        "jitters": [str(label) for label, _ in ex.sweep.axes[JITTER]],
        "distributions": _distributions(ex),
        "samples": _samples(ex),
        "ep_curves": {"layout": str(first[LAYOUT]), "jitter": str(first[JITTER]),
                      "delta_px": delta_px,
                      **{k: {"t_true": v["t_true"], "t_star": v["t_star"]} for k, v in curves.items()}},
        "fidelity": {"ep_flatness": pf.ep_flatness(), "t_star_curve": pf.t_star_curve(),
                     "ward_bias": pf.ward_bias()},
        "figures": [str(fig.relative_to(ex.report_dir))],
    }


def first_stage_corrected_view(ex: Experiment) -> dict[str, Any]:
    """The corrected first-stage variants (DEPARTURES) on a subset of the same layouts and jitter."""
    return {
        **ex.header(),
        "layouts": _layouts(ex),
        "jitters": [str(label) for label, _ in ex.sweep.axes[JITTER]],
        "distributions": _distributions(ex),
        "samples": _samples(ex),
        "figures": [],
    }


def _ep_figure(curves: Mapping[str, Any], path: Path, *, where: str) -> Path:
    """3 + E_p(t) along the peak ray and along the true mirror ray, side by side, t over each ray's true t."""
    plt = pyplot()

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8), sharey=True)
    titles = {"peak": "peak ray (printed: brightest pixel)", "mirror": "true mirror ray (ORACLE)"}
    for ax, (name, c) in zip(axes, curves.items()):
        t = np.asarray(c["t"]) / c["t_true"]
        ax.plot(t, np.maximum(c["three_plus_ep"], 1e-12), "-", color="C0" if name == "peak" else "C1")
        ax.axvline(1.0, color="k", lw=0.8, ls="--", label="true lamp distance")
        ax.axvline(c["t_star"] / c["t_true"], color="C3", lw=1.2, label=f"t* = {c['t_star'] / c['t_true']:.3f} t")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("t / t_true")
        ax.set_title(titles[name])
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    axes[0].set_ylabel("3 + E_p(t)  (0 = collinear)")
    fig.suptitle(f"§4.1 Ward board, E_p(t) along two rays ({where})")
    fig.tight_layout()
    return save_png(fig, path)


#: The experiments in report order: key -> (sweep file in ``sweeps/paper/``, view of its rows).
EXPERIMENTS: dict[str, tuple[str, Callable[[Experiment], dict[str, Any]]]] = {
    "board": ("board.yaml", board_view),
    "bookend": ("bookend.yaml", lambda ex: object_view(ex, "§4.3 bookend (paper Figs. 5–6)")),
    "curved": ("curved.yaml", lambda ex: object_view(ex, "§4.3 curved object (paper Fig. 7)")),
    "near_vs_distant": ("near_vs_distant.yaml", near_vs_distant_view),
    "first_stage": ("first_stage.yaml", first_stage_view),
    "first_stage_corrected": ("first_stage_corrected.yaml", first_stage_corrected_view),
}


#: Every file ``reproduce`` writes into its folder besides the sweeps' results folders, with its kind
#: (see :mod:`nearlight.files.outputs`): an existing file there is replaced only when it is of that
#: kind; other files in the folder are left alone.
REPORT_FILES: dict[str, str] = {
    "paper_reproduction.json": "reproduction-json",
    "paper_reproduction.md": "reproduction-md",
    "provenance.json": "provenance",
    **{f"figures/{name}": "png" for name in ("fig3_board.png", "bookend_separation.png", "bookend_synthesis.png",
                                             "curved_separation.png", "curved_synthesis.png", "near_vs_distant.png",
                                             "first_stage_ep.png")},
}  # fmt: skip


def load_sweeps(*, quick: bool = False) -> dict[str, Any]:
    """``{experiment: Sweep}`` of :data:`EXPERIMENTS`, with the ``quick`` profile when asked."""
    folder = sweeps_folder()
    return {key: load_sweep(folder / file, profile=QUICK if quick else None) for key, (file, _) in EXPERIMENTS.items()}


def _profile(name: str, sweeps: Mapping[str, Any]) -> dict[str, Any]:
    """What sets a run's size, read from the sweeps: image size, analyzer angles, the distances."""
    scene = sweeps["board"].tasks[0].scene
    return {
        "name": name,
        "resolution": get_dotted(scene, "camera.resolution"),
        "analyzer_angles_deg": [float(a) for a in get_dotted(scene, "capture.analyzer_angles_deg")],
        "distances_m": [float(v) for _, v in sweeps["near_vs_distant"].axes["lamp_distance"]],
    }


#: Experiments that render into another one's cache (their scenes are a subset of its).
SHARED_RENDERS = {"first_stage_corrected": "first_stage"}


def _cache(key: str, folders: Mapping[str, Path], cache_dir: str | Path | None | bool) -> str | Path | None | bool:
    """The render cache of experiment ``key``: ``cache_dir``, but with the default (True, each results
    folder's ``renders/``) an experiment of :data:`SHARED_RENDERS` re-uses the other's renders."""
    if cache_dir is True and key in SHARED_RENDERS and SHARED_RENDERS[key] in folders:
        return folders[SHARED_RENDERS[key]] / RENDERS
    return cache_dir


def reproduce(
    out: str | Path, *, quick: bool = False, workers: int = 1, progress: bool = True,
    cache_dir: str | Path | None | bool = True,
) -> Path:
    """Run (or resume) every experiment's sweep into ``out`` and write the report.

    Parameters
    ----------
    out : path-like
        Report folder (created). The sweeps' results go to
        ``out/sweeps/<profile>/<sweep name>/`` (resumed when there). An earlier
        report there is replaced, file by file (:data:`REPORT_FILES`), only
        where each file is of the kind ``reproduce`` writes; anything else there,
        or a results folder holding another sweep, is refused before any work
        and left untouched.
    quick : bool, optional
        Each sweep file's ``quick`` profile (small images, a 4-angle camera), for tests.
    workers : int, optional
        Local worker processes of the engine; 1 runs in this process.
    progress : bool, optional
        The engine's progress bars on stderr.
    cache_dir : path-like, True or None, optional
        The render cache, as :func:`~nearlight.evaluation.engine.run.run_sweep` takes
        it (True: each results folder's ``renders/``); the figures re-load renders from it.

    Returns
    -------
    Path
        ``out / "paper_reproduction.md"``.
    """
    out = Path(out)
    check_folder(out, what="report folder")
    check_folder(out / "figures", what="figures folder")
    check_files_in(out, REPORT_FILES)
    sweeps = load_sweeps(quick=quick)
    profile = QUICK if quick else FULL
    folders = {key: out / "sweeps" / profile / s.name for key, s in sweeps.items()}
    for key, s in sweeps.items():
        check_folder(folders[key], what="results folder")
        check_resumable(folders[key], s)
    make_folder(out, what="report folder")
    start = time.perf_counter()
    results: dict[str, Any] = {}
    command = "nearlight reproduce" + (" --quick" if quick else "") + f" --out {out}"
    for key, s in sweeps.items():
        cache = _cache(key, folders, cache_dir)
        summary = run_sweep(s, folders[key], workers=workers, progress=progress, cache_dir=cache, command=command)
        if not summary.complete:
            raise UserError(f"{folders[key]}: sweep {s.name} is incomplete; run `nearlight reproduce` again")
        rows, _ = read_results(folders[key])
        results[key] = EXPERIMENTS[key][1](Experiment(key, s, folders[key], rows, out, cache))
    doc = {
        "nearlight_version": __version__,
        "code_version": code_version(),
        "environment": collect(),
        "profile": _profile(profile, sweeps),
        "elapsed_s": time.perf_counter() - start,
        "paper": PAPER,
        "experiments": results,
    }
    write_json(out / "paper_reproduction.json", jsonable(doc), what="the reproduction")
    md = write_text(out / "paper_reproduction.md", markdown(doc), what="the reproduction")
    # the report part; each experiment's rows carry the record of the run that made them
    # (OUT/sweeps/<profile>/<name>/provenance.json), which a resumed run leaves as it was
    record(out, command=command, entry_modules=[__name__, "nearlight.evaluation.paper.markdown"],
           inputs=[f for s in sweeps.values() for f in sweep_inputs(s)], part="report")
    return md


def failures(doc: Mapping[str, Any]) -> list[str]:
    """``"experiment: row: error"`` for every task of a reproduction document that did not run (``status``
    ``error``); an estimate the sanity rules refused (``failed``) is a finding the tables show, not a failed run."""
    lines = []
    for name, ex in doc["experiments"].items():
        labelled = [(m, r) for m, r in ex.get("methods", {}).items()]
        labelled += [(f"{r['method']} at {r['lamp_distance_m']:g} m", r) for r in ex.get("rows", [])]
        labelled += [(f"{r['method']} at {r['layout']}/{r['jitter']}", r) for r in ex.get("samples", [])]
        lines += [f"{name}: {label}: {r['error']}" for label, r in labelled if r["status"] == "error"]
    return lines


def finite_numbers(doc: Any) -> bool:
    """True when every number in a (nested) JSON document is finite."""
    if isinstance(doc, Mapping):
        return all(finite_numbers(v) for v in doc.values())
    if isinstance(doc, (list, tuple)):
        return all(finite_numbers(v) for v in doc)
    if isinstance(doc, float):
        return math.isfinite(doc)
    return True
