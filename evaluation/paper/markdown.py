"""Markdown of the paper reproduction, from its JSON document only.

Every number printed here is read from the document that
:func:`nearlight.evaluation.paper.reproduce.reproduce` wrote (itself a view of the
sweeps' result rows); the paper's numbers come from its ``paper`` section
(quoted with their section there).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...errors import UserError
from ...files.markdown import markdown_table
from .check import tolerance_text


def _vec(v: Any, digits: int = 3) -> str:
    """``(x, y, z)``; ``n/a`` for a vector the sanity rules refused (its numbers NaN, ``None`` in JSON)."""
    if any(x is None for x in v):
        return "n/a"
    return "(" + ", ".join(f"{x:.{digits}f}" for x in v) + ")"


def _num(x: Any, fmt: str = ".3g") -> str:
    return "n/a" if x is None else format(x, fmt)


def _pct(x: Any) -> str:
    """A relative error as ``12.3 %``, ``n/a`` when there is none (a refused Ks)."""
    return "n/a" if x is None else f"{100 * x:.1f} %"


def _figures(section: dict[str, Any]) -> str:
    return "\n\n".join(f"![{f}]({f})" for f in section["figures"])


def _source(section: dict[str, Any]) -> str:
    """Where a section's rows come from: its sweep file, results folder and code versions."""
    return (f"Sweep `{section['sweep']}` (scene `{section['scene']}`), rows in `{section['results']}/` "
            f"(made by {', '.join(section['code_versions'])}).")


def _failure(r: dict[str, Any]) -> str:
    """A task's row that is no number: ``refused: <rule>: <reason>`` (the sanity rules) or ``failed: <error>``."""
    if r["status"] == "failed":
        return f"refused: {r['error'].removeprefix('estimate: ')}"
    return f"failed: {r['error']}"


def _failed(r: dict[str, Any], columns: int) -> list[str] | None:
    """The cells of a failed task's row (its error in the first), or None when it succeeded."""
    return None if r["status"] == "ok" else [_failure(r)] + [""] * (columns - 1)


def _lamp_true(ex: dict[str, Any], key: str) -> Any:
    """An experiment's one true lamp (a one-line UserError when its truth has none: several lamps)."""
    if "lamp_position" not in ex["truth"]:
        raise UserError(f"reproduction document: experiments.{key}.truth.lamp_position: missing "
                        "(the reproduction expects a capture with one lamp)")
    return ex["truth"]["lamp_position"]


def board_section(doc: dict[str, Any]) -> str:
    ex, paper = doc["experiments"]["board"], doc["paper"]["board"]
    unit = ex["paper_unit_m"]
    true_u = np.asarray(paper["lamp_true"])
    lamp_true = np.asarray(_lamp_true(ex, "board"))
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

{markdown_table(["", "lamp (units)", "error (units)", "error (% of distance)", "σ", "Ks"], rows)}

{_figures(ex)}
"""


def object_section(doc: dict[str, Any], key: str, heading: str) -> str:
    ex = doc["experiments"][key]
    bsdf, noise = ex["truth"]["bsdf"], ex["camera_noise"]
    paper = doc["paper"]["bookend"]
    rows = [["truth", _vec(_lamp_true(ex, key)), "", "", f"{bsdf['sigma']}", _vec(bsdf["ks"], 2), "", ""]]
    variants = ex.get("variants", {})
    for suffix, methods in [("", ex["methods"])] + [(f" ({v})", d["methods"]) for v, d in variants.items()]:
        for m, r in methods.items():
            rows.append([f"`{m}`{suffix}", *(_failed(r, 7) or [
                _vec(r["lamp_position"]), f"{1000 * r['lamp_position_error_m']:.1f}", f"{r['lamp_position_error_pct']:.2f} %",
                f"{r['sigma']:.4f}", _vec(r["ks_in_truth_units"], 3), _pct(r["sigma_rel_error"]),
                _pct(r["ks_rel_error"])])])  # fmt: skip
    diagnostic = "".join(
        f"Rows marked ({v}) are a DIAGNOSTIC, not the paper's experiment: the same scene with "
        + ", ".join(f"`{k}: {val}`" for k, val in d["set"].items())
        + " (the sweep's `set` axis), to show how much of the errors above that change accounts for. "
        for v, d in variants.items())
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
{_rig(ex.get("realism", "none"))}{diagnostic}Lamp positions in metres, world frame.
{note}
{markdown_table(["", "lamp (m)", "error (mm)", "error (% of distance)", "σ", "Ks", "σ error", "Ks error"], rows)}

{_figures(ex)}
"""


def _rig(realism: str) -> str:
    if realism == "none":
        return "An ideal rig (no nuisances). "
    return (f"The rig is the `{realism}` profile (docs/scene-files.md, \"Nuisances\"): a lamp of finite size with a "
            "cos-power beam behind a leaky polarizer, an analyzer with finite extinction and angle errors, "
            "vignetting, lamp flicker, range holes on the highlight, misregistered and quantised range, a "
            "calibration error of the camera pose; so no method sees exactly its own model, as on the paper's "
            "real captures. The range image has no normals: every method's points and normals are the surface "
            "nearlight fits to the range, its error as the capture's `rig.range` states it (docs/physics.md, "
            "\"Range sensor error and the fitted surface\"; the paper had a range finder too, and every method "
            "gets the same geometry). ")


def distance_section(doc: dict[str, Any]) -> str:
    ex = doc["experiments"]["near_vs_distant"]
    methods = list(dict.fromkeys(r["method"] for r in ex["rows"]))
    dists = sorted({r["lamp_distance_m"] for r in ex["rows"]})
    by = {(r["lamp_distance_m"], r["method"]): r for r in ex["rows"]}

    def cell(r: dict[str, Any]) -> str:
        if r["status"] != "ok":
            return _failure(r)
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

{markdown_table(["from the board centre (m)", "from the highlight (m)"] + [f"`{m}`" for m in methods], rows)}

{_figures(ex)}
"""


def _dist_cells(d: dict[str, Any]) -> list[str]:
    """Median, p10–p90, IQR and failures of one distribution (% of the lamp's distance)."""
    return [str(d["n"]), _num(d["median"], ".1f"), f"{_num(d['p10'], '.1f')}–{_num(d['p90'], '.1f')}",
            f"{_num(d['p25'], '.1f')}–{_num(d['p75'], '.1f')}", str(d["failed"])]


def first_stage_section(doc: dict[str, Any]) -> str:
    ex = doc["experiments"]["first_stage"]
    cor = doc["experiments"].get("first_stage_corrected")
    paper = ex["paper_first_stage_pct"]
    variants = [(m, d, ex) for m, d in ex["distributions"].items()]
    variants += [(m, d, cor) for m, d in cor["distributions"].items()] if cor else []
    head = ["variant", "kind", "samples", "median", "p10–p90", "IQR", "failed",
            f"percentile of the paper's {paper:.1f} %", "median / p90, first vs second half of the jitters"]
    rows = []
    for m, d, _ in variants:
        halves = " vs ".join(f"{_num(h['median'], '.1f')} / {_num(h['p90'], '.1f')}" for h in d["halves"])
        rows.append([f"`{m}`", d["kind"], *_dist_cells(d["all"]), f"{d['all']['reference_percentile']:.0f}", halves])
    layouts = list(ex["layouts"])
    def per_layout(d: dict[str, Any]) -> str:
        return "—" if d is None else f"{_num(d['median'], '.1f')} ({_num(d['min'], '.1f')}–{_num(d['max'], '.1f')})"

    lay_rows = [[f"`{m}`"] + [per_layout(d["layouts"].get(lay)) for lay in layouts] for m, d, _ in variants]
    fid = ex["fidelity"]
    flat = markdown_table(["t / t_true", "t (m)", "3 + E_p"],
                  [[f"{r['factor']:g}", f"{r['t']:.3f}", f"{r['three_plus_ep']:.2e}"] for r in fid["ep_flatness"]["rows"]])
    tstar = markdown_table(["s", "t*/t", "1/(1 + s)"],
                   [[f"{r['s']:g}", f"{r['t_ratio']:.3f}", _num(r["law"], ".3f")] for r in fid["t_star_curve"]["rows"]])
    ward = markdown_table(["Dc/t", "t (m)", "TS t*/t", "Ward t*/t", "Ward bias"],
                  [[f"{r['dc_over_t']:g}", f"{r['t']:.3f}", f"{r['ts_t_ratio']:.4f}", f"{r['ward_t_ratio']:.4f}",
                    f"{100 * r['ward_bias']:+.1f} %"] for r in fid["ward_bias"]["rows"]])  # fmt: skip
    curves = ex["ep_curves"]
    lay_text = ", ".join(f"`{k}` {_vec(v['camera_position'], 4)}" for k, v in ex["layouts"].items())
    corrected = (f" The corrected variants (DEPARTURES, `{cor['sweep']}`) ran on jitters "
                 f"{', '.join(cor['jitters'])} of the same set only (they cost 5–10 s a capture), so their "
                 f"halves are one jitter each.") if cor else ""
    return f"""## 5. The paper's first stage as a distribution (§4.1)

{_source(ex)} The §4.1 Ward board, lamp at the paper's (13, 2, 3) units (one unit = {ex['paper_unit_m']} m
and the board centre at the origin are our choice: the paper gives neither unit nor camera),
at {ex['resolution'][0]}×{ex['resolution'][1]} pixels, noise-free. `paper-init` starts its ray at the brightest
pixel, so its error depends on where the pixel grid falls on the highlight: one render is one draw.
Here it is drawn {len(ex['jitters'])} times per layout, the camera's look-at point moved by sub-pixel offsets
(the R2 sequence over one pixel), over a declared family of paper-like layouts, the camera 0.5 m
from the board centre and 18°, 33° (the scene's: the lamp's mirror direction) and 48° off the board
normal: {lay_text}.{corrected} Errors are % of the lamp's distance from the highlight point; the paper's
{paper:.1f} % is its L* = (11.81, 2.16, 3.051) against (13, 2, 3), % of |L_true| from its origin. The
percentile is the share of samples with an error at most the paper's. A failed task counts as a failure
(above every error).

{markdown_table(head, rows)}

Median (min–max) per layout:

{markdown_table(["variant"] + [f"`{lay}`" for lay in layouts], lay_rows)}

**Why** (`nearlight.evaluation.paper.fidelity`, on analytic noise-free captures, no renderer;
the ray from the exact mirror point, an ORACLE). On a plane E_p hardly depends on t: 3 + E_p along
the exact mirror ray of a Torrance–Sparrow board (σ = 0.05, t_true = {fid['ep_flatness']['t_true']:.3f} m):

{flat}

The ray's origin sets t*: from m + s·δ (m the mirror point, δ = {fid['t_star_curve']['delta_px']:.2f} px its
offset to the brightest pixel; s = 1 is the printed paper's origin), t*/t against 1/(1 + s):

{tstar}

Even on the exact ray, the Torrance–Sparrow log-linear model is biased on a Ward surface by an
amount set by Dc/t (Dc = {fid['ward_bias']['dc']:.3f} m the camera's distance, the lamp on the mirror ray
of the board centre at t = Dc/(Dc/t); σ = 0.1, Ward of the same lobe width and peak):

{ward}

The figure: 3 + E_p(t) on the rendered board (layout `{curves['layout']}`, jitter `{curves['jitter']}`; its brightest
pixel is {curves['delta_px']:.2f} px from the true mirror point) along the peak ray (t* = {curves['peak']['t_star'] / curves['peak']['t_true']:.3f} of the lamp's distance) and along the true
mirror ray (t* = {curves['mirror']['t_star'] / curves['mirror']['t_true']:.3f}), over a dense t grid.

{_figures(ex)}
"""


def markdown(doc: dict[str, Any]) -> str:
    """The whole report."""
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
quoted with their section. {tolerance_text(doc)}
"""
    return "\n".join([
        head,
        board_section(doc),
        object_section(doc, "bookend", "2. Bookend (paper §4.3, Figs. 5 and 6)"),
        object_section(doc, "curved", "3. Curved object (paper §4.3, Fig. 7)"),
        distance_section(doc),
        *([first_stage_section(doc)] if "first_stage" in doc["experiments"] else []),
    ])  # fmt: skip
