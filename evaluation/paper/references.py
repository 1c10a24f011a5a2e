"""Reproductions kept from other CPUs, each for as long as the code behind its tables is unchanged.

A run on one machine cannot show that its numbers hold on the next one; a run
from another machine, kept, can. ``reports/references/<name>/`` holds one
``paper_reproduction.json`` made elsewhere (or with another LLVM target) and
its ``reference.json``: where it was rendered (CPU, flags, target), the
commit that made it, and per table the :func:`fingerprint` of the code and
inputs that table's numbers depend on. A table of a reference is *applicable*
while today's fingerprint is the one recorded; regenerating the committed
reports on one machine does not touch the references, so another machine's
evidence stays until the code behind it changes. ``tests/evaluation/paper/
test_references.py`` compares this machine's run with every applicable table,
within the tolerance classes of :mod:`nearlight.evaluation.paper.check`.

What a table depends on is its sweep file and scene with the code and
packages that compute its numbers (:func:`nearlight.evaluation.engine.fingerprint.fingerprint`).

``python scripts/keep_reference.py RUN_DIR NAME --tables ...`` keeps a run
(``reports/references/README.md`` lists the references and the CPUs each has
been checked on).

A code change that retires a table need not move its numbers (an estimator
change for captures without normals leaves every table of captures with
them as it was). :func:`carry` keeps such a table applicable: given this
machine's reproduction before the change (made by the code whose
fingerprints the references recorded) and after it, every retired table
whose numbers are the same in both, to the last bit, has its fingerprint
moved to today's, the move written in the record (``carried``). The
evidence is this machine's: the other CPU's numbers are not re-made, and a
table the change moved on this machine is left retired.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from ...errors import UserError, one_line
from ...files.atomic import write_json
from ..engine.fingerprint import REFERENCES, fingerprints as code_fingerprints
from ..engine.run import sweep_inputs

#: Where reproductions are kept.
FOLDER = REFERENCES
#: The record beside a reference's ``paper_reproduction.json``.
RECORD = "reference.json"


def fingerprints(*, quick: bool) -> dict[str, str]:
    """``{table: sha256}`` of what each table of the reproduction (profile ``quick``) depends on, today."""
    from .reproduce import load_sweeps

    return code_fingerprints({table: sweep_inputs(sweep) for table, sweep in load_sweeps(quick=quick).items()})


def keep(run: Path, name: str, tables: Iterable[str], *, note: str, folder: Path = FOLDER) -> Path:
    """Keep the reproduction of ``run`` as reference ``name`` for ``tables`` (their fingerprints today).

    Raises
    ------
    UserError
        ``run`` has no reproduction document, a table is not in it, or ``name`` is taken.
    """
    doc_path = Path(run) / "paper_reproduction.json"
    try:
        doc = json.loads(doc_path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise UserError(f"{doc_path}: cannot read a reproduction document ({exc})") from None
    quick = doc["profile"]["name"] == "quick"
    now = fingerprints(quick=quick)
    tables = list(tables)
    missing = [t for t in tables if t not in doc["experiments"] or t not in now]
    if missing:
        raise UserError(f"--tables: {', '.join(missing)} not in {doc_path} (it has {', '.join(doc['experiments'])})")
    target = folder / name
    if target.exists():
        raise UserError(f"{target}: a reference of that name exists (references are kept, not replaced)")
    target.mkdir(parents=True)
    (target / "paper_reproduction.json").write_bytes(doc_path.read_bytes())
    env = doc.get("environment") or {}
    return write_json(target / RECORD, {
        "profile": doc["profile"]["name"],
        "made_by": doc.get("code_version"),
        "cpu": env.get("cpu"), "cpu_flags": env.get("cpu_flags"), "jit_target": env.get("jit_target", "host"),
        "tables": {t: now[t] for t in tables},
        "note": note,
    }, what="the reference record")


def references(profile: str, folder: Path = FOLDER, names: Iterable[str] | None = None
               ) -> list[tuple[str, dict[str, Any], list[str], list[str]]]:
    """Every kept reference of ``profile`` (or those of ``names``): ``(name, document, applicable, retired)``.

    A table is retired when the code or inputs it depends on changed since it was kept
    (its :func:`fingerprints` differ).
    """
    now = fingerprints(quick=profile == "quick")
    out = []
    for record_path in sorted(folder.glob(f"*/{RECORD}")):
        if names is not None and record_path.parent.name not in names:
            continue
        try:
            record: Mapping[str, Any] = json.loads(record_path.read_text(encoding="utf-8"))
            if record["profile"] != profile:
                continue
            doc = json.loads((record_path.parent / "paper_reproduction.json").read_text(encoding="utf-8"))
            live = [t for t, h in dict(record["tables"]).items() if now.get(t) == h]
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise UserError(f"{record_path}: not a reference record of nearlight's ({one_line(exc)[:80]}); "
                            "expected profile and tables") from None
        out.append((record_path.parent.name, doc, live, [t for t in record["tables"] if t not in live]))
    return out


#: Keys of a reproduction document that differ between any two runs (when and by what code, how long), not numbers.
VOLATILE = frozenset({"code_version", "code_versions", "runtime_s", "seconds", "elapsed_s", "sweep", "results"})


def same_numbers(a: Any, b: Any) -> bool:
    """Whether two parts of reproduction documents hold the same numbers to the last bit, :data:`VOLATILE` keys aside."""
    if isinstance(a, dict) and isinstance(b, dict):
        keys = (set(a) | set(b)) - VOLATILE
        return all(k in a and k in b and same_numbers(a[k], b[k]) for k in keys)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(same_numbers(x, y) for x, y in zip(a, b))
    return a == b or (a != a and b != b)  # NaN is NaN


def carry(before: Path, after: Path, before_fingerprints: Mapping[str, Mapping[str, str]], *, note: str,
          folder: Path = FOLDER) -> list[str]:
    """Carry every reference's retired tables that a code change left as they were (see the module docstring).

    Parameters
    ----------
    before, after : Path
        ``nearlight reproduce --out`` folders (or their ``paper_reproduction.json``) of one machine,
        one profile and one LLVM target, made by the code before the change and by today's.
    before_fingerprints : mapping
        ``{"full": ..., "quick": ...}``, each :func:`fingerprints` of the code that made ``before`` for that
        profile (computed in a checkout of it: ``scripts/keep_reference.py fingerprints``): only a table
        recorded with that fingerprint is carried.
    note : str
        Why, in a line (the change).

    Returns
    -------
    list of str
        ``name/table`` of every table carried.

    Raises
    ------
    UserError
        A folder without a reproduction, or two runs of other machines, targets or profiles.
    """
    docs = []
    for run in (Path(before), Path(after)):
        path = run if run.suffix == ".json" else run / "paper_reproduction.json"
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise UserError(f"{path}: cannot read a reproduction document ({exc})") from None
        if not (isinstance(doc, dict) and isinstance(doc.get("profile"), dict) and isinstance(doc.get("experiments"), dict)):
            raise UserError(f"{path}: not a reproduction document (expected profile and experiments)")
        docs.append(doc)
    old, new = docs
    same = {k: (old.get("environment") or {}).get(k) == (new.get("environment") or {}).get(k)
            for k in ("cpu", "cpu_flags", "jit_target")}
    if not all(same.values()) or old["profile"]["name"] != new["profile"]["name"]:
        differ = [k for k, v in same.items() if not v] + ["profile"] * (old["profile"]["name"] != new["profile"]["name"])
        raise UserError(f"{before} and {after}: not one machine's runs ({', '.join(differ)} differ): the evidence "
                        "that a change left a table as it was is one machine's two runs")
    profile = new["profile"]["name"]
    now = fingerprints(quick=profile == "quick")
    then = before_fingerprints.get(profile)
    if not isinstance(then, Mapping):
        raise UserError(f"the fingerprints of the code before: no {profile!r} profile (expected {{full: ..., quick: ...}})")
    carried = []
    for record_path in sorted(folder.glob(f"*/{RECORD}")):
        record = json.loads(record_path.read_text(encoding="utf-8"))
        if record["profile"] != profile:
            continue
        moved = []
        for table, recorded in record["tables"].items():
            if (recorded != now.get(table) and recorded == then.get(table)
                    and table in old["experiments"] and table in new["experiments"]
                    and same_numbers(old["experiments"][table], new["experiments"][table])):
                record["tables"][table] = now[table]
                moved.append({"table": table, "from": recorded, "to": now[table], "before": old.get("code_version"),
                              "after": new.get("code_version"), "note": note})
        if moved:
            record.setdefault("carried", []).extend(moved)
            write_json(record_path, record, what="the reference record")
            carried += [f"{record_path.parent.name}/{m['table']}" for m in moved]
    return carried
