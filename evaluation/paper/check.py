"""Does a paper reproduction agree with another run of it (another machine, another day)?

Every number of the reproduction is deterministic for given code: renders are
exact for direct light, camera noise is seeded and a continuous function of the
render, and every method is stable under float rounding (each states its
bound in its docstring; ``tests/estimator/test_stability.py``). What can differ
between two machines is the renders' last bits (Dr.Jit compiles for the host
CPU). Two runs of the same profile therefore agree, metric by metric and row by
row, within :data:`TOLERANCES` (absolute, in the metric's units) or
:data:`RELATIVE` of the reference value, whichever is larger. The bounds are
10–100 times the methods' measured float-rounding spread (≤ 3e-5 of the
distance for ``full``, ≤ 1e-5 for the others): tight enough that any change of
code or data shows. The paper's methods are discontinuous by design (the
brightest pixel): should a render's last bits ever change which pixel is
brightest, their rows move by far more and the check names them.
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Iterator
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, create_model, model_validator

from ...errors import UserError, one_line
from ...files.schema import validate

#: Allowed absolute difference per metric between two runs of the same profile, in the metric's units.
TOLERANCES: dict[str, float] = {
    "lamp_position_error_pct": 0.01,  # percentage points of the lamp's distance
    "direction_error_deg": 0.01,
    "sigma_rel_error": 1e-3,
    "ks_rel_error": 1e-3,
    "specular_rmse_rel": 1e-4,
}
#: Allowed relative difference (of the reference value), when larger than the absolute one.
RELATIVE = 1e-3
#: The first-stage study's numbers (``first_stage``: distributions over layouts × jitter, and the
#: analytic ``paper_fidelity`` tables), absolute, in their units. Quantiles are order statistics (or
#: linear interpolations between two) of row errors that agree within ``lamp_position_error_pct``'s
#: 0.01 points, so they agree within the same; the paper's percentile is a count, exact unless a row
#: crosses the paper's 8.9 % (which a 0.01-point move can only do at 8.9 % itself: 1e-9 allows none).
#: The fidelity tables run on analytic captures (numpy only, no renderer): they differ between
#: machines by float rounding only (≤ 1e-12 measured on one machine, run to run: 0); t*/t sits on the
#: 1-mm t grid, so 1e-6 lets none of its grid steps (≥ 1.6e-3 of t) through; 3 + E_p is ~1e-13 at
#: the true t (rounding), hence an absolute 1e-9; δ is found to 1e-4 px (Nelder–Mead's xatol).
STUDY_TOLERANCES: dict[str, float] = {
    "median": 0.01, "p10": 0.01, "p25": 0.01, "p75": 0.01, "p90": 0.01, "min": 0.01, "max": 0.01,
    "reference_percentile": 1e-9, "failed": 0.0,
    "t_ratio": 1e-6, "ts_t_ratio": 1e-6, "ward_t_ratio": 1e-6, "three_plus_ep": 1e-9, "delta_px": 1e-3,
}


def rows(doc: dict[str, Any]) -> Iterator[tuple[str, str, str, float | None]]:
    """Every compared number of a reproduction document: ``(experiment, row, metric, value)``."""
    for name, ex in doc["experiments"].items():
        if "methods" in ex:
            for method, r in ex["methods"].items():
                for metric in TOLERANCES:
                    yield name, method, metric, r.get(metric)
        for label, variant in ex.get("variants", {}).items():
            for method, r in variant["methods"].items():
                for metric in TOLERANCES:
                    yield name, f"{method} ({label})", metric, r.get(metric)
        for r in ex.get("rows", []):
            distance = r.get("lamp_distance_m", r.get("distance_m"))  # distance_m: runs made before the paper sweeps
            for metric in TOLERANCES:
                yield name, f"{r['method']} at {distance:g} m", metric, r.get(metric)
        yield from _study_rows(name, ex)


def _study_rows(name: str, ex: dict[str, Any]) -> Iterator[tuple[str, str, str, float | None]]:
    """The first-stage study's numbers: every sample row, every distribution, the fidelity tables."""
    for r in ex.get("samples", []):
        for metric in TOLERANCES:
            yield name, f"{r['method']} at {r['layout']}/{r['jitter']}", metric, r.get(metric)
    for method, d in ex.get("distributions", {}).items():
        parts = [("all", d["all"])] + [(f"layout {k}", v) for k, v in d["layouts"].items()]
        parts += [(f"jitters {','.join(h['jitters'])}", h) for h in d["halves"]]
        for where, dist in parts:
            for metric in ("median", "p10", "p25", "p75", "p90", "min", "max", "reference_percentile", "failed"):
                yield name, f"{method}: {where}", metric, dist.get(metric)
    if "delta_px" in ex.get("ep_curves", {}):
        yield name, "ep_curves", "delta_px", ex["ep_curves"]["delta_px"]
    fidelity = ex.get("fidelity", {})
    for table, doc in fidelity.items():
        if "delta_px" in doc:
            yield name, table, "delta_px", doc["delta_px"]
        for i, r in enumerate(doc["rows"]):
            for metric, value in r.items():
                if metric in STUDY_TOLERANCES:
                    yield name, f"{table} row {i}", metric, value


def tolerance(metric: str, ref: float | None) -> float:
    """The allowed difference of ``metric`` from a reference value ``ref``."""
    if metric in TOLERANCES:
        return max(TOLERANCES[metric], RELATIVE * abs(ref or 0.0))
    return STUDY_TOLERANCES[metric]


def agree(new: float | None, ref: float | None, metric: str) -> bool:
    """Whether two values of ``metric`` agree within the tolerance (both missing agrees)."""
    if new is None or ref is None:
        return new is None and ref is None
    return math.isfinite(new) and abs(new - ref) <= tolerance(metric, ref)


def check(new: dict[str, Any], ref: dict[str, Any]) -> tuple[list[str], int]:
    """Compare two reproduction documents table by table.

    Parameters
    ----------
    new, ref : dict
        ``paper_reproduction.json`` documents of the same profile.

    Returns
    -------
    lines : list of str
        One summary line per experiment (table), then one line per disagreeing number.
    misses : int
        How many numbers disagree (a row of ``ref`` missing from ``new`` counts once per metric).
    """
    have = {(e, r, m): v for e, r, m, v in rows(new)}
    per_table: dict[str, list[int]] = {}
    details = []
    for e, r, m, v in rows(ref):
        total = per_table.setdefault(e, [0, 0])
        total[0] += 1
        key = (e, r, m)
        if key not in have:
            total[1] += 1
            details.append(f"  {e}: {r}: {m}: missing from the new run (reference {v})")
        elif not agree(have[key], v, m):
            total[1] += 1
            tol = tolerance(m, v)
            details.append(f"  {e}: {r}: {m}: {have[key]} vs reference {v} (allowed ±{tol:.3g})")
    lines = [f"{e}: {n - k} of {n} numbers agree" + (f", {k} differ" if k else "") for e, (n, k) in per_table.items()]
    return lines + details, sum(k for _, k in per_table.values())


def tolerance_text() -> str:
    """The tolerances as one Markdown sentence, for the report."""
    parts = ", ".join(f"{m} ±{t:g}" for m, t in TOLERANCES.items())
    return (f"Two runs of this profile on any machine agree, number by number, within {parts} "
            f"(or {RELATIVE:g} of the value, if larger); the first-stage study's quantiles within the same "
            "0.01 points, its percentile of the paper's number exactly, its analytic tables within float "
            "rounding (t*/t ±1e-6, 3 + E_p ±1e-9); `nearlight reproduce --against DIR` checks a run "
            "against another one's `paper_reproduction.json`, table by table.")


@functools.cache
def _reference_model() -> type:
    """The pydantic model of what :func:`rows` reads from a reproduction document (other keys are free)."""
    free = ConfigDict(extra="allow")
    Number = float | None
    Metrics = create_model("Metrics", __config__=free, **{m: (Number, None) for m in TOLERANCES})
    StudyRow = create_model("StudyRow", __config__=free, **{m: (Number, None) for m in STUDY_TOLERANCES})

    class Methods(BaseModel):
        model_config = free
        methods: dict[str, Metrics]

    class Row(Metrics):  # type: ignore[misc, valid-type]
        method: str
        lamp_distance_m: float | None = None
        distance_m: float | None = None

        @model_validator(mode="after")
        def _distance(self) -> Any:
            if self.lamp_distance_m is None and self.distance_m is None:
                raise ValueError("lamp_distance_m: missing (a row's lamp distance, in metres)")
            return self

    class Sample(Metrics):  # type: ignore[misc, valid-type]
        method: str
        layout: str
        jitter: str

    class Half(StudyRow):  # type: ignore[misc, valid-type]
        jitters: list[str]

    class Distribution(BaseModel):
        model_config = free
        all: StudyRow  # type: ignore[valid-type]
        layouts: dict[str, StudyRow]  # type: ignore[valid-type]
        halves: list[Half]

    class Table(BaseModel):
        model_config = free
        rows: list[StudyRow]  # type: ignore[valid-type]
        delta_px: Number = None

    class Experiment(BaseModel):
        model_config = free
        methods: dict[str, Metrics] = {}  # type: ignore[valid-type]
        variants: dict[str, Methods] = {}
        rows: list[Row] = []
        samples: list[Sample] = []
        distributions: dict[str, Distribution] = {}
        ep_curves: dict[str, Any] = {}
        fidelity: dict[str, Table] = {}

    class Profile(BaseModel):
        model_config = free
        name: str

    class Reference(BaseModel):
        model_config = free
        profile: Profile
        experiments: dict[str, Experiment] = Field(min_length=1)

    return Reference


def read_reference(path: Any, profile: str) -> dict[str, Any]:
    """A reproduction document to check a run against (``reproduce --against``), validated before any work.

    Raises
    ------
    UserError
        One line naming ``path`` and the key: unreadable, not JSON, a key of the wrong kind, no
        experiments, no number to compare, or another profile than ``profile``.
    """
    where = f"--against {path}"
    try:
        doc = json.loads(path.read_bytes().decode("utf-8"))
    except OSError as exc:
        raise UserError(f"{where}: cannot read ({exc.strerror or exc}); expected a folder written by "
                        "`nearlight reproduce`") from None
    except (ValueError, RecursionError) as exc:
        raise UserError(f"{where}: not valid JSON ({one_line(exc)[:80]})") from None
    if not (isinstance(doc, dict) and isinstance(doc.get("experiments"), dict)):
        raise UserError(f"{where}: experiments: expected a paper_reproduction.json document with experiments")
    validate(_reference_model(), doc, where=where)
    if doc["profile"]["name"] != profile:
        raise UserError(f"{where}: profile {doc['profile']['name']!r}, this run is {profile!r} (compare like with like)")
    if next(rows(doc), None) is None:
        raise UserError(f"{where}: experiments: no number to compare (a reference agrees with anything then)")
    return doc
