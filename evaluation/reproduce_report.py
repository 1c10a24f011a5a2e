"""Markdown of the paper reproduction, from its JSON document only.

Every number printed here is read from the document that
:func:`nearlight.evaluation.reproduce.reproduce` wrote (itself a view of the
sweeps' result rows); the paper's numbers come from its ``paper`` section
(quoted with their section there).
"""

from __future__ import annotations

from typing import Any

import numpy as np


def _vec(v: Any, digits: int = 3) -> str:
    return "(" + ", ".join(f"{x:.{digits}f}" for x in v) + ")"


def _num(x: Any, fmt: str = ".3g") -> str:
    return "n/a" if x is None else format(x, fmt)


def _table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def _figures(section: dict[str, Any]) -> str:
    return "\n\n".join(f"![{f}]({f})" for f in section["figures"])


def _source(section: dict[str, Any]) -> str:
    """Where a section's rows come from: its sweep file, results folder and code versions."""
    return (f"Sweep `{section['sweep']}` (scene `{section['scene']}`), rows in `{section['results']}/` "
            f"(made by {', '.join(section['code_versions'])}).")


def _failed(r: dict[str, Any], columns: int) -> list[str] | None:
    """The cells of a failed task's row (its error in the first), or None when it succeeded."""
    return None if r["status"] == "ok" else [f"failed: {r['error']}"] + [""] * (columns - 1)


def board_section(doc: dict[str, Any]) -> str:
    ex, paper = doc["experiments"]["board"], doc["paper"]["board"]
    unit = ex["paper_unit_m"]
    true_u = np.asarray(paper["lamp_true"])
    lamp_true = np.asarray(ex["truth"]["lamp_position"])
    paper_err = float(np.linalg.norm(np.asarray(paper["lamp_first_stage"]) - true_u))
    rows = [
        ["truth", _vec(lamp_true / unit), "", "", "", ""],
        [f"paper, first stage L* ({paper['section']})", _vec(paper["lamp_first_stage"]), f"{paper_err:.2f}",
         f"{100 * paper_err / np.linalg.norm(true_u):.1f} %", f"{paper['sigma']} (σ**)", _vec(paper["ks"], 2)],
    ]  # fmt: skip
    for m, r in ex["methods"].items():
        rows.append([f"nearlight `{m}`", *(_failed(r, 5) or [_vec(np.asarray(r["lamp_position"]) / unit),
                     f"{r['lamp_position_error_m'] / unit:.2f}", f"{r['lamp_position_error_pct']:.2f} %",
                     f"{r['sigma']:.4f}", _vec(r["ks_in_truth_units"], 3)])])  # fmt: skip
    bsdf = ex["truth"]["bsdf"]
    return f"""## 1. Synthetic board, Ward BRDF (paper §4.1, Fig. 3)

{_source(ex)} A Ward board (ρs = {bsdf['rho_s']}, σ' = {bsdf['alpha']}) in the middle of
the image. The paper gives no unit and no camera. We take one paper unit = {unit} m, the
board centre at the origin and the lamp at the paper's (13, 2, 3) units; the camera
layout is in the scene file. Positions below are in paper units; the error is
also given as a percentage of the lamp's distance (the paper's: from the origin,
|L_true| = {np.linalg.norm(true_u):.2f}; ours: from the highlight point). σ and Ks
are the Torrance–Sparrow fit to a Ward surface, so, as the paper says, they are
not comparable to the truth; they are printed to set them beside the paper's
σ** and Ks**. Ks is divided by the lamp intensity reaching the board, which the
estimator cannot know (it folds it into Ks).

{_table(["", "lamp (units)", "error (units)", "error (% of distance)", "σ", "Ks"], rows)}

{_figures(ex)}
"""


def object_section(doc: dict[str, Any], key: str, heading: str) -> str:
    ex = doc["experiments"][key]
    bsdf, noise = ex["truth"]["bsdf"], ex["camera_noise"]
    paper = doc["paper"]["bookend"]
    rows = [["truth", _vec(ex["truth"]["lamp_position"]), "", "", f"{bsdf['sigma']}", _vec(bsdf["ks"], 2), "", ""]]
    for m, r in ex["methods"].items():
        rows.append([f"`{m}`", *(_failed(r, 7) or [_vec(r["lamp_position"]), f"{1000 * r['lamp_position_error_m']:.1f}",
                     f"{r['lamp_position_error_pct']:.2f} %", f"{r['sigma']:.4f}", _vec(r["ks_in_truth_units"], 3),
                     f"{100 * r['sigma_rel_error']:.1f} %", f"{100 * r['ks_rel_error']:.1f} %"])])  # fmt: skip
    note = ""
    if key == "bookend":
        note = (
            f"The truth uses the paper's fitted values for the real bookend ({paper['section']}: "
            f"σ** = {paper['sigma']}, Ks** = {_vec(paper['ks'], 2)}). Ks is known only up to the lamp "
            "intensity: the table divides it by the true intensity reaching the surface, and its error "
            "is taken after the one global scale that leaves free.\n"
        )
    return f"""## {heading}

{_source(ex)} Torrance–Sparrow, seen by a camera with noise like the
paper's real captures ({noise['bits']}-bit, full well {noise['full_well']:.0f} e⁻, read noise
{noise['read_noise']:g} e⁻, brightest pixel at 90 % of the full well; noise seed {ex['seed']}), separated from the
analyzer stack (figures: the per-pixel cos 2θ fit; each method: its default separation).
Lamp positions in metres, world frame.
{note}
{_table(["", "lamp (m)", "error (mm)", "error (% of distance)", "σ", "Ks", "σ error", "Ks error"], rows)}

{_figures(ex)}
"""


def distance_section(doc: dict[str, Any]) -> str:
    ex = doc["experiments"]["near_vs_distant"]
    methods = list(dict.fromkeys(r["method"] for r in ex["rows"]))
    dists = sorted({r["lamp_distance_m"] for r in ex["rows"]})
    by = {(r["lamp_distance_m"], r["method"]): r for r in ex["rows"]}

    def cell(r: dict[str, Any]) -> str:
        if r["status"] != "ok":
            return f"failed: {r['error']}"
        return f"{r['lamp_position_error_pct']:.2f} % / {r['direction_error_deg']:.2f}°"

    highlight = {d: next((r["lamp_distance_true_m"] for m in methods if (r := by[d, m])["status"] == "ok"), None)
                 for d in dists}  # fmt: skip
    rows = [[f"{d:g}", _num(highlight[d], ".3f")] + [cell(by[d, m]) for m in methods] for d in dists]
    return f"""## 4. Near vs. distant (the paper's Fig. 1, measured)

{_source(ex)} The lamp moves along the ray from the board centre
{_vec(ex['ray']['from'])} towards {_vec(ex['ray']['direction'])} (the sweep's `lamp_distance`
axis). First column: the lamp's distance from the board centre; second: its distance from the
highlight point, which the errors are relative to. Each cell: lamp position error as % of the
lamp's distance from the highlight / direction error seen from the highlight.

{_table(["from the board centre (m)", "from the highlight (m)"] + [f"`{m}`" for m in methods], rows)}

{_figures(ex)}
"""


def markdown(doc: dict[str, Any]) -> str:
    """The whole report."""
    from .reproduce_check import tolerance_text

    p = doc["profile"]
    env = doc.get("environment") or {}
    where = f" on {env['cpu']} ({env['mitsuba_variant']})" if env else ""
    head = f"""# Paper reproduction

Hara, Nishino, Nakazawa, Ikeuchi, "Estimating Light Position and Surface Reflectance
from Specular Reflection under Perspective Projection", reproduced on Mitsuba 3
renders by nearlight {doc.get('code_version', doc['nearlight_version'])}{where}. Profile `{p['name']}`:
{p['resolution'][0]}×{p['resolution'][1]} pixels, {len(p['analyzer_angles_deg'])} analyzer angles; this run took
{doc['elapsed_s']:.0f} s (tasks already done by an earlier run are not run again). Each
experiment is a sweep file of `sweeps/paper/` run by the sweep engine; every number below is
read from its result rows (see `paper_reproduction.json`, which also records the
environment; each results folder has its `environment.json`); the paper's numbers are
quoted with their section. {tolerance_text()}
"""
    return "\n".join([
        head,
        board_section(doc),
        object_section(doc, "bookend", "2. Bookend (paper §4.3, Figs. 5 and 6)"),
        object_section(doc, "curved", "3. Curved object (paper §4.3, Fig. 7)"),
        distance_section(doc),
    ])  # fmt: skip
