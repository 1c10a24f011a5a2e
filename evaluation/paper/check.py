"""Does a paper reproduction agree with another run of it (another machine, another day)?

Every number of the reproduction is deterministic for given code and renders:
camera noise is seeded and a continuous function of the render, and every
method is stable under float rounding (each states its bound in its
docstring; ``tests/estimator/test_stability.py``). What can differ between two
machines is the renders' last bits: Dr.Jit compiles for a target CPU, and
although nearlight asks for one portable target on every x86-64-v3 CPU
(:mod:`nearlight.generator.jit_target`), a host target (an older run, another
architecture, ``NEARLIGHT_JIT_TARGET=host``) or another CPU's ray tests can
still move a render by a few hundred ulp. Each number therefore belongs to a
*tolerance class* (:func:`classes` states them per table, the report prints
them, ``reproduce --against`` applies exactly them):

- **continuous** (the numbers of ``full``, ``distant``, an ORACLE variant; the
  analytic ``paper_fidelity`` tables; every number when both runs rendered on
  the same CPU with the same target): within :data:`TOLERANCES` (absolute, in
  the metric's units) or :data:`RELATIVE` of the reference, whichever is
  larger; the first-stage distributions within :data:`STUDY_TOLERANCES`.
  The bounds are 10–100 times the methods' measured float-rounding spread.
- **brightest-pixel** (``paper-init`` and ``paper``, whose first stage picks
  the brightest pixel: discontinuous by design, a render's last bits can flip
  the pixel and move a row by several points), when the reference was
  rendered on another CPU or with another target: a row is not compared value
  by value (how many rows moved is printed); a distribution's quantile must
  change by no more than flips would move it: within the :data:`LEVEL`
  interval of a two-sample bootstrap of both runs' (layout, jitter) samples
  pooled (:func:`agree_as_distributions`), a count (``failed``, the paper's
  percentile) must pass Fisher's exact test at the same level. A
  distribution of fewer than :data:`MIN_SAMPLES` samples cannot tell a flip
  from a change and is not compared (counted as such).

Measured (docs/measurements/cross-cpu-renders.md): the first-stage study of
an AVX2 EPYC (738c131, host target) and of an AVX-512 EPYC with the portable
target agree in all 541 numbers as continuous; with the host target the
AVX-512 machines flipped 45 of them, all inside the brightest-pixel class.
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Iterable, Iterator, Mapping
from typing import Any, NamedTuple

import numpy as np
from scipy import stats

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


#: Method names (a label's text before `` (``) whose estimate starts from the brightest pixel.
BRIGHTEST_PIXEL_METHODS = ("paper-init", "paper")
CONTINUOUS, BRIGHTEST_PIXEL = "continuous", "brightest-pixel"
#: Confidence of the brightest-pixel class's intervals, per number.
LEVEL = 0.999
#: Bootstrap resamples per distribution (fixed seed: the check is deterministic).
BOOTSTRAPS = 4000
#: A brightest-pixel distribution of fewer samples is not compared across renders.
MIN_SAMPLES = 5
QUANTILES = {"p10": 10, "p25": 25, "median": 50, "p75": 75, "p90": 90, "min": 0, "max": 100}
COUNTS = ("failed", "reference_percentile")


class Number(NamedTuple):
    """One compared number of a reproduction document."""

    table: str
    row: str
    metric: str
    value: float | None
    method: str | None  # None: an analytic table (no method)
    select: dict[str, Any] | None = None  # a distribution's samples: {"layout": ...} or {"jitters": [...]}; {} all


def continuity(method: str | None) -> str:
    """The tolerance class of a method's numbers across renders: :data:`CONTINUOUS` or :data:`BRIGHTEST_PIXEL`."""
    if method is None or "ORACLE" in method:
        return CONTINUOUS
    return BRIGHTEST_PIXEL if method.split(" (")[0] in BRIGHTEST_PIXEL_METHODS else CONTINUOUS


def rows(doc: dict[str, Any]) -> Iterator[Number]:
    """Every compared number of a reproduction document."""
    for name, ex in doc["experiments"].items():
        if "methods" in ex:
            for method, r in ex["methods"].items():
                for metric in TOLERANCES:
                    yield Number(name, method, metric, r.get(metric), method)
        for label, variant in ex.get("variants", {}).items():
            for method, r in variant["methods"].items():
                for metric in TOLERANCES:
                    yield Number(name, f"{method} ({label})", metric, r.get(metric), method)
        for r in ex.get("rows", []):
            distance = r.get("lamp_distance_m", r.get("distance_m"))  # distance_m: runs made before the paper sweeps
            for metric in TOLERANCES:
                yield Number(name, f"{r['method']} at {distance:g} m", metric, r.get(metric), r["method"])
        yield from _study_rows(name, ex)


def _study_rows(name: str, ex: dict[str, Any]) -> Iterator[Number]:
    """The first-stage study's numbers: every sample row, every distribution, the fidelity tables."""
    for r in ex.get("samples", []):
        for metric in TOLERANCES:
            yield Number(name, f"{r['method']} at {r['layout']}/{r['jitter']}", metric, r.get(metric), r["method"])
    for method, d in ex.get("distributions", {}).items():
        parts = [("all", d["all"], {})] + [(f"layout {k}", v, {"layout": k}) for k, v in d["layouts"].items()]
        parts += [(f"jitters {','.join(h['jitters'])}", h, {"jitters": h["jitters"]}) for h in d["halves"]]
        for where, dist, select in parts:
            for metric in (*QUANTILES, *COUNTS):
                yield Number(name, f"{method}: {where}", metric, dist.get(metric), method, select)
    if "delta_px" in ex.get("ep_curves", {}):
        yield Number(name, "ep_curves", "delta_px", ex["ep_curves"]["delta_px"], None)
    fidelity = ex.get("fidelity", {})
    for table, doc in fidelity.items():
        if "delta_px" in doc:
            yield Number(name, table, "delta_px", doc["delta_px"], None)
        for i, r in enumerate(doc["rows"]):
            for metric, value in r.items():
                if metric in STUDY_TOLERANCES:
                    yield Number(name, f"{table} row {i}", metric, value, None)


def tolerance(metric: str, ref: float | None) -> float:
    """The continuous class's allowed difference of ``metric`` from a reference value ``ref``."""
    if metric in TOLERANCES:
        return max(TOLERANCES[metric], RELATIVE * abs(ref or 0.0))
    return STUDY_TOLERANCES[metric]


def agree(new: float | None, ref: float | None, metric: str) -> bool:
    """Whether two values of ``metric`` agree within the continuous class (both missing agrees)."""
    if new is None or ref is None:
        return new is None and ref is None
    return math.isfinite(new) and abs(new - ref) <= tolerance(metric, ref)


def machine(doc: Mapping[str, Any]) -> str:
    """Where a document was rendered: CPU model, its code-changing flags, the LLVM target (``host`` if none)."""
    env = doc.get("environment") or {}
    flags = env.get("cpu_flags") or []
    return (f"{env.get('cpu', 'unknown CPU')} ({' '.join(flags) if isinstance(flags, list) else flags}; "
            f"target {env.get('jit_target', 'host')})")


def same_renders(new: Mapping[str, Any], ref: Mapping[str, Any]) -> bool:
    """Whether two documents rendered with the same code: same CPU model, flags, variant and LLVM target."""
    keys = ("cpu", "cpu_flags", "mitsuba_variant", "jit_target")
    a, b = new.get("environment") or {}, ref.get("environment") or {}
    return bool(a) and bool(b) and all(a.get(k) == b.get(k) for k in keys)


def _errors(samples: list[dict[str, Any]], method: str, select: Mapping[str, Any]) -> np.ndarray:
    """The lamp errors (%) of a distribution's samples; a failed sample is +inf (as in the distribution)."""
    out = []
    for r in samples:
        if r["method"] != method or ("layout" in select and r["layout"] != select["layout"]):
            continue
        if "jitters" in select and r["jitter"] not in select["jitters"]:
            continue
        v = r.get("lamp_position_error_pct")
        out.append(v if r.get("status", "ok") == "ok" and v is not None else math.inf)
    return np.asarray(out, dtype=float)


def agree_as_distributions(new: np.ndarray, ref: np.ndarray, metric: str, new_value: float | None,
                           ref_value: float | None) -> tuple[bool, str]:
    """The brightest-pixel class: do two runs' ``metric`` of a distribution differ only as flips would move it?

    Both runs' samples (errors, %; a failure +inf) are taken as draws of one distribution (the
    hypothesis that only brightest-pixel flips differ): quantiles are compared by a two-sample
    bootstrap under that hypothesis (:data:`BOOTSTRAPS` pairs of resamples of the pooled samples,
    of each run's size; the change ``new_value - ref_value`` must lie within the :data:`LEVEL`
    interval of the resampled changes, widened by the continuous 0.01 points); counts (``failed``,
    ``reference_percentile``, a percentage of the samples) by Fisher's exact test at 1 - LEVEL.

    Returns
    -------
    ok : bool
    why : str
        The interval or p-value it was judged by, for the report.
    """
    if new_value is None or ref_value is None:
        return new_value is None and ref_value is None, "one of the two is missing"
    n1, n2 = len(new), len(ref)
    if metric in COUNTS:
        k1, k2 = (round(v) if metric == "failed" else round(v * n / 100.0)
                  for v, n in ((new_value, n1), (ref_value, n2)))
        p = stats.fisher_exact([[k1, n1 - k1], [k2, n2 - k2]]).pvalue
        return bool(p >= 1.0 - LEVEL), f"Fisher's exact test p = {p:.2g} ({k1} of {n1} vs {k2} of {n2})"
    pool = np.concatenate([new, ref])
    rng = np.random.default_rng(0)
    draws = pool[rng.integers(0, len(pool), size=(BOOTSTRAPS, n1 + n2))]
    with np.errstate(invalid="ignore"):
        q1 = np.percentile(draws[:, :n1], QUANTILES[metric], axis=1)
        q2 = np.percentile(draws[:, n1:], QUANTILES[metric], axis=1)
        change = q1 - q2
    change = np.where(np.isnan(change), 0.0, change)  # inf - inf: both resamples failed there
    alpha = 1.0 - LEVEL
    lo, hi = (float(x) for x in np.quantile(change, [alpha / 2, 1 - alpha / 2]))
    tol = STUDY_TOLERANCES[metric]
    d = new_value - ref_value
    return (lo - tol <= d <= hi + tol,
            f"a change of {d:+.3g}; {100 * LEVEL:g} % of flip-only changes lie in {lo - tol:+.3g}…{hi + tol:+.3g} "
            f"(bootstrap of the pooled {n1}+{n2} samples)")


def classes(doc: Mapping[str, Any]) -> dict[str, dict[str, list[str]]]:
    """Per table of ``doc``: its methods by tolerance class (``{table: {class: [method, ...]}}``)."""
    out: dict[str, dict[str, list[str]]] = {}
    for n in rows(doc):  # type: ignore[arg-type]
        if n.method is not None:
            kinds = out.setdefault(n.table, {CONTINUOUS: [], BRIGHTEST_PIXEL: []})[continuity(n.method)]
            if n.method not in kinds:
                kinds.append(n.method)
    return out


def check(new: dict[str, Any], ref: dict[str, Any], *, tables: Iterable[str] | None = None) -> tuple[list[str], int]:
    """Compare two reproduction documents table by table, within each number's tolerance class.

    Parameters
    ----------
    new, ref : dict
        ``paper_reproduction.json`` documents of the same profile.
    tables : iterable of str, optional
        Compare only these experiments (a kept reference's tables whose code is unchanged).

    Returns
    -------
    lines : list of str
        Where each was rendered, one summary line per experiment (table), then one line per
        disagreeing number naming both values and the class it failed.
    misses : int
        How many numbers disagree (a row of ``ref`` missing from ``new`` counts once per metric).
        The summary counts compared numbers; a brightest-pixel row against other renders, and a
        distribution of under :data:`MIN_SAMPLES` samples, are counted apart as not compared.
    """
    wanted = None if tables is None else set(tables)
    strict = same_renders(new, ref)
    have = {(n.table, n.row, n.metric): n.value for n in rows(new)}
    per_table: dict[str, dict[str, int]] = {}
    details = []
    for n in rows(ref):
        if wanted is not None and n.table not in wanted:
            continue
        t = per_table.setdefault(n.table, {"n": 0, "miss": 0, "moved": 0, "rows": 0, "few": 0})
        key = (n.table, n.row, n.metric)
        if key not in have:
            t["n"] += 1
            t["miss"] += 1
            details.append(f"  {n.table}: {n.row}: {n.metric}: missing from the new run (reference {n.value})")
            continue
        value = have[key]
        if strict or continuity(n.method) == CONTINUOUS:
            t["n"] += 1
            if not agree(value, n.value, n.metric):
                t["miss"] += 1
                details.append(f"  {n.table}: {n.row}: {n.metric}: {value} vs reference {n.value} "
                               f"(continuous, allowed ±{tolerance(n.metric, n.value):.3g})")
        elif n.select is None:  # a row of a brightest-pixel method: its flips are seen in its distribution
            t["rows"] += 1
            t["moved"] += not agree(value, n.value, n.metric)
        else:
            samples = [_errors(doc["experiments"][n.table].get("samples", []), n.method, n.select)
                       for doc in (new, ref)]
            if min(len(x) for x in samples) < MIN_SAMPLES:
                t["few"] += 1
                continue
            t["n"] += 1
            ok, why = agree_as_distributions(*samples, n.metric, value, n.value)
            if not ok:
                t["miss"] += 1
                details.append(f"  {n.table}: {n.row}: {n.metric}: {value} vs reference {n.value} "
                               f"(brightest-pixel: {why})")
    how = "same CPU and target: every number continuous" if strict else "other renders: classes apply"
    lines = [f"this run: {machine(new)}; reference: {machine(ref)} ({how})"]
    for e, t in per_table.items():
        line = f"{e}: {t['n'] - t['miss']} of {t['n']} numbers agree" + (f", {t['miss']} differ" if t["miss"] else "")
        if t["rows"]:
            line += (f"; {t['rows']} brightest-pixel row numbers not compared value by value "
                     f"({t['moved']} moved beyond the continuous tolerance)")
        if t["few"]:
            line += f"; {t['few']} brightest-pixel distribution numbers of under {MIN_SAMPLES} samples not compared"
        lines.append(line)
    return lines + details, sum(t["miss"] for t in per_table.values())


def tolerance_text(doc: Mapping[str, Any]) -> str:
    """The tolerance classes as Markdown, for the report: the rule, then each table's methods by class."""
    parts = ", ".join(f"{m} ±{t:g}" for m, t in TOLERANCES.items())
    text = (f"Tolerance classes (`nearlight reproduce --against DIR` applies exactly these, table by table, "
            f"against another run's `paper_reproduction.json`): *continuous* numbers agree within {parts} "
            f"(or {RELATIVE:g} of the value, if larger), the first-stage quantiles within 0.01 points, the "
            "analytic tables within float rounding (t*/t ±1e-6, 3 + E_p ±1e-9). *Brightest-pixel* numbers "
            "(`paper-init`, `paper`: discontinuous by design) are continuous too when both runs rendered on "
            "the same CPU with the same target; against renders from another CPU or target a row is not "
            f"compared value by value, a first-stage quantile may change only within the {100 * LEVEL:g} % "
            "interval of a two-sample bootstrap of both runs' samples pooled, a count must pass Fisher's "
            "exact test at the same level.")
    per = []
    for table, kinds in classes(doc).items():
        said = "; ".join(f"{k}: {', '.join(f'`{m}`' for m in ms)}" for k, ms in kinds.items() if ms)
        per.append(f"`{table}` ({said})")
    return text + " Per table: " + ", ".join(per) + "."


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
