"""Benchmark suites: suite files, `nearlight suite build` and `verify` (analytic renderer: no Mitsuba).

Also the shipped suite files (their pins) and the tolerant digests `verify --against` uses.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from nearlight.capture import read_capture, write_capture
from nearlight.cli import main
from nearlight.errors import UserError
from nearlight.evaluation.suites.suite import (
    DIGEST_RTOL,
    digest_deviation,
    image_digest,
    load_suite,
    read_manifest,
)

REPO = Path(__file__).resolve().parents[3]
#: 2 distances x (noise-free: 1 seed + noisy: 2 seeds) = 6 cases, 32x24 analytic captures.
SUITE = {
    "name": "tiny-v1",
    "version": 1,
    "renderer": "analytic",
    "scene": {"width": 32, "height": 24},
    "axes": {
        "lamp_distance": [0.3, 0.5],
        "noise": {"clean": None, "sensor": {"full_well": 20000, "read_noise": 2.0, "saturation": 1.0}},
    },
    "seeds": 2,
    "categories": ["lamp_distance", "noise"],
}
N_CASES = 6


def pinned_suite_file(folder: Path, doc: dict) -> Path:
    """``doc`` written to ``folder/<name>.yaml`` with its ``cases_hash`` pinned to its own cases."""
    path = folder / f"{doc['name']}.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    doc = {**doc, "cases_hash": load_suite(path, check_pin=False).cases_hash}
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def write_suite(folder: Path, **changes) -> Path:
    """The tiny suite file in ``folder``, pinned to its own cases."""
    return pinned_suite_file(folder, {**SUITE, **changes})


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    root = tmp_path_factory.mktemp("suite")
    path = write_suite(root)
    assert main(["suite", "build", str(path), "--out", str(root / "built"), "--quiet", "--no-cache"]) == 0
    return path, root / "built"


def test_manifest_names_every_case_file_and_version(built):
    _, out = built
    m = read_manifest(out)
    assert (m["suite"], m["version"], m["renderer"], m["format"]) == ("tiny-v1", 1, "analytic", "nearlight-suite/1")
    assert m["nearlight_version"] and m["generator_version"] and m["tolerance"]["digest_rtol"] == DIGEST_RTOL
    assert len(m["cases"]) == N_CASES and len({c["id"] for c in m["cases"]}) == N_CASES
    for c in m["cases"]:
        assert set(c["files"]) == {"input/capture.json", "input/capture.exr", "truth/capture.json", "truth/capture.exr"}
        assert set(c["categories"]) == {"lamp_distance", "noise"}
        assert len(c["digests"]["input"]["P"]) == 4 * 4 * 3  # 4x4 blocks, 3 channels
    # the input a method sees carries no truth; the truth capture does
    c = m["cases"][0]
    seen, truth = read_capture(out / c["path"] / "input"), read_capture(out / c["path"] / "truth")
    assert seen.truth is None and not any(k.startswith("truth") for k in seen.extra)
    lamp = truth.truth["lamp_position"]
    assert not any(repr(float(x)) in (out / c["path"] / "input" / "capture.json").read_text() for x in lamp)
    assert truth.truth is not None and "truth_specular" in truth.extra


def test_strip_truth_drops_the_generators_scene_record(built):
    """Mitsuba renders record their scene (lamp position, material) in capture.json's `generator`
    key: the truth in another form, so it is not handed to a method either; other keys stay."""
    from nearlight.evaluation.suites.suite import strip_truth

    _, out = built
    cap = read_capture(out / "cases" / "000" / "truth")
    cap = cap.replace(meta={**cap.meta, "generator": {"scene": {"lamp": {"position": [0.1, 0.2, 0.3]}}}, "rig_notes": "x"})
    seen = strip_truth(cap)
    assert seen.truth is None and "truth_specular" not in seen.extra
    assert "generator" not in seen.meta and seen.meta["rig_notes"] == "x"
    assert cap.truth is not None and "generator" in cap.meta  # the original is not changed


def test_noisy_inputs_differ_from_their_truth_and_between_seeds(built):
    _, out = built
    m = read_manifest(out)
    noisy = [c for c in m["cases"] if c["categories"]["noise"] == "sensor" and c["categories"]["lamp_distance"] == 0.3]
    assert [c["seed"] for c in noisy] == [0, 1]
    a, b = (read_capture(out / c["path"] / "input").stack for c in noisy)
    assert not np.array_equal(a, b)


def test_rebuild_is_identical_and_verify_passes(built, tmp_path, capsys):
    path, out = built
    assert main(["suite", "build", str(path), "--out", str(tmp_path / "again"), "--quiet", "--no-cache"]) == 0
    capsys.readouterr()
    assert main(["suite", "verify", str(tmp_path / "again"), "--against", str(out / "manifest.json")]) == 0
    text = capsys.readouterr().out
    assert f"{N_CASES} case(s) identical, 0 within the tolerance, 0 beyond it" in text
    assert f"ok: {4 * N_CASES} of {4 * N_CASES} files" in text


def test_resume_keeps_built_cases(built, tmp_path, capsys):
    path, out = built
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    shutil.rmtree(copy / "cases" / "002" / "truth")  # an interrupted build
    assert main(["suite", "build", str(path), "--out", str(copy), "--no-cache", "--quiet"]) == 0
    assert f"built 1 case(s), kept {N_CASES - 1} already built" in capsys.readouterr().err
    assert json.loads((copy / "manifest.json").read_text())["cases"] == read_manifest(out)["cases"]


def test_interrupted_build_is_refused_by_score_and_resumed_by_build(built, tmp_path, capsys):
    from nearlight.evaluation.suites.suite import manifest_doc

    path, out = built
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    # what a build killed after its first 4 cases leaves: the provisional manifest, 2 cases missing
    (copy / "manifest.json").write_text(json.dumps(manifest_doc(load_suite(path), {})))
    for i in (4, 5):
        shutil.rmtree(copy / "cases" / f"{i:03d}")
    assert main(["score", str(copy), "--method", "full", "--out", str(tmp_path / "s")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "complete: false, an interrupted build" in err
    assert main(["suite", "build", str(path), "--out", str(copy), "--no-cache", "--quiet"]) == 0
    assert f"built 2 case(s), kept {N_CASES - 2} already built" in capsys.readouterr().err
    assert read_manifest(copy)["cases"] == read_manifest(out)["cases"]


def test_tampered_file_fails_verify(built, tmp_path, capsys):
    _, out = built
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    with open(copy / "cases" / "001" / "input" / "capture.json", "a") as f:
        f.write(" ")
    assert main(["suite", "verify", str(copy)]) == 1
    assert "cases/001/input/capture.json: checksum mismatch" in capsys.readouterr().out


def test_digests_tolerate_last_bits_not_real_changes(built):
    _, out = built
    cap = read_capture(out / "cases" / "000" / "truth")
    ref = image_digest(cap)
    # float32 last-bit differences (relative 2^-23 on every pixel, of either sign): far within the tolerance
    rng = np.random.default_rng(0)
    bits = cap.replace(stack=cap.stack * (1 + rng.choice([-1, 1], cap.stack.shape) * 2.0**-23))
    assert digest_deviation(ref, image_digest(bits))[0] < 1e-6
    # one analyzer image 1 % brighter in one corner block (of 4x4): beyond it, and named
    stack = cap.stack.copy()
    stack[2, :6, :8] *= 1.01 * 10  # the corner is dark; x10 makes its block move by ~1 % of the peak
    dev, layer = digest_deviation(ref, image_digest(cap.replace(stack=stack)))
    assert dev > DIGEST_RTOL and layer == "stack/2"
    # a background block that gains a surface: not comparable at all
    P = cap.P.copy()
    P[:] = np.nan
    assert digest_deviation(ref, image_digest(cap.replace(P=P)))[0] == np.inf


def test_verify_against_a_build_beyond_tolerance(built, tmp_path, capsys):
    _, out = built
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    m = json.loads((copy / "manifest.json").read_text())
    case = m["cases"][3]
    cap = read_capture(copy / case["path"] / "truth")
    write_capture(cap.replace(stack=cap.stack * 1.05), copy / case["path"] / "truth", overwrite=True)
    from nearlight.evaluation.suites.suite import case_record

    m["cases"][3] = {**case, **case_record(copy / case["path"])}
    (copy / "manifest.json").write_text(json.dumps(m))
    assert main(["suite", "verify", str(copy), "--against", str(out)]) == 1
    text = capsys.readouterr().out
    assert "cases/003: files differ, digests BEYOND tolerance" in text and "truth/stack/" in text
    assert "DIFFERS: against" in text and "1 beyond it" in text


def test_changed_definition_is_refused_until_renamed(tmp_path):
    path = write_suite(tmp_path)
    doc = yaml.safe_load(path.read_text())
    doc["axes"]["lamp_distance"] = [0.3, 0.6]  # an edit of a frozen suite
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(UserError, match=r"tiny-v1\.yaml: cases_hash: the cases hash to [0-9a-f]{16}, the file pins"):
        load_suite(path)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"methods": ["full"]}, r"methods: a suite has no methods"),
        ({"version": "one"}, r"version: expected a positive integer"),
        ({"categories": ["colour"]}, r"categories: expected a list of the suite's axes"),
        ({"axes": {"colour": [1]}}, r"bad\.yaml: axes\.colour: unknown axis"),  # the sweep's error, naming the file
        ({"name": ""}, r"bad\.yaml: name: expected the suite's name"),
    ],
)
def test_bad_suite_files_are_one_line_errors(tmp_path, capsys, change, message):
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump({**SUITE, "cases_hash": "0", **change}))
    assert main(["suite", "build", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "bad.yaml: " in err
    assert __import__("re").search(message, err)
    assert not (tmp_path / "out").exists()


def test_build_refuses_a_folder_it_did_not_write(tmp_path, capsys):
    path = write_suite(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    assert main(["suite", "build", str(path), "--out", str(out), "--no-cache"]) == 2
    assert "not empty and not a built suite" in capsys.readouterr().err
    assert [p.name for p in out.iterdir()] == ["notes.txt"]


def test_verify_names_a_missing_manifest(tmp_path, capsys):
    assert main(["suite", "verify", str(tmp_path)]) == 2
    assert f"{tmp_path / 'manifest.json'}: missing" in capsys.readouterr().err


def test_shipped_suites_load_at_their_pins():
    """Every suite file of suites/ hashes to the cases it pins (load_suite refuses it otherwise)."""
    files = sorted((REPO / "suites").glob("*.yaml"))
    assert files
    for f in files:
        suite = load_suite(f)
        assert suite.name == f.stem and suite.version >= 1


@pytest.mark.render
def test_a_mitsuba_suite_hands_methods_no_scene_record(tmp_path, capsys):
    """One tiny Mitsuba case (32x24, the bench rig): the render's capture.json records the scene it
    rendered (lamp position, material) under `generator`; the built input must not carry it."""
    path = write_suite(tmp_path, name="mitsuba-v1", renderer="mitsuba", axes={}, seeds=1, categories=[], scene={
        "camera": {"position": [0.0, -0.35, 0.5], "look_at": [0.0, 0.0, 0.0], "fov_x_deg": 50.0, "resolution": [32, 24]},
        "object": {"type": "board", "size": [0.4, 0.4]},
        "material": {"model": "torrance_sparrow", "ks": [0.8, 0.6, 0.5], "sigma": 0.1, "kd": [0.3, 0.4, 0.35]},
        "lamp": {"position": [0.05, 0.15, 0.35], "intensity": [2.0, 2.0, 2.0]},
        "capture": {"analyzer_angles_deg": [0, 45, 90, 135]}, "realism": "bench"})  # fmt: skip
    out = tmp_path / "built"
    assert main(["suite", "build", str(path), "--out", str(out), "--quiet", "--no-cache"]) == 0
    case = out / read_manifest(out)["cases"][0]["path"]
    truth_json, input_json = (json.loads((case / sub / "capture.json").read_text()) for sub in ("truth", "input"))
    assert "generator" in truth_json and "truth" in truth_json
    assert "generator" not in input_json and "truth" not in input_json

    def keys(doc):
        return set(doc) | {k for v in doc.values() if isinstance(v, dict) for k in keys(v)} if isinstance(doc, dict) else set()

    assert {"lamp", "material", "bsdf"} & keys(truth_json)  # what the truth side names ...
    assert not {"lamp", "material", "bsdf", "scene"} & keys(input_json)  # ... the input does not, at any depth
