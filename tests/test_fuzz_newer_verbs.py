"""Fuzz layer, part two: the newer verbs (`suite build` / `verify`, `score`, `compare` of scorecards, `gsa`,
`reproduce --against`, plug-ins), hardened as the older ones.

The same rules as :mod:`tests.test_fuzz_inputs` (whose case type, helpers and runner it imports): every
generated case must exit 2 with exactly one stderr line ``nearlight: error: ...`` naming the culprit, no
traceback, and leave its folder byte for byte as it was. The families:

- **hostile manifests**: ids and paths that escape the suite (``../../victim/important``, ``/etc``, a NUL
  byte, a slash, a link out of the folder), keys of the wrong kind or missing, a manifest that is not JSON;
  through ``suite verify``, ``suite verify --against`` and ``score`` (which must not write outside ``--out``
  nor read outside the suite);
- **suite files** and **build places**: keys of the wrong kind, parts, pins, an ``--out`` that is not a suite's;
- **output places** checked before any work: ``compare --json``, ``score --out``, ``gsa``'s report place;
- **compare** of a scorecard against a sweep;
- **baseline**: an ``--out`` that is not a baseline nearlight made (the user's folder, a file, a damaged
  ``sweep.json``), a ``--reason`` that is not one line, bad thresholds, a broken sweep file;
- **references** of ``reproduce --against`` that are damaged or hand-edited (or agree with anything);
- **plug-ins** (``--method module:function``) that fail at import or in the call.

The faults (two builds at once, a full disk, a killed build resumed, a killed worker, a damaged part) are
tests at the end of this file. Nothing renders: suites use the analytic renderer at 24x18.
"""

from __future__ import annotations

import copy
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml

from nearlight.cli import main

from .test_fuzz_inputs import SEED, SWEEP, Case, _dump, _no_rendering, _user_folder, _write, assert_one_clear_line

__all__ = ["_no_rendering"]  # the runner's autouse fixture: a refusal must come before any rendering

CASES: list[Case] = []


def case(id: str) -> Callable:
    def add(build: Callable) -> Callable:
        CASES.append(Case(id, build))
        return build

    return add


REPO = Path(__file__).resolve().parents[1]
#: 2 cases (two lamp distances), noise-free, 24x18 analytic captures.
SUITE = {
    "name": "fuzz-v1",
    "version": 1,
    "renderer": "analytic",
    "scene": {"width": 24, "height": 18},
    "axes": {"lamp_distance": [0.3, 0.5]},
    "seeds": 1,
    "categories": ["lamp_distance"],
}


def _pinned(folder: Path, doc: dict, name: str = "suite.yaml") -> Path:
    from nearlight.evaluation.suites.suite import load_suite

    path = _write(folder / name, _dump(doc))
    return _write(path, _dump({**doc, "cases_hash": load_suite(path, check_pin=False).cases_hash}))


def _copy_suite(folder: Path, assets: dict[str, Path]) -> Path:
    dst = folder / "suite"
    shutil.copytree(assets["suite"], dst)
    return dst


def _manifest(suite: Path) -> tuple[Path, dict]:
    path = suite / "manifest.json"
    return path, json.loads(path.read_text())


# --------------------------------------------------------------------------- hostile and damaged manifests


#: (where, broken value, the key the error line names). ``where`` is a dotted key of the manifest
#: (``cases.0.id``); a value of :data:`DELETE` removes the key.
DELETE = object()
MANIFEST_BREAKS: list[tuple[str, Any, str]] = [
    # ids and paths that escape the suite, or are not one path component
    ("cases.0.id", "../../victim/important", "cases.0.id"),
    ("cases.0.id", "a/b", "cases.0.id"),
    ("cases.0.id", "x\x00y", "cases.0.id"),
    ("cases.0.id", "..", "cases.0.id"),
    ("cases.0.id", "", "cases.0.id"),
    ("cases.0.id", ".hidden", "cases.0.id"),
    ("cases.0.id", 5, "cases.0.id"),
    ("cases.0.id", None, "cases.0.id"),
    ("cases.1.id", "/tmp/x", "cases.1.id"),
    ("cases.0.path", "../outside", "cases.0.path"),
    ("cases.0.path", "/etc", "cases.0.path"),
    ("cases.0.path", "cases/../../x", "cases.0.path"),
    ("cases.0.path", "cases/000\x00", "cases.0.path"),
    ("cases.0.path", "cases\\000", "cases.0.path"),
    ("cases.0.path", "", "cases.0.path"),
    ("cases.0.path", 3, "cases.0.path"),
    ("cases.1.path", "cases//001/..", "cases.1.path"),
    ("cases.0.files", {"../../victim.txt": "0" * 64}, "cases.0.files"),
    ("cases.0.files", {"/etc/hostname": "0" * 64}, "cases.0.files"),
    ("cases.0.files", {"input/../../../x": "0" * 64}, "cases.0.files"),
    ("cases.0.files", {"input/capture.json": "zz"}, "cases.0.files"),
    ("cases.0.files", {"input/capture.json": 5}, "cases.0.files"),
    ("cases.0.files", {}, "cases.0.files"),
    ("cases.0.files", "all", "cases.0.files"),
    # a case without one of its keys
    ("cases.0.files", DELETE, "cases.0.files"),
    ("cases.0.path", DELETE, "cases.0.path"),
    ("cases.0.id", DELETE, "cases.0.id"),
    ("cases.0.seed", DELETE, "cases.0.seed"),
    ("cases.0.categories", DELETE, "cases.0.categories"),
    ("cases.0.digests", DELETE, "cases.0.digests"),
    ("cases.0.noisy", DELETE, "cases.0.noisy"),
    # keys of the wrong kind
    ("cases", 5, "cases"),
    ("cases", "all", "cases"),
    ("cases", [], "cases"),
    ("cases", [5], "cases.0"),
    ("cases", {"0": {}}, "cases"),
    ("cases.0.seed", 1.5, "cases.0.seed"),
    ("cases.0.seed", "0", "cases.0.seed"),
    ("cases.0.noisy", "no", "cases.0.noisy"),
    ("cases.0.categories", "near", "cases.0.categories"),
    ("cases.0.categories", {"lamp_distance": [0.3]}, "cases.0.categories"),
    ("cases.0.digests", {"input": {}}, "cases.0.digests"),
    ("cases.0.digests", "none", "cases.0.digests"),
    ("cases.0.digests.input.P", "x", "cases.0.digests"),
    ("tolerance", "loose", "tolerance"),
    ("tolerance.digest_rtol", "1e-3", "tolerance.digest_rtol"),
    ("tolerance.digest_rtol", -1, "tolerance.digest_rtol"),
    ("tolerance.digest_grid", 0, "tolerance.digest_grid"),
    ("tolerance", DELETE, "tolerance"),
    ("version", "1", "version"),
    ("version", 0, "version"),
    ("version", True, "version"),
    ("suite", 5, "suite"),
    ("suite", "", "suite"),
    ("suite", DELETE, "suite"),
    ("cases_hash", DELETE, "cases_hash"),
    ("categories", "lamp_distance", "categories"),
    ("categories", [1], "categories"),
    ("complete", "yes", "complete"),
    ("complete", DELETE, "complete"),
    ("complete", False, "complete"),
    ("format", "nearlight-suite/2", "format"),
    ("format", DELETE, "format"),
]


def _set(doc: Any, dotted: str, value: Any) -> None:
    *path, last = dotted.split(".")
    node = doc
    for p in path:
        node = node[int(p)] if isinstance(node, list) else node[p]
    key = int(last) if isinstance(node, list) else last
    if value is DELETE:
        del node[key]
    else:
        node[key] = value


def _broken_suite(folder: Path, assets: dict[str, Path], where: str, value: Any) -> Path:
    suite = _copy_suite(folder, assets)
    path, doc = _manifest(suite)
    _set(doc, where, value if value is DELETE else copy.deepcopy(value))
    path.write_text(json.dumps(doc))
    return suite


def _verbs(suite: Path, folder: Path, assets: dict[str, Path]) -> dict[str, list[str]]:
    """The three readers of a manifest, each given ``suite``'s."""
    return {
        "verify": ["suite", "verify", str(suite)],
        "against": ["suite", "verify", str(assets["suite"]), "--against", str(suite / "manifest.json")],
        "score": ["score", str(suite), "--method", "paper-init", "--out", str(folder / "score"), "--quiet"],
    }


def _manifest_cases() -> None:
    for n, (where, value, culprit) in enumerate(MANIFEST_BREAKS):
        for verb in ("verify", "against", "score"):
            @case(f"manifest-{where}-{n}-{verb}")
            def build(folder, assets, where=where, value=value, culprit=culprit, verb=verb):
                suite = _broken_suite(folder, assets, where, value)
                # the user's files a hostile id or path would reach: must stay as they are
                _write(folder / "victim" / "important.parquet", "my data")
                _write(folder / "outside" / "input" / "capture.json", "{}")
                return _verbs(suite, folder, assets)[verb], f"manifest.json: {culprit}"

    rng = random.Random(f"{SEED}-manifest")
    for name, damage in {"truncated": lambda b: b[: len(b) // 3], "empty": lambda b: b"", "array": lambda b: b"[]",
                         "utf16": lambda b: b.decode().encode("utf-16"), "nan": lambda b: b"NaN",
                         "byte": lambda b: b[:40] + b"\xff" + b[41:],
                         "random": lambda b: bytes(rng.randrange(256) for _ in range(200))}.items():  # fmt: skip
        for verb in ("verify", "score"):
            @case(f"manifest-bytes-{name}-{verb}")
            def build(folder, assets, damage=damage, verb=verb):
                suite = _copy_suite(folder, assets)
                path = suite / "manifest.json"
                path.write_bytes(damage(path.read_bytes()))
                return _verbs(suite, folder, assets)[verb], str(path)

    for n, (name, value) in enumerate([("task_id", "../../victim/important"), ("status", "ok"), ("method", "x"),
                                       ("lamp_position_error_pct", 0.0)]):  # fmt: skip
        @case(f"manifest-category-named-like-a-row-column-{name}")
        def build(folder, assets, name=name, value=value):
            suite = _broken_suite(folder, assets, f"cases.0.categories.{name}", value)
            _write(folder / "victim" / "important.parquet", "my data")
            return _verbs(suite, folder, assets)["score"], f"manifest.json: cases.0.categories.{name}"

    for verb in ("verify", "score"):
        @case(f"manifest-duplicate-id-{verb}")
        def build(folder, assets, verb=verb):
            suite = _copy_suite(folder, assets)
            path, doc = _manifest(suite)
            doc["cases"][1]["id"] = doc["cases"][0]["id"]
            path.write_text(json.dumps(doc))
            return _verbs(suite, folder, assets)[verb], "manifest.json: cases"

        @case(f"manifest-case-folder-links-out-{verb}")
        def build(folder, assets, verb=verb):
            suite = _copy_suite(folder, assets)
            _, doc = _manifest(suite)
            victim = folder / "elsewhere"
            shutil.move(suite / doc["cases"][0]["path"], victim)
            os.symlink(victim, suite / doc["cases"][0]["path"])
            return _verbs(suite, folder, assets)[verb], "path"

        @case(f"manifest-file-links-out-{verb}")
        def build(folder, assets, verb=verb):
            suite = _copy_suite(folder, assets)
            _, doc = _manifest(suite)
            f = suite / doc["cases"][0]["path"] / "input" / "capture.json"
            outside = _write(folder / "notes.json", f.read_text())
            f.unlink()
            os.symlink(outside, f)
            return _verbs(suite, folder, assets)[verb], "files"


_manifest_cases()


# --------------------------------------------------------------------------- suite files and build places


def _build_argv(path: Path, folder: Path) -> list[str]:
    return ["suite", "build", str(path), "--out", str(folder / "built"), "--quiet", "--no-cache"]


SUITE_BREAKS: dict[str, list[Any]] = {
    "version": ["1", 0, -2, True, None, 1.5],
    "name": [None, "", 5],
    "categories": ["lamp_distance", ["bogus"], [1]],
    "methods": [["paper"]],
    "cases_hash": ["0000000000000000", 5],
    "parts": [5, [], [{"scene": {"width": 24, "height": 18}}], [{"name": "a/b", "scene": 5}],
              [{"name": "a", "scene": {"width": 24, "height": 18}, "bogus": 1}]],
    "axes": [{"lamp_distance": "near"}, {"nonsense": [1]}],
}


def _suite_file_cases() -> None:
    for key, values in SUITE_BREAKS.items():
        for i, value in enumerate(values):
            @case(f"suite-file-{key}-{i}")
            def build(folder, assets, key=key, value=value):
                doc = {**SUITE, key: value, "cases_hash": "pin"}
                if key == "parts":
                    doc.pop("scene")
                path = _write(folder / "suite.yaml", _dump(doc))
                return _build_argv(path, folder), f"{path}: {key}"

    @case("suite-build-out-user-folder")
    def build(folder, assets):
        d = _user_folder(folder, "built")
        return _build_argv(_pinned(folder, SUITE), folder), str(d)

    @case("suite-build-out-is-a-file")
    def build(folder, assets):
        f = _write(folder / "built", "x")
        return _build_argv(_pinned(folder, SUITE), folder), str(f)

    @case("suite-build-out-another-suite")
    def build(folder, assets):
        shutil.copytree(assets["suite"], folder / "built")
        return _build_argv(_pinned(folder, {**SUITE, "name": "other-v1", "axes": {"lamp_distance": [0.35, 0.5]}}), folder), str(folder / "built")

    @case("suite-build-out-user-manifest")
    def build(folder, assets):
        _write(folder / "built" / "manifest.json", '{"my": "manifest"}')
        return _build_argv(_pinned(folder, SUITE), folder), "manifest.json"


_suite_file_cases()


# --------------------------------------------------------------------------- output places, before any work


def _score_argv(suite: Path, out: Path, method: str = "paper-init") -> list[str]:
    return ["score", str(suite), "--method", method, "--out", str(out), "--quiet"]


def _output_place_cases() -> None:
    for name, text in {"notes": '{"my": "notes"}', "list": "[1, 2]", "text": "not json", "sweep-json":
                       '{"format": "nearlight-sweep/1", "name": "x"}'}.items():  # fmt: skip
        @case(f"out-compare-json-user-file-{name}")
        def build(folder, assets, text=text):
            f = _write(folder / "notes.json", text)
            return ["compare", str(assets["score"]), str(assets["score"]), "--json", str(f)], str(f)

    @case("out-compare-json-wrong-suffix")
    def build(folder, assets):
        return ["compare", str(assets["score"]), str(assets["score"]), "--json", str(folder / "c.txt")], "c.txt"

    @case("out-compare-json-is-a-folder")
    def build(folder, assets):
        (folder / "c.json").mkdir()
        return ["compare", str(assets["score"]), str(assets["score"]), "--json", str(folder / "c.json")], "c.json"

    @case("out-compare-json-under-a-file")
    def build(folder, assets):
        f = _write(folder / "f", "x")
        return ["compare", str(assets["score"]), str(assets["score"]), "--json", str(f / "c.json")], str(f / "c.json")

    @case("out-compare-json-user-file-sweeps")
    def build(folder, assets):
        f = _write(folder / "verdict.json", '{"mine": 1}')
        return ["compare", str(assets["results"]), str(assets["results"]), "--json", str(f)], str(f)

    for name in ("scorecard.md", "scorecard.json", "scorecard.png"):
        @case(f"out-score-user-{name}")
        def build(folder, assets, name=name):
            f = _write(folder / "score" / name, "my own notes\n")
            return _score_argv(assets["suite"], folder / "score"), str(f)

    @case("out-score-out-is-a-file")
    def build(folder, assets):
        f = _write(folder / "score", "x")
        return _score_argv(assets["suite"], f), str(f)

    @case("out-score-out-another-run")
    def build(folder, assets):
        shutil.copytree(assets["score"], folder / "score")
        return _score_argv(assets["suite"], folder / "score", "distant"), str(folder / "score")

    @case("out-score-out-a-sweep")
    def build(folder, assets):
        shutil.copytree(assets["results"], folder / "score")
        return _score_argv(assets["suite"], folder / "score"), str(folder / "score")

    for name in ("gsa.md", "indices.csv", "outputs.csv", "indices_lamp_position_error_pct.png", "scatter_paper-init.png"):
        @case(f"out-gsa-report-user-{name}")
        def build(folder, assets, name=name):
            f = _write(folder / "res" / "main" / "gsa" / name, "my own notes\n")
            return ["gsa", str(_gsa_file(folder)), "--out", str(folder / "res"), "--quiet"], str(f)

    @case("out-gsa-report-folder-is-a-file")
    def build(folder, assets):
        f = _write(folder / "res" / "main" / "gsa", "x")
        return ["gsa", str(_gsa_file(folder)), "--out", str(folder / "res"), "--quiet"], str(f)

    @case("out-gsa-out-is-a-file")
    def build(folder, assets):
        f = _write(folder / "res", "x")
        return ["gsa", str(_gsa_file(folder)), "--out", str(f), "--quiet"], str(f)


GSA = {
    "name": "fuzz-gsa", "renderer": "analytic", "scene": {"width": 16, "height": 12},
    "methods": ["paper-init"], "crlb": False, "metrics": ["lamp_position_error_pct"],
    "inputs": {"lamp_distance": {"low": 0.2, "high": 0.6}, "roughness": {"low": 0.05, "high": 0.25}},
    "designs": {"main": {"method": "sobol", "n": 4}},
}  # fmt: skip


def _gsa_file(folder: Path) -> Path:
    return _write(folder / "gsa.yaml", _dump(GSA))


_output_place_cases()


# --------------------------------------------------------------------------- compare: like with like


def _compare_cases() -> None:
    @case("compare-scorecard-against-sweep")
    def build(folder, assets):
        return ["compare", str(assets["score"]), str(assets["results"])], str(assets["results"])

    @case("compare-sweep-against-scorecard")
    def build(folder, assets):
        return ["compare", str(assets["results"]), str(assets["score"])], str(assets["results"])

    for name, data in {"garbage": b"garbage" * 20, "empty": b"", "truncated": None}.items():
        @case(f"compare-score-part-{name}")
        def build(folder, assets, data=data):
            score = folder / "score"
            shutil.copytree(assets["score"], score)
            (score / "results.parquet").unlink()
            part = sorted((score / "parts").glob("*.parquet"))[0]
            part.write_bytes(part.read_bytes()[:50] if data is None else data)
            return ["compare", str(score), str(assets["score"])], str(part)


_compare_cases()


# --------------------------------------------------------------------------- baseline


def _baseline_cases() -> None:
    def argv(sweep: Path, out: Path, *extra: str) -> list[str]:
        return ["baseline", str(sweep), "--out", str(out), "--quiet", *extra]

    @case("baseline-out-user-folder")
    def build(folder, assets):
        return argv(_write(folder / "sweep.yaml", _dump(SWEEP)), _user_folder(folder)), "mine"

    @case("baseline-out-is-a-file")
    def build(folder, assets):
        return argv(_write(folder / "sweep.yaml", _dump(SWEEP)), _write(folder / "notes.txt", "x")), "notes.txt"

    @case("baseline-out-damaged-sweep-json")
    def build(folder, assets):
        out = folder / "old-baseline"
        shutil.copytree(assets["results"], out)
        (out / "sweep.json").write_text("{not json")
        return argv(_write(folder / "sweep.yaml", _dump(SWEEP)), out), "sweep.json"

    for name, value in {"empty": "", "blank": "   ", "two-lines": "first\nsecond"}.items():
        @case(f"baseline-reason-{name}")
        def build(folder, assets, value=value):
            return argv(_write(folder / "sweep.yaml", _dump(SWEEP)), folder / "b", "--reason", value), "--reason"

    for flag, value in (("--alpha", "2"), ("--alpha", "0"), ("--tolerance", "-1"), ("--tolerance", "nan"),
                        ("--workers", "0")):  # fmt: skip
        @case(f"baseline-{flag.strip('-')}-{value}")
        def build(folder, assets, flag=flag, value=value):
            return argv(_write(folder / "sweep.yaml", _dump(SWEEP)), folder / "b", flag, value), flag

    for key, value in (("methods", ["nosuchmethod"]), ("seeds", -1), ("renderer", "povray")):
        @case(f"baseline-sweep-{key}")
        def build(folder, assets, key=key, value=value):
            return argv(_write(folder / "sweep.yaml", _dump({**SWEEP, key: value})), folder / "b"), "sweep.yaml"

    @case("baseline-sweep-missing")
    def build(folder, assets):
        return argv(folder / "nosuch.yaml", folder / "b"), "nosuch.yaml"


_baseline_cases()


# --------------------------------------------------------------------------- reproduce --against


def _reference_doc() -> dict:
    """A real reproduction document (the committed one), as the quick profile's."""
    doc = json.loads((REPO / "reports" / "paper_reproduction" / "paper_reproduction.json").read_text())
    doc["profile"]["name"] = "quick"
    return doc


REFERENCE_BREAKS: list[tuple[str, Any, str]] = [
    ("experiments", {}, "experiments"),
    ("experiments", 5, "experiments"),
    ("experiments", [], "experiments"),
    ("experiments", {"board": {}}, "experiments: no number"),
    ("experiments", {"board": {"figures": []}}, "experiments: no number"),
    ("experiments.board", "x", "experiments.board"),
    ("experiments.board.methods", [1], "experiments.board.methods"),
    ("experiments.board.methods.paper-init", "ok", "experiments.board.methods.paper-init"),
    ("experiments.board.methods.paper-init.lamp_position_error_pct", "big",
     "experiments.board.methods.paper-init.lamp_position_error_pct"),
    ("experiments.board.methods.paper-init.sigma_rel_error", [0.1], "experiments.board.methods.paper-init.sigma_rel_error"),
    ("experiments.near_vs_distant.rows", "all", "experiments.near_vs_distant.rows"),
    ("experiments.near_vs_distant.rows", [{"method": 1}], "experiments.near_vs_distant.rows.0"),
    ("experiments.near_vs_distant.rows", [{"method": "paper"}], "experiments.near_vs_distant.rows.0"),
    ("experiments.near_vs_distant.rows.0.lamp_distance_m", "far", "experiments.near_vs_distant.rows.0.lamp_distance_m"),
    ("experiments.bookend.variants", {"x": {}}, "experiments.bookend.variants.x.methods"),
    ("experiments.bookend.variants", {"x": 1}, "experiments.bookend.variants.x"),
    ("experiments.first_stage.distributions", {"paper": {}}, "experiments.first_stage.distributions.paper"),
    ("experiments.first_stage.distributions", 3, "experiments.first_stage.distributions"),
    ("experiments.first_stage.samples", [{"method": "paper"}], "experiments.first_stage.samples.0"),
    ("experiments.first_stage.ep_curves", "flat", "experiments.first_stage.ep_curves"),
    ("profile", DELETE, "profile"),
    ("profile", "quick", "profile"),
    ("profile.name", 5, "profile.name"),
    ("profile.name", "full", "profile 'full'"),
]


def _reference_cases() -> None:
    base = _reference_doc()

    def argv(folder: Path) -> list[str]:
        return ["reproduce", "--quick", "--out", str(folder / "repro"), "--quiet", "--against", str(folder / "ref")]

    for n, (where, value, culprit) in enumerate(REFERENCE_BREAKS):
        @case(f"reference-{where}-{n}")
        def build(folder, assets, where=where, value=value, culprit=culprit):
            doc = copy.deepcopy(base)
            _set(doc, where, value if value is DELETE else copy.deepcopy(value))
            _write(folder / "ref" / "paper_reproduction.json", json.dumps(doc))
            return argv(folder), f"paper_reproduction.json: {culprit}"

    for name, data in {"empty": b"", "array": b"[]", "truncated": json.dumps(base).encode()[:500],
                       "utf16": json.dumps({"experiments": {}}).encode("utf-16")}.items():  # fmt: skip
        @case(f"reference-bytes-{name}")
        def build(folder, assets, data=data):
            _write(folder / "ref" / "paper_reproduction.json", data)
            return argv(folder), "paper_reproduction.json"

    @case("reference-missing")
    def build(folder, assets):
        (folder / "ref").mkdir()
        return argv(folder), "paper_reproduction.json"

    # a kept reference (reports/references/): its record damaged, or every table retired
    records = {"not-json": b"{", "array": b"[]", "no-tables": json.dumps({"profile": "quick"}).encode(),
               "tables-list": json.dumps({"profile": "quick", "tables": ["board"]}).encode(),
               "retired": json.dumps({"profile": "quick", "tables": {"board": "0" * 64}}).encode()}
    for name, data in records.items():
        @case(f"reference-record-{name}")
        def build(folder, assets, data=data, name=name):
            _write(folder / "ref" / "paper_reproduction.json", json.dumps(base))
            _write(folder / "ref" / "reference.json", data)
            return argv(folder), ("every table of this kept reference is retired" if name == "retired"
                                  else "reference.json: not a reference record")


_reference_cases()


# --------------------------------------------------------------------------- plug-ins


#: Plug-in modules that fail at import or in the call, and how each must be named.
PLUGINS: dict[str, tuple[str, str]] = {
    "syntax-error": ("def fit(capture)\n    return 1\n", "SyntaxError"),
    "raises-at-import": ("raise RuntimeError('no licence server')\ndef fit(capture): pass\n", "RuntimeError"),
    "exit-0-at-import": ("import sys\nsys.exit(0)\n", "SystemExit"),
    "exit-3-at-import": ("import sys\nsys.exit(3)\n", "SystemExit"),
    "missing-dependency": ("import nearlight_no_such_dependency\n", "cannot import"),
    "no-function": ("x = 1\n", "has no function"),
    "not-callable": ("fit = 5\n", "has no function"),
    "zero-division-at-import": ("1 / 0\n", "ZeroDivisionError"),
    "recursion-at-import": ("def f(): return f()\nf()\n", "RecursionError"),
}
#: Plug-ins whose import succeeds and whose call fails (``estimate``: one line naming the plug-in).
CALL_FAILURES: dict[str, tuple[str, str]] = {
    "exit-0-in-call": ("import sys\ndef fit(capture):\n    sys.exit(0)\n", "SystemExit"),
    "exit-message-in-call": ("import sys\ndef fit(capture):\n    sys.exit('bye')\n", "SystemExit"),
    "raises-in-call": ("def fit(capture):\n    raise ValueError('bad pixels')\n", "ValueError"),
    "returns-none": ("def fit(capture):\n    return None\n", "returned NoneType"),
    "returns-dict": ("def fit(capture):\n    return {'lamp': [0, 0, 1]}\n", "returned dict"),
    "bad-signature": ("def fit():\n    return None\n", "fit"),
}


def _plugin_cases() -> None:
    for n, (name, (source, culprit)) in enumerate({**PLUGINS, **CALL_FAILURES}.items()):
        module = f"nl_fuzz_plugin_{n}_{name.replace('-', '_')}"
        verbs = ("estimate", "score") if name in PLUGINS else ("estimate",)
        for verb in verbs:
            @case(f"plugin-{name}-{verb}")
            def build(folder, assets, source=source, culprit=culprit, module=module, verb=verb):
                _write(folder / "plugins" / f"{module}.py", source)
                sys.path.insert(0, str(folder / "plugins"))  # removed by the runner fixture
                spec = f"{module}:fit"
                if verb == "estimate":
                    shutil.copytree(assets["suite"] / "cases" / "000" / "input", folder / "cap")
                    return ["estimate", str(folder / "cap"), "--method", spec], f"method {spec}"
                return _score_argv(assets["suite"], folder / "score", spec), f"method {spec}"


_plugin_cases()


# --------------------------------------------------------------------------- results files and exports


def _results_lines(assets: dict[str, Path]) -> list[dict]:
    """The results file `score --method paper-init` wrote for the fuzz suite (header, then a row per case)."""
    return [json.loads(s) for s in (assets["score"] / "results.jsonl").read_text().splitlines()]


def _ok_line(lines: list[dict]) -> int:
    """Index of the first row with an answer (a case needs one; the fuzz suite's lamps are near and noise-free)."""
    ok = [i for i, r in enumerate(lines) if i and r.get("status") == "ok"]
    assert ok, "paper-init answered no case of the fuzz suite"
    return ok[0]


def _results_argvs(suite: Path, path: Path, folder: Path) -> dict[str, list[str]]:
    """The two readers of a results file: `--check` (writes nothing) and `--results` (must write nothing either)."""
    return {"check": ["score", str(suite), "--check", str(path)],
            "results": ["score", str(suite), "--results", str(path), "--out", str(folder / "score"), "--quiet"]}  # fmt: skip


#: (name, where in the file: "header" or "row", key, broken value, the text the error line names).
RESULTS_BREAKS: list[tuple[str, str, str, Any, str]] = [
    ("header-format", "header", "format", "nearlight-results/2", "format"),
    ("header-no-format", "header", "format", DELETE, "format"),
    ("header-units-mm", "header", "units", "mm", "units"),
    ("header-frame-camera", "header", "frame", "camera", "frame"),
    ("header-no-method", "header", "method", DELETE, "method"),
    ("header-method-empty", "header", "method", "", "method"),
    ("header-method-number", "header", "method", 5, "method"),
    ("header-no-machine", "header", "machine", DELETE, "machine"),
    ("header-version-string", "header", "version", "1", "version"),
    ("header-other-suite", "header", "suite", "core-v1", "suite"),
    ("header-other-version", "header", "version", 2, "version"),
    ("header-other-cases", "header", "cases_hash", "ffffffffffffffff", "cases_hash"),
    ("header-extra-key", "header", "truth", {"lamp": [0, 0, 1]}, "truth"),
    ("header-rules-separation", "header", "rules", {"separation": "guess"}, "rules.separation"),
    ("header-rules-threshold", "header", "rules", {"threshold": 2}, "rules.threshold"),
    ("header-rules-unknown", "header", "rules", {"reach": 100}, "rules.reach"),
    ("row-status", "row", "status", "maybe", "status"),
    ("row-no-status", "row", "status", DELETE, "status"),
    ("row-no-lamp", "row", "lamp_position", DELETE, "lamp_position"),
    ("row-lamp-two", "row", "lamp_position", [0.1, 0.2], "lamp_position"),
    ("row-lamp-four", "row", "lamp_position", [0.1, 0.2, 0.3, 0.4], "lamp_position"),
    ("row-lamp-string", "row", "lamp_position", ["0.1", "x", 0.3], "lamp_position"),
    ("row-lamp-dict", "row", "lamp_position", {"x": 0.1}, "lamp_position"),
    ("row-lamp-mm", "row", "lamp_position", [100.0, 200.0, 450.0], "millimetres?"),
    ("row-no-ks", "row", "ks", DELETE, "ks"),
    ("row-ks-scalar", "row", "ks", 0.5, "ks"),
    ("row-sigma-string", "row", "sigma", "rough", "sigma"),
    ("row-no-sigma", "row", "sigma", DELETE, "sigma"),
    ("row-cov-2x2", "row", "covariance", [[1e-6, 0], [0, 1e-6]], "covariance"),
    ("row-cov-negative", "row", "covariance", [[1e-6, 0, 0], [0, -1e-6, 0], [0, 0, 1e-6]], "not positive definite"),
    ("row-cov-zero", "row", "covariance", [[0, 0, 0], [0, 0, 0], [0, 0, 0]], "not positive definite"),
    ("row-cov-asymmetric", "row", "covariance", [[1e-6, 5e-7, 0], [0, 1e-6, 0], [0, 0, 1e-6]], "not symmetric"),
    ("row-bsdf-model", "row", "bsdf", {"model": "phong", "ks": [1, 1, 1], "sigma": 0.1}, "bsdf"),
    ("row-bsdf-keys", "row", "bsdf", {"model": "ward", "ks": [1, 1, 1], "sigma": 0.1}, "rho_s"),
    ("row-bsdf-rough", "row", "bsdf", {"model": "ward", "rho_s": [1, 1, 1], "alpha": -0.1}, "alpha"),
    ("row-light-distant-bare", "row", "light_model", {"type": "distant"}, "light_model"),
    ("row-light-area", "row", "light_model", {"type": "area"}, "light_model.type"),
    ("row-runtime-negative", "row", "runtime_s", -1.0, "runtime_s"),
    ("row-extra-key", "row", "truth", [0, 0, 1], "truth"),
    ("row-case-number", "row", "case", 5, "case"),
    ("row-no-case", "row", "case", DELETE, "case"),
    ("row-failed-no-reason", "row", "status", "failed", "needs its reason"),
]
#: Whole files that are not a results file: (name, bytes, the text the error line names).
RESULTS_FILES: list[tuple[str, bytes, str]] = [
    ("empty", b"", "empty"),
    ("blank-lines", b"\n\n  \n", "empty"),
    ("binary", bytes(range(256)) * 4, "results.jsonl"),
    ("latin-1", '{"format": "nearlight-résults/1"}\n'.encode("latin-1"), "results.jsonl"),
    ("not-json", b"{not json\n", "results.jsonl:1: not a JSON line"),
    ("a-list", b"[1, 2, 3]\n", "results.jsonl:1"),
    ("a-scorecard", b'{"format": "nearlight-scorecard/1"}\n', "format"),
    ("deep", b"[" * 100_000 + b"]" * 100_000 + b"\n", "results.jsonl:1"),
]


def _results_file_cases() -> None:
    for name, where, key, value, culprit in RESULTS_BREAKS:
        for verb in ("check", "results"):
            @case(f"results-{name}-{verb}")
            def build(folder, assets, where=where, key=key, value=value, culprit=culprit, verb=verb):
                lines = _results_lines(assets)
                i = 0 if where == "header" else _ok_line(lines)
                _set(lines[i], key, value if value is DELETE else copy.deepcopy(value))
                if key == "status" and value == "failed":
                    lines[i].pop("reason", None)
                path = _write(folder / "results.jsonl", "\n".join(json.dumps(r) for r in lines) + "\n")
                return _results_argvs(assets["suite"], path, folder)[verb], f"results.jsonl:{i + 1}"

            @case(f"results-{name}-{verb}-names-key")
            def build2(folder, assets, build=build, culprit=culprit):
                argv, _ = build(folder, assets)
                return argv, culprit

    for name, data, culprit in RESULTS_FILES:
        for verb in ("check", "results"):
            @case(f"results-file-{name}-{verb}")
            def build(folder, assets, data=data, culprit=culprit, verb=verb):
                path = _write(folder / "results.jsonl", data)
                return _results_argvs(assets["suite"], path, folder)[verb], culprit

    for constant in ("NaN", "Infinity", "-Infinity"):
        for verb in ("check", "results"):
            @case(f"results-constant-{constant}-{verb}")
            def build(folder, assets, constant=constant, verb=verb):
                lines = [json.dumps(r) for r in _results_lines(assets)]
                i = _ok_line(_results_lines(assets))
                lines[i] = lines[i].replace('"sigma": ', f'"sigma": {constant}, "was": ', 1)
                path = _write(folder / "results.jsonl", "\n".join(lines) + "\n")
                return _results_argvs(assets["suite"], path, folder)[verb], f"results.jsonl:{i + 1}: {constant}"

    for name in ("missing", "twice", "extra"):
        for verb in ("check", "results"):
            @case(f"results-case-{name}-{verb}")
            def build(folder, assets, name=name, verb=verb):
                lines = _results_lines(assets)
                ids = [r["case"] for r in lines[1:]]
                if name == "missing":
                    lines, culprit = lines[:-1], f"case {ids[-1]}"
                elif name == "twice":
                    lines, culprit = [*lines, lines[1]], f"results.jsonl:{len(lines) + 1}: case {ids[0]}"
                else:
                    lines = [*lines, {**lines[1], "case": "0123456789abcdef"}]
                    culprit = f"results.jsonl:{len(lines)}: case 0123456789abcdef"
                path = _write(folder / "results.jsonl", "\n".join(json.dumps(r) for r in lines) + "\n")
                return _results_argvs(assets["suite"], path, folder)[verb], culprit

    for verb in ("check", "results"):
        @case(f"results-file-missing-{verb}")
        def build(folder, assets, verb=verb):
            return _results_argvs(assets["suite"], folder / "nosuch.jsonl", folder)[verb], "nosuch.jsonl"

        @case(f"results-file-is-a-folder-{verb}")
        def build(folder, assets, verb=verb):
            (folder / "r.jsonl").mkdir()
            return _results_argvs(assets["suite"], folder / "r.jsonl", folder)[verb], "r.jsonl"

    # the verb's grammar: what --check and --results take, and what they refuse
    @case("results-check-with-out")
    def build(folder, assets):
        return ["score", str(assets["suite"]), "--check", str(assets["score"] / "results.jsonl"), "--out",
                str(folder / "o")], "--check"  # fmt: skip

    @case("results-with-set")
    def build(folder, assets):
        return ["score", str(assets["suite"]), "--results", str(assets["score"] / "results.jsonl"), "--set",
                "t_max=3", "--out", str(folder / "o")], "--set"  # fmt: skip

    @case("results-without-out")
    def build(folder, assets):
        return ["score", str(assets["suite"]), "--results", str(assets["score"] / "results.jsonl")], "--out"

    @case("results-against-an-export")
    def build(folder, assets):
        return ["score", str(assets["export"]), "--results", str(assets["score"] / "results.jsonl"), "--out",
                str(folder / "o"), "--quiet"], "without the truth"  # fmt: skip

    @case("results-out-user-results-jsonl")
    def build(folder, assets):
        f = _write(folder / "score" / "results.jsonl", '{"my": "answers"}\n')
        return _score_argv(assets["suite"], folder / "score"), str(f)

    @case("results-out-holds-another-file-s-run")
    def build(folder, assets):
        shutil.copytree(assets["score"], folder / "score")
        lines = _results_lines(assets)
        lines[0]["method_version"] = "other"
        path = _write(folder / "r.jsonl", "\n".join(json.dumps(r) for r in lines) + "\n")
        return ["score", str(assets["suite"]), "--results", str(path), "--out", str(folder / "score"),
                "--quiet"], "holds another run"  # fmt: skip


#: (where in an export's manifest, broken value, the key the error line names).
EXPORT_BREAKS: list[tuple[str, Any, str]] = [
    ("cases.0.path", "../outside", "cases.0.path"),
    ("cases.0.path", "/etc", "cases.0.path"),
    ("cases.0.id", "../../victim", "cases.0.id"),
    ("cases.0.files", {"../../victim.txt": "0" * 64}, "cases.0.files"),
    ("cases.0.files", {"input/capture.json": "zz"}, "cases.0.files"),
    ("cases.0.files", {}, "cases.0.files"),
    ("cases.0.truth", {"lamp": [0, 0, 1]}, "cases.0.truth"),
    ("cases", [], "cases"),
    ("cases", "all", "cases"),
    ("version", "1", "version"),
    ("suite", "", "suite"),
    ("cases_hash", DELETE, "cases_hash"),
]


def _export_cases() -> None:
    for n, (where, value, culprit) in enumerate(EXPORT_BREAKS):
        for verb in ("verify", "check"):
            @case(f"export-manifest-{where}-{n}-{verb}")
            def build(folder, assets, where=where, value=value, culprit=culprit, verb=verb):
                export = folder / "inputs"
                shutil.copytree(assets["export"], export)
                doc = json.loads((export / "manifest.json").read_text())
                _set(doc, where, value if value is DELETE else copy.deepcopy(value))
                (export / "manifest.json").write_text(json.dumps(doc))
                if verb == "verify":
                    return ["suite", "verify", str(export)], culprit
                return ["score", str(export), "--check", str(assets["score"] / "results.jsonl")], culprit

    for key in ("id", "path"):
        @case(f"export-manifest-two-cases-one-{key}")
        def build(folder, assets, key=key):
            export = folder / "inputs"
            shutil.copytree(assets["export"], export)
            doc = json.loads((export / "manifest.json").read_text())
            doc["cases"][1][key] = doc["cases"][0][key]
            (export / "manifest.json").write_text(json.dumps(doc))
            return ["suite", "verify", str(export)], "names two cases"

    @case("export-verify-against")
    def build(folder, assets):
        return ["suite", "verify", str(assets["export"]), "--against", str(assets["suite"])], "--against"

    @case("export-out-user-folder")
    def build(folder, assets):
        return ["suite", "export", str(assets["suite"]), "--out", str(_user_folder(folder))], "not empty"

    @case("export-out-is-a-file")
    def build(folder, assets):
        f = _write(folder / "notes.txt", "x")
        return ["suite", "export", str(assets["suite"]), "--out", str(f)], "notes.txt"

    @case("export-out-an-earlier-export")
    def build(folder, assets):
        shutil.copytree(assets["export"], folder / "inputs")
        return ["suite", "export", str(assets["suite"]), "--out", str(folder / "inputs")], "not empty"

    @case("export-of-an-export")
    def build(folder, assets):
        return ["suite", "export", str(assets["export"]), "--out", str(folder / "again")], "manifest.json"

    @case("export-of-a-damaged-suite")
    def build(folder, assets):
        suite = _copy_suite(folder, assets)
        _, doc = _manifest(suite)
        exr = suite / doc["cases"][0]["path"] / "input" / "capture.exr"
        exr.write_bytes(exr.read_bytes()[:-10])
        return ["suite", "export", str(suite), "--out", str(folder / "inputs")], "capture.exr"

    @case("export-of-a-user-folder")
    def build(folder, assets):
        return ["suite", "export", str(_user_folder(folder)), "--out", str(folder / "inputs")], "manifest.json"


_results_file_cases()
_export_cases()


def _closed_form_cases() -> None:
    """A scene the closed-form renderer does not cover, named in one line before any work (sweep, gsa)."""
    uncovered = {"torus": ({"object": {"type": "torus"}}, "object.type torus"),
                 "mitsuba-bsdf": ({"material": {"model": "mitsuba", "bsdf": {"type": "diffuse"}}}, "material.model mitsuba"),
                 "bookend-bounces": ({"object": {"type": "bookend"}, "capture.max_depth": 3}, "capture.max_depth 3")}  # fmt: skip
    for name, (sets, culprit) in uncovered.items():
        @case(f"closed-form-sweep-{name}")
        def build(folder, assets, sets=sets, culprit=culprit):
            doc = {"name": "cf", "renderer": "closed-form", "scene": str(REPO / "scenes" / "ts_board.yaml"),
                   "set": {"camera.resolution": [24, 18]}, "axes": {"set": {"x": sets}}, "seeds": 1,
                   "methods": ["paper-init"]}  # fmt: skip
            return ["sweep", str(_write(folder / "cf.yaml", _dump(doc))), "--out", str(folder / "res"), "--quiet"], culprit

        @case(f"closed-form-gsa-{name}")
        def build(folder, assets, sets=sets, culprit=culprit):
            doc = {**GSA, "renderer": "closed-form", "scene": str(REPO / "scenes" / "ts_board.yaml"),
                   "set": {"camera.resolution": [16, 12], **{k: v for k, v in sets.items()}},
                   "inputs": {"lamp_distance": {"low": 0.3, "high": 0.5}, "roughness": {"low": 0.05, "high": 0.2}}}  # fmt: skip
            return ["gsa", str(_write(folder / "g.yaml", _dump(doc))), "--out", str(folder / "res"), "--quiet"], culprit


_closed_form_cases()


# --------------------------------------------------------------------------- site: sources and the site's place


def _site_cases() -> None:
    def scores(folder: Path, assets: dict[str, Path]) -> Path:
        src = folder / "reports" / "scores"
        shutil.copytree(assets["score"], src / "tiny", ignore=shutil.ignore_patterns("parts", "renders"))
        return folder / "reports"

    @case("site-source-missing")
    def build(folder, assets):
        return ["site", str(folder / "no-such-reports"), "--out", str(folder / "site")], "no-such-reports"

    @case("site-source-is-a-file")
    def build(folder, assets):
        return ["site", str(_write(folder / "notes.txt", "x")), "--out", str(folder / "site")], "notes.txt"

    @case("site-source-without-reports")
    def build(folder, assets):
        _write(folder / "empty" / "data.csv", "a,b\n1,2\n")
        return ["site", str(folder / "empty"), "--out", str(folder / "site")], "no scorecard.json and no Markdown"

    for name, data in {"not-json": b"{ nope", "empty": b"", "utf16": '{"format": 1}'.encode("utf-16"),
                       "groups-of-numbers": json.dumps({"format": "nearlight-scorecard/1", "thresholds": {
                           "lamp_position_error_pct": [1.0]}, "groups": [3]}).encode(),
                       "recall-missing": json.dumps({"format": "nearlight-scorecard/1", "thresholds": {
                           "lamp_position_error_pct": [1.0]}, "groups": [{"category": "all", "value": "all",
                           "n": 1, "failed": 0, "lamp_position_error_pct": {"median": 1.0}}]}).encode()}.items():  # fmt: skip
        @case(f"site-scorecard-{name}")
        def build(folder, assets, data=data):
            reports = scores(folder, assets)
            card = reports / "scores" / "tiny" / "scorecard.json"
            card.write_bytes(data)
            return ["site", str(reports), "--out", str(folder / "site")], str(card)

    @case("site-markdown-not-utf8")
    def build(folder, assets):
        md = _write(folder / "reports" / "summary.md", b"# Results\n\xff\xfe broken\n")
        return ["site", str(folder / "reports"), "--out", str(folder / "site")], str(md)

    @case("site-out-user-folder")
    def build(folder, assets):
        return ["site", str(scores(folder, assets)), "--out", str(_user_folder(folder))], "mine"

    @case("site-out-is-a-file")
    def build(folder, assets):
        return ["site", str(scores(folder, assets)), "--out", str(_write(folder / "site.html", "x"))], "site.html"

    @case("site-out-record-damaged")
    def build(folder, assets):
        _write(folder / "site" / "site.json", "{ nope")
        return ["site", str(scores(folder, assets)), "--out", str(folder / "site")], "site.json"

    @case("site-out-a-user-file-where-a-page-goes")
    def build(folder, assets):
        _write(folder / "site" / "site.json", json.dumps({"format": "nearlight-site/1", "files": ["site.json"]}))
        _write(folder / "site" / "index.html", "<p>my own page</p>")
        return ["site", str(scores(folder, assets)), "--out", str(folder / "site")], "index.html"


    @case("site-built-suite-case-escapes")
    def build(folder, assets):
        suite = _copy_suite(folder, assets)
        doc = json.loads((suite / "manifest.json").read_text())
        doc["cases"][0]["path"] = "../../victim/important"
        (suite / "manifest.json").write_text(json.dumps(doc))
        _write(folder / "victim" / "important" / "input" / "capture.json", "{}")
        return ["site", str(suite), "--out", str(folder / "site")], "manifest.json"

    @case("site-built-suite-case-input-missing")
    def build(folder, assets):
        suite = _copy_suite(folder, assets)
        case_dir = suite / json.loads((suite / "manifest.json").read_text())["cases"][0]["path"] / "input"
        shutil.rmtree(case_dir)
        return ["site", str(suite), "--out", str(folder / "site")], "input"


_site_cases()


# --------------------------------------------------------------------------- running the cases


@pytest.fixture(scope="module")
def assets(tmp_path_factory) -> dict[str, Path]:
    """A built tiny suite, a score folder of it (with its results file), its export, and a finished tiny sweep
    (built once)."""
    from nearlight.evaluation.engine.run import run_sweep
    from nearlight.evaluation.engine.sweep import load_sweep

    d = tmp_path_factory.mktemp("fuzz-newer-assets")
    assert main(["suite", "build", str(_pinned(d, SUITE)), "--out", str(d / "suite"), "--quiet", "--no-cache"]) == 0
    assert main(_score_argv(d / "suite", d / "score")) == 0
    assert main(["suite", "export", str(d / "suite"), "--out", str(d / "export")]) == 0
    run_sweep(load_sweep(_write(d / "sweep.yaml", _dump(SWEEP))), d / "results", progress=False)
    return {"suite": d / "suite", "score": d / "score", "results": d / "results", "export": d / "export"}


@pytest.fixture(autouse=True)
def _plugin_hygiene(monkeypatch):
    """Plug-ins imported by a case write no ``__pycache__`` into its folder, and leave ``sys.path`` as it was."""
    monkeypatch.setattr(sys, "dont_write_bytecode", True)
    monkeypatch.setattr(sys, "path", list(sys.path))
    yield


@pytest.mark.parametrize("c", CASES, ids=[c.id for c in CASES])
def test_broken_input_to_a_newer_verb_is_one_clear_line(c: Case, tmp_path, assets, capsys, monkeypatch):
    assert_one_clear_line(c, tmp_path, assets, capsys, monkeypatch)


def test_case_count():
    ids = [c.id for c in CASES]
    assert len(ids) == len(set(ids)) and len(ids) >= 120
    print(f"\nfuzz layer, newer verbs: {len(ids)} generated broken-input cases (seed {SEED})")


# --------------------------------------------------------------------------- faults


def _one_error_line(capsys, *needles: str) -> str:
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("nearlight: error: ")]
    assert "Traceback" not in err and len(lines) == 1, err
    assert all(n in lines[0] for n in needles), (needles, lines[0])
    return lines[0]


def _verifies(suite: Path, capsys) -> None:
    capsys.readouterr()
    assert main(["suite", "verify", str(suite)]) == 0, capsys.readouterr()
    capsys.readouterr()


#: A lock holder in another process: holds the build lock of argv[1] until killed.
HOLDER = """
import sys, time
from pathlib import Path
from nearlight.evaluation.suites.suite import build_lock
out = Path(sys.argv[1]); out.mkdir(parents=True, exist_ok=True)
with build_lock(out):
    print("locked", flush=True)
    time.sleep(120)
"""


def test_two_builds_into_one_folder_at_once_the_second_is_refused(tmp_path, capsys):
    path, out = _pinned(tmp_path, SUITE), tmp_path / "built"
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(out)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        assert main(_build_argv(path, tmp_path)) == 2
        _one_error_line(capsys, str(out), "another `nearlight suite build` is writing there")
        assert sorted(p.name for p in out.iterdir()) == [".build.lock"]  # the second wrote nothing
    finally:
        holder.send_signal(signal.SIGKILL)  # a killed build releases its lock (the kernel's flock)
        holder.wait()
        holder.stdout.close()
    assert main(_build_argv(path, tmp_path)) == 0
    _verifies(out, capsys)


def test_a_full_disk_under_suite_build_is_one_line_and_leaves_nothing_half_written(tmp_path, capsys, monkeypatch):
    """Simulated: the capture writer's EXR step raises ENOSPC (as OpenEXR's own words, a RuntimeError)."""
    import nearlight.capture.format as fmt

    path, out = _pinned(tmp_path, SUITE), tmp_path / "built"
    real = fmt._channels
    calls = []

    def full(*a, **kw):
        calls.append(1)
        if len(calls) >= 3:  # the first case's input and truth fit, then the disk is full
            raise RuntimeError('Failed to write pixel data to image file "x.exr". No space left on device.')
        return real(*a, **kw)

    monkeypatch.setattr(fmt, "_channels", full)
    assert main(_build_argv(path, tmp_path)) == 2
    _one_error_line(capsys, "no space left on", str(out / "cases" / "001" / "input"))
    assert not [p for p in out.rglob("*") if ".partial" in p.name or ".old" in p.name]
    assert not (out / "cases" / "001" / "input").exists()  # no half-written case
    assert json.loads((out / "manifest.json").read_text())["complete"] is False  # resumable
    monkeypatch.setattr(fmt, "_channels", real)
    assert main(_build_argv(path, tmp_path)) == 0
    assert "built 1 case(s), kept 1 already built" in capsys.readouterr().err
    _verifies(out, capsys)


def test_a_real_full_disk_on_a_small_tmpfs(tmp_path, capsys):
    """The same on a 48 kB tmpfs (root only; skipped where ``mount -t tmpfs`` is not allowed)."""
    disk = tmp_path / "disk"
    disk.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=48k", "tmpfs", str(disk)], capture_output=True).returncode:
        pytest.skip("mount -t tmpfs is not allowed here")
    try:
        assert main(["suite", "build", str(_pinned(tmp_path, SUITE)), "--out", str(disk / "s"), "--quiet",
                     "--no-cache"]) == 2  # fmt: skip
        _one_error_line(capsys, "no space left on", str(disk / "s"))
        assert not [p for p in disk.rglob("*") if ".partial" in p.name]
        for c in (disk / "s" / "cases").iterdir():  # every case folder is whole or empty
            assert sorted(p.name for p in c.iterdir()) in ([], ["input", "truth"]), c
    finally:
        subprocess.run(["umount", str(disk)], check=True)


def test_a_full_disk_under_score_is_one_line(tmp_path, assets, capsys, monkeypatch):
    import pandas as pd

    def full(self, path, *a, **kw):
        raise OSError(28, "No space left on device")  # pyarrow's ENOSPC, as an OSError

    monkeypatch.setattr(pd.DataFrame, "to_parquet", full)
    assert main(_score_argv(assets["suite"], tmp_path / "score")) == 2
    _one_error_line(capsys, "no space left on", str(tmp_path / "score" / "parts"))
    assert not list((tmp_path / "score").rglob("*.partial")) and not list((tmp_path / "score" / "parts").iterdir())


def test_a_killed_build_resumes_into_a_suite_that_verifies(tmp_path, capsys):
    """What SIGKILL leaves (a scratch folder of a capture write, a case half-written) is cleaned on resume,
    never checksummed; and a build really killed with SIGKILL resumes too."""
    path, out = _pinned(tmp_path, SUITE), tmp_path / "built"
    assert main(_build_argv(path, tmp_path)) == 0
    case = out / "cases" / "001"
    shutil.rmtree(case / "truth")  # the kill came between the case's two captures ...
    scratch = case / ".truth.x1y2z3.partial"  # ... while the truth was being written
    _write(scratch / "capture.json", "{}")
    doc = json.loads((out / "manifest.json").read_text())
    doc["complete"] = False
    (out / "manifest.json").write_text(json.dumps(doc))
    assert main(_build_argv(path, tmp_path)) == 0
    assert "built 1 case(s), kept 1 already built" in capsys.readouterr().err
    assert not scratch.exists()
    files = [f for c in json.loads((out / "manifest.json").read_text())["cases"] for f in c["files"]]
    assert not [f for f in files if "partial" in f] and len(files) == 8
    _verifies(out, capsys)

    # a real SIGKILL in the middle of a larger build, then the same command again
    big = _pinned(tmp_path, {**SUITE, "name": "big-v1", "scene": {"width": 160, "height": 120},
                             "axes": {"lamp_distance": [round(0.2 + 0.025 * k, 3) for k in range(16)]}}, "big.yaml")  # fmt: skip
    out2 = tmp_path / "big"
    argv = ["suite", "build", str(big), "--out", str(out2), "--quiet", "--no-cache"]
    proc = subprocess.Popen([sys.executable, "-m", "nearlight", *argv], stderr=subprocess.DEVNULL, stdout=subprocess.DEVNULL)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not (out2 / "cases" / "001").exists() and proc.poll() is None:
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    assert proc.wait() == -signal.SIGKILL and not json.loads((out2 / "manifest.json").read_text())["complete"]
    assert main(argv) == 0, capsys.readouterr().err
    assert "kept" in capsys.readouterr().err
    _verifies(out2, capsys)


#: Plug-ins for the faults of a method under `score`.
FAULTY = """
import os, sys
def exits(capture):
    sys.exit(0)
def dies(capture):
    os._exit(1)
"""


@pytest.fixture
def faulty(tmp_path, monkeypatch):
    _write(tmp_path / "plugins" / "nl_faulty_plugin.py", textwrap.dedent(FAULTY))
    monkeypatch.syspath_prepend(str(tmp_path / "plugins"))
    return "nl_faulty_plugin"


def test_sys_exit_in_a_plugin_under_score_is_a_failed_case_not_an_exit(tmp_path, assets, faulty, capsys):
    assert main(_score_argv(assets["suite"], tmp_path / "score", f"{faulty}:exits")) == 0
    card = json.loads((tmp_path / "score" / "scorecard.json").read_text())
    assert card["failed"] == card["cases"] == 2
    assert any(f"method {faulty}:exits: failed with SystemExit" in e for e in card["errors"]), card["errors"]


def test_a_plugin_that_kills_its_worker_is_one_line_naming_it(tmp_path, assets, faulty, capsys):
    assert main([*_score_argv(assets["suite"], tmp_path / "score", f"{faulty}:dies"), "--workers", "2"]) == 2
    _one_error_line(capsys, f"method {faulty}:dies: a worker process died")


def test_a_damaged_score_part_is_set_aside_and_scored_again(tmp_path, assets, capsys):
    score = tmp_path / "score"
    shutil.copytree(assets["score"], score)
    (score / "results.parquet").unlink()
    part = sorted((score / "parts").glob("*.parquet"))[0]
    part.write_bytes(b"garbage")
    capsys.readouterr()
    assert main(["report", str(score)]) == 2  # a reader names the part and what to do
    _one_error_line(capsys, str(part), "delete it, or run the same `nearlight sweep` or `nearlight score` again")
    assert main(_score_argv(assets["suite"], score)) == 0  # and doing it works
    err = capsys.readouterr().err
    assert "a damaged result part was moved to" in err and "ran 1 case(s), skipped 1" in err
    assert (score / "parts" / "damaged" / part.name).read_bytes() == b"garbage"


def test_a_plugin_that_kills_its_worker_under_gsa_is_one_line(tmp_path, faulty, capsys):
    doc = {**GSA, "methods": [f"{faulty}:dies"]}
    path = _write(tmp_path / "gsa.yaml", _dump(doc))
    assert main(["gsa", str(path), "--out", str(tmp_path / "res"), "--quiet", "--workers", "2"]) == 2
    _one_error_line(capsys, f"{faulty}:dies", "a worker process died")


@pytest.mark.parametrize("verb", [["reproduce", "--quick", "--quiet"], ["suite", "build", "SUITE", "--quiet"]])
def test_a_bad_llvm_target_choice_is_one_line_before_any_work(verb, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("NEARLIGHT_JIT_TARGET", "avx512")
    suite = _pinned(tmp_path, SUITE)
    out = tmp_path / "out"
    argv = [str(suite) if a == "SUITE" else a for a in verb] + ["--out", str(out)]
    assert main(argv) == 2
    _one_error_line(capsys, "NEARLIGHT_JIT_TARGET: expected portable or host, got 'avx512'")
    assert not out.exists()
