"""The results file: a method's answers on a suite, written wherever it ran, scored by ``nearlight score``.

A results file (``nearlight-results/1``, docs/benchmark-suites.md, "Results files") is
JSON Lines: a header line naming the suite, the method, its version and the machine,
then one line per case of the suite::

    {"format": "nearlight-results/1", "suite": "core-v1", "version": 1, "cases_hash": "b89baa9ad85aeeaa",
     "method": "my-method", "method_version": "1.2", "machine": "...", "units": "m", "frame": "world"}
    {"case": "<id>", "status": "ok", "lamp_position": [x, y, z], "ks": [r, g, b], "sigma": 0.1,
     "covariance": [[...], [...], [...]], "runtime_s": 0.12}
    {"case": "<id>", "status": "failed", "reason": "no highlight above the noise"}

Positions are metres in the capture's world frame (the frame of its ``P`` and its
camera); ``ks`` and ``sigma`` are the Torrance–Sparrow parameters (or their
equivalents, with the fitted family's own parameters in ``bsdf``); ``covariance`` the
1-σ covariance of the lamp position, m². :func:`read_results` checks a file against a
suite's cases and names the first bad line; :func:`row_estimate` makes a row the
:class:`~nearlight.estimator.Estimate` that is scored, held to the same rules
(:mod:`nearlight.estimator.sanity`) as a plug-in's answer. ``nearlight score --method``
writes its own answers in this format (:func:`estimate_row`), so that one scorer
serves both: a method run by nearlight and one run elsewhere.
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, StrictInt, field_validator, model_validator

from ...capture import read_capture
from ...errors import UserError, one_line
from ...estimator import Estimate
from ...estimator.prediction import fitted_bsdf
from ...files.atomic import write_text
from ...files.schema import validate
from ...physics.reflectance import LOBES

#: The header's ``format``.
FORMAT = "nearlight-results/1"
#: The results file ``nearlight score --method`` writes beside its scorecard.
RESULTS_JSONL = "results.jsonl"
#: Plausibility of the scale: a lamp farther from the camera than this many times the camera's median distance
#: from the surface it sees is refused as a unit error. A suite's lamps stand within a few camera distances
#: (core-v1: 0.3 to 2.3 times); the same lamps in millimetres stand 300 to 2300 times away; the estimator's own
#: ``reach`` rule already refuses, as a failed row, anything beyond 10 times the camera's distance from the highlight.
SCALE_MAX = 100.0
#: The method options the sanity rules read (:mod:`nearlight.estimator.sanity`), kept in a header's ``rules``.
RULES_KEYS = ("separation", "threshold", "t_max")
#: Relative asymmetry of a covariance that is still symmetric (a float32 round trip gives about 1e-7).
SYMMETRY_RTOL = 1e-6

Vec3 = Annotated[list[Annotated[float, Field(strict=False, allow_inf_nan=False)]], Field(min_length=3, max_length=3)]


@functools.cache
def _models() -> tuple[type, type]:
    """The pydantic models of a header and of a row (built on first use)."""
    Finite = Annotated[float, Field(allow_inf_nan=False)]

    class Rules(BaseModel):
        model_config = ConfigDict(extra="forbid")
        separation: Literal["fit", "projected", "maxmin"] = "fit"
        threshold: Annotated[float, Field(gt=0, lt=1, allow_inf_nan=False)] | None = None
        t_max: Annotated[float, Field(gt=0, allow_inf_nan=False)] | None = None

    class Header(BaseModel):
        model_config = ConfigDict(extra="forbid")
        format: Literal["nearlight-results/1"]
        suite: str = Field(min_length=1)
        version: StrictInt
        cases_hash: str = Field(min_length=1)
        method: str = Field(min_length=1, max_length=200)
        method_version: str = Field(min_length=1, max_length=200)
        machine: str = Field(min_length=1, max_length=500)
        units: Literal["m"]
        frame: Literal["world"]
        rules: Rules = Rules()

    class Light(BaseModel):
        model_config = ConfigDict(extra="forbid")
        type: Literal["point", "distant"]
        light_direction: Vec3 | None = None
        view_direction: Vec3 | None = None

        @model_validator(mode="after")
        def _directions(self) -> Light:
            if self.type == "distant" and (self.light_direction is None or self.view_direction is None):
                raise ValueError("a distant light needs light_direction and view_direction")
            return self

    class Row(BaseModel):
        model_config = ConfigDict(extra="forbid")
        case: str = Field(min_length=1)
        status: Literal["ok", "failed"]
        reason: str | None = Field(default=None, min_length=1, max_length=2000)
        lamp_position: Vec3 | None = None
        lamp_positions: list[Vec3] | None = None
        ks: Vec3 | None = None
        sigma: Finite | None = None
        covariance: Annotated[list[Vec3], Field(min_length=3, max_length=3)] | None = None
        bsdf: dict[str, Any] | None = None
        light_model: Light | None = None
        undetermined: list[str] = []
        runtime_s: Annotated[float, Field(ge=0, allow_inf_nan=False)] | None = None

        @model_validator(mode="after")
        def _complete(self) -> Row:
            if self.status == "failed":
                if self.reason is None:
                    raise ValueError("a failed row needs its reason (one line: why the method gave no answer)")
                return self
            for key in ("lamp_position", "ks", "sigma"):
                if getattr(self, key) is None and key not in self.undetermined:
                    raise ValueError(f"{key}: missing (a row with status ok needs lamp_position, ks and sigma, unless "
                                     "undetermined names ks or sigma)")
            return self

        @field_validator("covariance")
        @classmethod
        def _covariance(cls, v: list | None) -> list | None:
            if v is not None:
                covariance_problem(np.asarray(v, dtype=float))
            return v

        @field_validator("bsdf")
        @classmethod
        def _bsdf(cls, v: dict | None) -> dict | None:
            if v is not None:
                bsdf_problem(v)
            return v

    return Header, Row


def covariance_problem(C: np.ndarray) -> None:
    """Raise ``ValueError`` unless ``C`` (3, 3) is symmetric (to :data:`SYMMETRY_RTOL`) and positive definite."""
    scale = float(np.max(np.abs(C))) or 1.0
    if float(np.max(np.abs(C - C.T))) > SYMMETRY_RTOL * scale:
        raise ValueError("not symmetric (a 1-σ covariance of the lamp position, m², is)")
    try:
        np.linalg.cholesky(C)
    except np.linalg.LinAlgError:
        eig = np.linalg.eigvalsh(0.5 * (C + C.T))
        raise ValueError(f"not positive definite (smallest eigenvalue {eig[0]:.3g} m²): it states no "
                         "ellipsoid; leave it out") from None  # fmt: skip


def bsdf_problem(bsdf: Mapping[str, Any]) -> None:
    """Raise ``ValueError`` unless ``bsdf`` is a lobe family's own parameters: ``model`` (a key of
    :data:`~nearlight.physics.reflectance.LOBES`), its colour (3 finite numbers ≥ 0) and roughness (> 0)."""
    model = bsdf.get("model")
    if model not in LOBES:
        raise ValueError(f"model: expected one of {', '.join(LOBES)}, got {model!r}")
    lobe = LOBES[model]
    if set(bsdf) != {"model", lobe.colour_key, lobe.roughness_key}:
        raise ValueError(f"expected the keys model, {lobe.colour_key}, {lobe.roughness_key} for {model}, got "
                         f"{', '.join(sorted(map(str, bsdf)))}")  # fmt: skip
    colour, rough = bsdf[lobe.colour_key], bsdf[lobe.roughness_key]
    if not (isinstance(colour, list) and len(colour) == 3 and all(_finite_number(c) and c >= 0 for c in colour)):
        raise ValueError(f"{lobe.colour_key}: expected 3 finite numbers >= 0, got {colour!r}")
    if not (_finite_number(rough) and rough > 0):
        raise ValueError(f"{lobe.roughness_key}: expected a finite number > 0, got {rough!r}")


def _finite_number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


# --------------------------------------------------------------------------- writing


def header(suite: Mapping[str, Any], *, method: str, method_version: str, machine: str,
           rules: Mapping[str, Any] | None = None) -> dict[str, Any]:  # fmt: skip
    """The header line of a results file for ``suite`` (a manifest: ``suite``, ``version``, ``cases_hash``).

    ``rules``: the options the sanity rules hold the answers with (:data:`RULES_KEYS` of
    :func:`nearlight.estimator.api.rules_options`: how the rules separate the highlight, and the method's own
    search reach); default ``separation`` ``fit``."""
    doc = {"format": FORMAT, "suite": suite["suite"], "version": suite["version"], "cases_hash": suite["cases_hash"],
           "method": method, "method_version": method_version, "machine": machine, "units": "m", "frame": "world"}  # fmt: skip
    kept = {k: float(v) if k != "separation" else v for k, v in (rules or {}).items()
            if k in RULES_KEYS and v is not None}
    if kept:
        doc["rules"] = kept
    return doc


def estimate_row(case_id: str, answer: Estimate | None, reviewed: Estimate | None, *, runtime_s: float | None,
                 error: str | None = None) -> dict[str, Any]:  # fmt: skip
    """The row of one case: ``answer`` as the method gave it (before the rules), or the failure.

    Parameters
    ----------
    case_id : str
    answer : Estimate or None
        The method's own result (:func:`nearlight.estimator.estimate` with ``sanity=False``); None when it
        raised.
    reviewed : Estimate or None
        ``answer`` held to the rules (:func:`nearlight.estimator.sanity.review`). A refused one is written as
        ``failed`` with the rule's reason, so that a re-score of the row fails it the same way.
    runtime_s : float or None
        The method's seconds.
    error : str, optional
        Why there is no answer (the row is ``failed``).

    Returns
    -------
    dict
        One row (:data:`FORMAT`): the method's numbers, its lamp covariance when it is positive definite (a
        covariance that states no ellipsoid is left out: it scores as none), its fitted family's ``bsdf``,
        its ``light_model`` when not a point lamp, its ``undetermined`` quantities.
    """
    row: dict[str, Any] = {"case": case_id}
    judged = reviewed if reviewed is not None else answer
    if error is not None or answer is None or judged is None or not judged.ok:
        failure = judged.diagnostics.get("failure") if judged is not None else None
        reason = error or (f"{failure['rule']}: {failure['reason']}" if failure else "failed")
        row.update(status="failed", reason=one_line(reason)[:2000])
    else:
        undetermined = set(answer.diagnostics.get("undetermined", ()))
        row.update(status="ok", lamp_position=_floats(answer.lamp_position))
        if "ks" not in undetermined:
            row["ks"] = _floats(np.broadcast_to(answer.ks, (3,)))
        if "sigma" not in undetermined:
            row["sigma"] = float(answer.sigma)
        if answer.lamp_positions is not None:
            row["lamp_positions"] = [_floats(p) for p in np.asarray(answer.lamp_positions).reshape(-1, 3)]
        if answer.covariance is not None:
            C = np.asarray(answer.covariance, dtype=float)[:3, :3]
            try:
                covariance_problem(C)
                row["covariance"] = [_floats(r) for r in C]
            except (ValueError, np.linalg.LinAlgError):
                pass
        bsdf = fitted_bsdf(answer)
        if bsdf is not None:
            row["bsdf"] = {k: (_floats(v) if np.ndim(v) else float(v)) if k != "model" else v for k, v in bsdf.items()}
        if answer.light_model.get("type", "point") != "point":
            row["light_model"] = {k: (_floats(v) if k != "type" else v) for k, v in answer.light_model.items()}
        if answer.diagnostics.get("undetermined"):
            row["undetermined"] = [str(q) for q in answer.diagnostics["undetermined"]]
    if runtime_s is not None and math.isfinite(runtime_s):
        row["runtime_s"] = float(runtime_s)
    return row


def _floats(v: Any) -> list[float]:
    return [float(x) for x in np.ravel(v)]


def write_results(path: str | Path, head: Mapping[str, Any], rows: Sequence[Mapping[str, Any]]) -> Path:
    """Write a results file (header line, then ``rows`` in order), atomically."""
    lines = [json.dumps(dict(head), allow_nan=False)] + [json.dumps(dict(r), allow_nan=False) for r in rows]
    return write_text(path, "\n".join(lines) + "\n")


# --------------------------------------------------------------------------- reading and checking


def read_results(path: str | Path, suite: Mapping[str, Any], cases: Sequence[tuple[str, Path]]) -> tuple[dict, dict]:
    """A results file checked against a suite's cases; :class:`UserError` naming the first bad line.

    Parameters
    ----------
    path : path-like
    suite : mapping
        ``suite``, ``version``, ``cases_hash`` (a built suite's manifest or an export's).
    cases : sequence of (case id, input capture folder)
        The suite's cases, in order; each ok row's scale is checked against its capture
        (:data:`SCALE_MAX`).

    Returns
    -------
    header : dict
        The validated header (``rules`` filled with its defaults).
    rows : dict
        Case id -> validated row (a dict), one per case.

    Raises
    ------
    UserError
        ``<path>:<line>: ...`` for the first line that is not JSON, not a valid header or row, a case twice, a case
        not in the suite, a NaN, a malformed covariance or bsdf, a lamp at an implausible scale; ``<path>: case
        ...`` for the first case without a row.
    """
    path = Path(path)
    try:
        text = path.read_bytes().decode("utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise UserError(f"{path}: not a readable results file ({one_line(exc)[:120]})") from None
    Header, Row = _models()
    lines = [(i + 1, s) for i, s in enumerate(text.splitlines()) if s.strip()]
    if not lines:
        raise UserError(f"{path}: empty; expected a header line ({FORMAT}) and one line per case")
    head = validate(Header, _json_line(path, *lines[0]), where=f"{path}:{lines[0][0]}").model_dump()
    for key in ("suite", "version", "cases_hash"):
        if head[key] != suite[key]:
            raise UserError(f"{path}:{lines[0][0]}: {key}: the file answers {head[key]!r}, the suite is "
                            f"{suite[key]!r} (suite {suite['suite']} v{suite['version']}, cases {suite['cases_hash']})")  # fmt: skip
    folders = dict(cases)
    rows: dict[str, dict] = {}
    for lineno, line in lines[1:]:
        doc = _json_line(path, lineno, line)
        case = doc.get("case") if isinstance(doc, dict) else None
        where = f"{path}:{lineno}" + (f": case {case}" if isinstance(case, str) else "")
        row = validate(Row, doc, where=where).model_dump(exclude_none=True)
        if row["case"] not in folders:
            raise UserError(f"{where}: not a case of suite {suite['suite']} v{suite['version']} (an extra row, or "
                            "another suite's)")  # fmt: skip
        if row["case"] in rows:
            raise UserError(f"{where}: a second row for this case (one row per case)")
        if row["status"] == "ok":
            _check_scale(row, folders[row["case"]], where=where)
        rows[row["case"]] = row
    for case_id, folder in cases:
        if case_id not in rows:
            raise UserError(f"{path}: case {case_id} ({folder.parent.name}) has no row; every case needs one (status "
                            "failed with a reason, for a case the method could not answer)")  # fmt: skip
    return head, rows


def _json_line(path: Path, lineno: int, line: str) -> Any:
    try:
        return json.loads(line, parse_constant=lambda c: _refuse_constant(path, lineno, c))
    except (ValueError, RecursionError) as exc:
        if isinstance(exc, UserError):
            raise
        raise UserError(f"{path}:{lineno}: not a JSON line ({one_line(exc)[:120]})") from None


def _refuse_constant(path: Path, lineno: int, constant: str) -> None:
    raise UserError(f"{path}:{lineno}: {constant}: not a number; every number is finite (a method with no answer "
                    "writes status failed)")  # fmt: skip


def _check_scale(row: Mapping[str, Any], folder: Path, *, where: str) -> None:
    """Refuse a lamp farther than :data:`SCALE_MAX` camera distances from the camera (millimetres for metres)."""
    capture = read_capture(folder)
    camera = np.asarray(capture.camera.position, dtype=float)
    P = capture.P.reshape(-1, 3)
    P = P[np.all(np.isfinite(P), axis=1)]
    if not len(P):
        return
    depth = float(np.median(np.linalg.norm(P - camera, axis=1)))
    for lamp in [row["lamp_position"], *row.get("lamp_positions", [])]:
        ratio = float(np.linalg.norm(np.asarray(lamp) - camera)) / depth
        if ratio > SCALE_MAX:
            raise UserError(f"{where}: lamp {lamp} is {ratio:.3g} times the camera's {depth:.3g} m distance from the "
                            f"surface away from the camera (more than {SCALE_MAX:g}): positions are metres in the "
                            "capture's world frame (millimetres?); a method with no answer writes status failed")  # fmt: skip


def row_estimate(row: Mapping[str, Any], method: str) -> Estimate:
    """The :class:`~nearlight.estimator.Estimate` of an ``ok`` row (as the method gave it: the sanity rules come
    after). Its ``bsdf`` goes where ``full`` keeps its fitted family (``stages["full"]["bsdf"]``), so the
    grading re-synthesis and the rules use it."""
    stages = {}
    if "bsdf" in row:
        stages["full"] = {"lobe": row["bsdf"]["model"], "bsdf": dict(row["bsdf"])}
    return Estimate(
        method=method,
        lamp_position=np.asarray(row["lamp_position"], dtype=float),
        ks=np.asarray(row.get("ks", [math.nan] * 3), dtype=float),  # absent: undetermined (the row names it)
        sigma=float(row.get("sigma", math.nan)),
        covariance=None if "covariance" not in row else _lamp_block(row["covariance"]),
        stages=stages,
        diagnostics={"undetermined": list(row["undetermined"])} if row.get("undetermined") else {},
        light_model=dict(row.get("light_model") or {"type": "point"}),
        lamp_positions=None if "lamp_positions" not in row else np.asarray(row["lamp_positions"], dtype=float),
    )


def _lamp_block(C: list) -> np.ndarray:
    """A 3 × 3 lamp covariance as the estimate's (4, 4) ``(x, y, z, σ)`` covariance, σ's row and column NaN
    (not stated): the scorers and the rules read the lamp block only."""
    out = np.full((4, 4), np.nan)
    out[:3, :3] = np.asarray(C, dtype=float)
    return out
