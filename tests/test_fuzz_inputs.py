"""Fuzz layer: generated broken inputs to every verb, each a clear one-line error.

Every case builds a broken input in its own folder (a scene file, a sweep
file, a capture, a results folder, an output place, an option), runs the
``nearlight`` command in-process (:func:`nearlight.cli.main`), and asserts:

- exit status 2;
- exactly one line on stderr, ``nearlight: error: ...``, naming the culprit
  (the file, key, channel or option the case broke);
- no traceback;
- nothing written, nothing removed: the case's folder is byte-for-byte what it
  was before the command (no half-written output, no ``.partial`` left, no
  user file replaced).

Cases are generated from a fixed seed (:data:`SEED`), so the list is the same
on every run; :func:`test_case_count` prints how many there are. Renders never
run: Mitsuba's tracing is replaced by a stub that fails the case if reached,
so a broken scene must be refused before any rendering. Grow the list with
every new class of bad input found.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import os
import random
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from nearlight.capture import write_capture
from nearlight.cli import main
from nearlight.generator.analytic import analytic_capture

SEED = 20261125
ROOT = Path(__file__).resolve().parents[1]
SCENE = yaml.safe_load((ROOT / "scenes" / "ts_board.yaml").read_text())
SCENE["camera"]["resolution"] = [16, 12]


@dataclasses.dataclass(frozen=True)
class Case:
    """One generated broken input.

    ``build(folder, assets)`` writes the input into ``folder`` and returns the
    command line and the text the error line must contain (the culprit).
    """

    id: str
    build: Callable[[Path, dict[str, Path]], tuple[list[str], str]]


CASES: list[Case] = []


def case(id: str) -> Callable:
    def add(build: Callable) -> Callable:
        CASES.append(Case(id, build))
        return build

    return add


def _write(path: Path, data: str | bytes) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(data, bytes):
        path.write_bytes(data)
    else:
        path.write_text(data)
    return path


def _dump(doc: Any) -> str:
    return yaml.safe_dump(doc, sort_keys=False, allow_unicode=True)


# --------------------------------------------------------------------------- scene files


def _render_argv(scene: Path, folder: Path, *extra: str) -> list[str]:
    return ["render", str(scene), "--out", str(folder / "out"), "--no-cache", "--quiet", *extra]


#: (dotted key, broken values): each is outside what the scene schema accepts.
SCENE_BREAKS: dict[str, list[Any]] = {
    "camera.position": [[0, 0], "abc", {"x": 1}, [float("nan"), 0, 0], [1e400, 0, 0], None, [0, 0, 0, 0]],
    "camera.look_at": [[0, -0.35, 0.55], [True, 0, 0], "origin"],
    "camera.fov_x_deg": [0, -10, 180, 400, "wide", float("inf"), [40]],
    "camera.resolution": [[0, 10], [-1, 5], [1.5, 2], [16], [16, 12, 3], [99999, 99999], "640x480", [16384, 16384]],
    "camera.up": [[0, 0, 0], [0, 0]],
    "object.type": ["teapot", 3, None],
    "object.size": [[0, 0.3], [-1, 1], "big", [0.3]],
    "object.rotation_deg": [[0, 0], "x"],
    "object.normal": [[0, 0, 0]],
    "material.model": ["phong", None],
    "material.sigma": [0, -0.1, "rough", [0.1], float("nan")],
    "material.ks": [[0.3, 0.3], [-1, 0, 0], "grey", 0.5],
    "material.kd": [[0.1, 0.2], [0, -0.5, 0]],
    "material.polarization": ["circular", 1],
    "material.eta": [1.0, 0.5, "glass"],
    "lamp.position": [[0, 0], "up", [0, 0, 0], [0, 0, 1e400]],
    "lamp.intensity": [[-1, 1, 1], [1, 1], "bright"],
    "lamp.polarizer_axis": [[0, 0, 0], [1, 0]],
    "capture.analyzer_angles_deg": [[0, 90], [0, 180, 360], "all", [], [0, 45, "x"]],
    "capture.spp": [0, -4, 1.5, 1 << 20],
    "capture.max_depth": [1, 0, 100, "deep"],
    "capture.noise": ["high", {"full_well": -1}, {"bits": 0}, {"bits": 64}, {"read_noise": -5},
                      {"saturation": "max"}, {"unknown": 1}],  # fmt: skip
    "capture.range_noise_m": [-0.001, "1mm"],
    "capture.seed": [-1, 1.5, "seed"],
    # nuisances
    "realism": ["messy", 3, None],
    "lamp.polarizer_extinction_ratio": [0.9, -1, "ideal"],
    "lamp.anisotropy_k": [-1, "cos"],
    "lamp.anisotropy_axis": [[0, 0, 0], [1, 0]],
    "lamp.radius": [-0.01, 1.0, "big"],
    "material.texture": ["checker", {"kd_contrast": 1.0}, {"period_m": 0}, {"roughness_contrast": -0.1}, {"bogus": 1}],
    "lamp.samples": [0, 1.5, 1 << 20],
    "nuisances": ["bench", [1]],
    "nuisances.analyzer.extinction_ratio": [0.5, "high"],
    "nuisances.analyzer.offset_deg": [91, "x"],
    "nuisances.analyzer.jitter_deg": [-0.1],
    "nuisances.camera.vignetting": [1.0, -0.1],
    "nuisances.camera.gamma": [0, -2.2],
    "nuisances.camera.flicker": [-0.01, 2],
    "nuisances.camera.white_balance": [[1, 1], [0, 1, 1]],
    "nuisances.range.holes_shiny_above": [0, 1.5],
    "nuisances.range.holes_dark_below": [1, -0.1],
    "nuisances.range.shift_px": [[0.1], [9, 0], "left"],
    "nuisances.range.quantum_m": [-0.001, 1],
    "nuisances.calibration.position_m": [[0, 0], [1, 0, 0]],
    "nuisances.calibration.rotation_deg": [[0, 0, 0, 0], [90, 0, 0]],
    "nuisances.bogus.key": [1],
    # calibration targets (issue 39)
    "targets": ["balls", [{"type": "cube", "position": [0, 0, 0]}], [{"type": "mirror_sphere"}],
                [{"type": "mirror_sphere", "position": [0.2, 0, 0.05], "radius": 0}],
                [{"type": "mirror_sphere", "position": [0.1, 0.25, 0.44]}],
                [{"type": "matte_card", "position": [0, 0, 0.01], "size": [0.1]}],
                [{"type": "matte_card", "position": [0, 0, 0.01], "albedo": -0.1}],
                [{"type": "mirror_sphere", "position": [0.2, 0, 0.05], "calibration_error_m": -0.001}],
                [{"type": "mirror_sphere", "position": [0.2, 0, 0.05]}] * 9],
    "lamp.intersectable": [True, "lit"],
}


def _set_key(doc: dict, dotted: str, value: Any) -> None:
    node = doc
    *path, last = dotted.split(".")
    for p in path:
        node = node.setdefault(p, {})
    node[last] = value


def _scene_case(key: str, value: Any, i: int) -> None:
    @case(f"scene-{key}-{i}")
    def build(folder: Path, assets: dict[str, Path]) -> tuple[list[str], str]:
        doc = copy.deepcopy(SCENE)
        _set_key(doc, key, value)
        scene = _write(folder / "scene.yaml", _dump(doc))
        culprit = "camera" if key == "camera.look_at" else key.split(".")[0]
        return _render_argv(scene, folder), culprit


for _key, _values in SCENE_BREAKS.items():
    for _i, _value in enumerate(_values):
        _scene_case(_key, _value, _i)


def _scene_structure_cases() -> None:
    rng = random.Random(SEED)
    sections = ["camera", "object", "material", "lamp"]
    for section in sections:  # a required section missing
        @case(f"scene-missing-{section}")
        def build(folder, assets, section=section):
            doc = copy.deepcopy(SCENE)
            del doc[section]
            return _render_argv(_write(folder / "scene.yaml", _dump(doc)), folder), section

    for n in range(6):  # a misspelt key somewhere
        section = rng.choice(sections)
        word = "".join(rng.choice("abcdefghijklmnopqrstuvwxyz") for _ in range(7))

        @case(f"scene-unknown-key-{n}")
        def build(folder, assets, section=section, word=word):
            doc = copy.deepcopy(SCENE)
            doc[section][word] = 1
            return _render_argv(_write(folder / "scene.yaml", _dump(doc)), folder), f"{section}.{word}"

    for n in range(3):  # a required key missing inside a section
        section, key = rng.choice([("camera", "position"), ("camera", "look_at"), ("lamp", "position"),
                                   ("material", "sigma"), ("material", "ks")])  # fmt: skip

        @case(f"scene-missing-key-{n}-{section}.{key}")
        def build(folder, assets, section=section, key=key):
            doc = copy.deepcopy(SCENE)
            del doc[section][key]
            return _render_argv(_write(folder / "scene.yaml", _dump(doc)), folder), f"{section}.{key}"


_scene_structure_cases()


def _text_file_cases(prefix: str, make_argv: Callable[[Path, Path], list[str]], base_text: str) -> None:
    """Non-UTF-8, binary, truncated and not-YAML variants of a text file (class 1)."""
    rng = random.Random(f"{SEED}-{prefix}")
    latin1 = ("# lamp at 45\xb0 above the board\n" + base_text).encode("latin-1", errors="replace")
    variants: dict[str, bytes] = {
        "latin1-comment": latin1,
        "latin1-value": base_text.replace("name:", "name: caf\xe9 #", 1).encode("latin-1", errors="replace")
        if "name:" in base_text else b"camera: {position: [0, 0, 1]} # caf\xe9\n",
        "utf16": base_text.encode("utf-16"),
        "nul-bytes": b"\x00" * 64,
        "binary-png": b"\x89PNG\r\n\x1a\n" + bytes(rng.randrange(256) for _ in range(200)),
        "empty": b"",
        "just-a-list": b"- 1\n- 2\n",
        "just-a-string": b"hello\n",
        "bad-yaml": b"camera: {position: [0, 0\n",
        "tabs": b"camera:\n\t position: [0, 0, 1]\n",
        "deep-nesting": b"[" * 5000 + b"]" * 5000,
        "random-bytes-1": bytes(rng.randrange(128, 256) for _ in range(300)),
        "random-bytes-2": bytes(rng.randrange(256) for _ in range(300)) + b"\x00",
    }
    for n in range(4):  # the real file cut at a random point, plus one stray invalid byte
        cut = rng.randrange(10, max(11, len(base_text) - 1))
        variants[f"cut-{n}"] = base_text.encode()[:cut] + b"\xff"
    for name, data in variants.items():
        @case(f"{prefix}-text-{name}")
        def build(folder, assets, data=data):
            path = _write(folder / "file.yaml", data)
            return make_argv(path, folder), str(path)


_text_file_cases("scene", lambda p, f: _render_argv(p, f), _dump(SCENE))

# a folder given as the scene file; a scene file that does not exist
case("scene-is-a-folder")(lambda folder, assets: (_render_argv(_write(folder / "d" / "x", "") and folder / "d",
                                                                 folder), str(folder / "d")))
case("scene-missing-file")(lambda folder, assets: (_render_argv(folder / "nope.yaml", folder),
                                                    str(folder / "nope.yaml")))


def _set_option_cases() -> None:
    scene = ROOT / "scenes" / "ts_board.yaml"
    for n, item in enumerate(["noequals", "=1", "lamp.position=[0,", "lamp.position.x=1", "camera=5",
                              "camera.resolution=[0,0]", "material.sigma=-1", "nosuch.key=1", ".=5", "a..b=1"]):  # fmt: skip
        @case(f"render-set-{n}")
        def build(folder, assets, item=item):
            argv = _render_argv(scene, folder, "--set", item)
            culprit = {"noequals": "--set", "=1": "--set", "lamp.position=[0,": "--set", ".=5": "'.'",
                       "a..b=1": "'a..b'"}.get(item, item.split("=")[0].split(".")[0])  # fmt: skip
            return argv, culprit


_set_option_cases()


def _mitsuba_material_cases() -> None:
    for n, bsdf in enumerate([{"type": "nosuchbsdf"}, {"type": "roughconductor", "alpha": "abc"},
                              {"type": "pplastic", "diffuse_reflectance": {"type": "rgb", "value": [1, 2]}},
                              {"type": "pplastic", "bogus_param": 3}, {"type": "pplastic", "alpha": [1, 2, 3]},
                              {"type": 5}, {"no_type": 1}]):  # fmt: skip
        @case(f"scene-mitsuba-material-{n}")
        def build(folder, assets, bsdf=bsdf):
            doc = copy.deepcopy(SCENE)
            doc["material"] = {"model": "mitsuba", "bsdf": bsdf}
            return _render_argv(_write(folder / "scene.yaml", _dump(doc)), folder), "material"


_mitsuba_material_cases()


def _mesh_file_cases() -> None:
    plys = {"not-ply": b"garbage, not a PLY\n", "empty": b"",
            "cut-short": b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1 2\n",
            "binary-noise": bytes(random.Random(f"{SEED}-ply").randrange(256) for _ in range(400))}  # fmt: skip
    for name, data in plys.items():
        @case(f"scene-mesh-file-{name}")
        def build(folder, assets, data=data):
            _write(folder / "m.ply", data)
            doc = copy.deepcopy(SCENE)
            doc["object"] = {"type": "mesh", "file": "m.ply"}
            return _render_argv(_write(folder / "scene.yaml", _dump(doc)), folder), "object.file"

    @case("scene-mesh-file-missing")
    def build(folder, assets):
        doc = copy.deepcopy(SCENE)
        doc["object"] = {"type": "mesh", "file": "nowhere.ply"}
        return _render_argv(_write(folder / "scene.yaml", _dump(doc)), folder), "object.file"


_mesh_file_cases()


# --------------------------------------------------------------------------- sweep files

SWEEP = {
    "name": "fuzz",
    "renderer": "analytic",
    "scene": {"width": 24, "height": 18},
    "axes": {"lamp_distance": [0.3, 0.5]},
    "seeds": 1,
    "methods": ["paper-init"],
}


def _sweep_argv(path: Path, folder: Path, *extra: str) -> list[str]:
    return ["sweep", str(path), "--out", str(folder / "results"), "--quiet", *extra]


SWEEP_BREAKS: dict[str, list[Any]] = {
    "name": [None, [], {"a": 1}],
    "renderer": ["povray", 3],
    "scene": [5, "missing-scene.yaml", {"width": "wide"}, {"width": -3}],
    "set": ["lamp", {"width": "x"}],
    "axes": ["lamp_distance", {"bogus": [1]}, {"lamp_distance": [-1]}, {"lamp_distance": []},
             {"lamp_distance": [0.3, "0.3"]}, {"noise": {"bad": {"full_well": -1}}}, {"noise": ["loud"]},
             {"range_noise": [-0.01]}, {"roughness": [0]}, {"analyzer_angles": [2]}, {"polarization": ["circular"]},
             {"bsdf": ["phong"]}],  # fmt: skip
    "seeds": [0, -1, [-1], [1, 1], [], "three", 1.5, [0, -5]],
    "methods": [[], ["nosuchmethod"], ["nosuchmodule_xyz:fn"], [{"method": "paper", "bogus": 1}], "paper", [5]],
    "crlb": ["maybe", [1]],
    "bogus_top_key": [1],
}


def _sweep_case(key: str, value: Any, i: int) -> None:
    @case(f"sweep-{key}-{i}")
    def build(folder, assets):
        doc = copy.deepcopy(SWEEP)
        doc[key] = value
        path = _write(folder / "sweep.yaml", _dump(doc))
        # a bad value put in by `set` is named where it lands, in the scene
        named = "scene: width" if key == "set" and isinstance(value, dict) else key
        return _sweep_argv(path, folder), f"{path}: {named}"


for _key, _values in SWEEP_BREAKS.items():
    for _i, _value in enumerate(_values):
        _sweep_case(_key, _value, _i)

for _key in ("name", "scene", "methods"):
    case(f"sweep-missing-{_key}")(
        lambda folder, assets, key=_key: (
            _sweep_argv(p := _write(folder / "sweep.yaml", _dump({k: v for k, v in SWEEP.items() if k != key})),
                        folder), str(p))  # fmt: skip
    )

_text_file_cases("sweep", lambda p, f: _sweep_argv(p, f), _dump(SWEEP))


def _sweep_scene_file_cases() -> None:
    for name, data in {"latin1": "camera: {position: [0, 0, 1]} # 45\xb0\n".encode("latin-1"),
                       "binary": b"\x00\x01\x02\x03", "list": b"- 1\n"}.items():  # fmt: skip
        @case(f"sweep-scene-file-{name}")
        def build(folder, assets, data=data):
            scene = _write(folder / "base.yaml", data)
            doc = dict(SWEEP, renderer="mitsuba", scene="base.yaml")
            return _sweep_argv(_write(folder / "sweep.yaml", _dump(doc)), folder), str(scene)


_sweep_scene_file_cases()


def _sweep_option_cases() -> None:
    for n, address in enumerate(["banana", "tcp://", "tcp://host", "http://host:8786", "tcp://host:0",
                                 "tcp://host:99999", "tcp://a b:1", ""]):  # fmt: skip
        @case(f"sweep-scheduler-{n}")
        def build(folder, assets, address=address):
            path = _write(folder / "sweep.yaml", _dump(SWEEP))
            return _sweep_argv(path, folder, "--scheduler", address), "--scheduler"

    for n, workers in enumerate(["0", "-2"]):
        @case(f"sweep-workers-{n}")
        def build(folder, assets, workers=workers):
            path = _write(folder / "sweep.yaml", _dump(SWEEP))
            return _sweep_argv(path, folder, "--workers", workers), "--workers"


_sweep_option_cases()


# --------------------------------------------------------------------------- captures


def _capture(folder: Path, **changes: Any) -> Path:
    cap = analytic_capture(width=32, height=24)
    return write_capture(cap.replace(**changes) if changes else cap, folder / "cap")


def _estimate_argv(cap: Path, folder: Path) -> list[str]:
    # --json: a failing estimate must not leave its output behind
    return ["estimate", str(cap), "--method", "paper-init", "--json", str(folder / "est.json")]


def _target_method_cases() -> None:
    """The target methods on captures that lack what they read (issue 40): one line naming the capture and what is
    missing, before any fit."""
    cases = {
        "mirror-spheres-no-balls": (["--method", "mirror-spheres"], "mirror spheres"),
        "lambertian-card-no-card": (["--method", "lambertian-plane", "--set", "surface=card"], "matte_card"),
        "lambertian-plane-sphere": (["--method", "lambertian-plane"], "plane"),
    }
    for name, (argv, culprit) in cases.items():
        @case(f"method-{name}")
        def build(folder, assets, argv=argv, culprit=culprit, name=name):
            shape = {"shape": "sphere"} if name.endswith("sphere") else {}
            cap = write_capture(analytic_capture(width=32, height=24, **shape), folder / "cap")
            return ["estimate", str(cap), *argv, "--json", str(folder / "est.json")], culprit


_target_method_cases()


def _exr_byte_cases() -> None:
    rng = random.Random(f"{SEED}-exr")
    for n in range(10):  # truncated at a random point
        frac = rng.uniform(0.0, 0.98)

        @case(f"capture-exr-truncated-{n}")
        def build(folder, assets, frac=frac):
            cap = _capture(folder)
            exr = cap / "capture.exr"
            data = exr.read_bytes()
            exr.write_bytes(data[: int(len(data) * frac)])
            return _estimate_argv(cap, folder), str(exr)

    for n in range(14):  # random byte ranges overwritten in the image data (ZIP-compressed, so detectable)
        start_frac, length, seed = rng.uniform(0.2, 0.95), rng.randrange(1, 64), rng.randrange(1 << 30)

        @case(f"capture-exr-overwritten-{n}")
        def build(folder, assets, start_frac=start_frac, length=length, seed=seed):
            cap = _capture(folder)
            exr = cap / "capture.exr"
            data = bytearray(exr.read_bytes())
            start = int(len(data) * start_frac)
            r = random.Random(seed)
            for k in range(start, min(len(data), start + length)):
                data[k] = (data[k] + 1 + r.randrange(255)) % 256  # every byte really changes
            exr.write_bytes(bytes(data))
            return _estimate_argv(cap, folder), str(exr)

    for name, data in {"empty": b"", "png": b"\x89PNG\r\n\x1a\n" + b"\x00" * 100, "text": b"not an exr\n",
                       "magic-only": b"\x76\x2f\x31\x01"}.items():  # fmt: skip
        @case(f"capture-exr-{name}")
        def build(folder, assets, data=data):
            cap = _capture(folder)
            (cap / "capture.exr").write_bytes(data)
            return _estimate_argv(cap, folder), str(cap / "capture.exr")


_exr_byte_cases()


def _json_mutation_cases() -> None:
    """Random mutations of capture.json: wrong types, missing keys, bad values (seeded)."""
    bad: dict[str, list[Any]] = {
        "format": ["nearlight-capture/3", "nearlight-capture/0", None, 1, "exr"],
        "units": ["mm", "inch", 1],
        "width": [0, -32, "32", 33, 32.5, None, True],
        "height": [0, 25, "24", None],
        "camera": [None, "pinhole", [0, 0, 1]],
        "camera.position": [[0, 0], "here", [None, 0, 0], [0, 0, 0, 0], None],
        "camera.to_world": [[[1, 0, 0], [0, 1, 0], [0, 0, 1]], "identity", [[1] * 4] * 3],
        "camera.fov_x_deg": [0, 180, -5, "wide"],
        "analyzer_angles_deg": [[], [0, 45], [0, 45, 90], "all", [0, 45, 90, "135"]],
        "lamp_polarizer_axis": [[1, 0], "x"],
        # v2 keys (docs/capture-format.md)
        "rig": ["ideal", [1], 3],
        "rig.lamps": [0, -1, 1.5, "one", True],
        "rig.analyzer_extinction_ratio": [0.5, -3, "high", [300], float("inf")],
        "rig.lamp_polarizer_extinction_ratio": [0, "x"],
        "truth": ["lamp", [1, 2]],
        "truth.lamps": [[], "one", [5], [{"position": [0, 0]}], [{"position": [0, 0, 1], "radius_m": -1}],
                        [{"position": [0, 0, 1], "intensity": [-1, 1, 1]}],
                        [{"position": [0, 0, 1], "polarizer_extinction_ratio": 0.9}],
                        [{"position": [0, 0, 1], "anisotropy": {"k": -1, "axis": [0, 0, 1]}}],
                        [{"position": [0, 0, 1], "anisotropy": {"k": 2, "axis": [0, 0, 0]}}],
                        [{"position": [0, 0, 1], "anisotropy": "cos"}]],  # fmt: skip
        "truth.camera": ["pinhole", {"position": [0, 1]}, {"position": [0, 0, 1], "fov_x_deg": 200},
                         {"position": [0, 0, 1], "to_world": [[1, 0], [0, 1]]}],  # fmt: skip
        "truth.nuisances": ["bench", [1]],
        # object ids and calibration targets (issue 39): the capture has no object_id layer
        "objects": [["object"], [], "object", ["targets.0"], ["object", "object"], [1]],
        "rig.targets": ["balls", [5], [{"type": "cube"}], [{"type": "mirror_sphere", "name": "targets.0"}],
                        [{"type": "mirror_sphere", "name": "targets.0", "centre": [0, 0, 0.1], "radius": -1}],
                        [{"type": "matte_card", "name": "targets.0", "centre": [0, 0, 0.1], "normal": [0, 0, 0],
                          "size": [0.1, 0.1]}],
                        [{"type": "mirror_sphere", "name": "", "centre": [0, 0, 0.1], "radius": 0.02}],
                        [{"type": "mirror_sphere", "name": "targets.0", "centre": [0, 0, 0.1], "radius": 0.02,
                          "centre_error_m": "1mm"}]],
    }
    rng = random.Random(f"{SEED}-json")
    items = [(k, v) for k, vs in bad.items() for v in vs]
    for n, (key, value) in enumerate(items):
        @case(f"capture-json-{key}-{n}")
        def build(folder, assets, key=key, value=value):
            cap = _capture(folder)
            path = cap / "capture.json"
            doc = json.loads(path.read_text())
            if "." in key:
                section, sub = key.split(".")
                doc[section][sub] = value
            else:
                doc[key] = value
            path.write_text(json.dumps(doc))
            return _estimate_argv(cap, folder), key.split(".")[-1]

    # rig.range (v2): the error names the key inside rig.range
    ok_range = {"sigma_m": 0.001, "quantum_m": 0.0, "axis": "ray"}
    bad_range: list[tuple[str, Any, str]] = [
        ("not-object", "laser", "rig.range"),
        ("list", [0.001, 0.0, "ray"], "rig.range"),
        ("unknown-key", {**ok_range, "gain": 2}, "rig.range.gain"),
        ("sigma-negative", {**ok_range, "sigma_m": -0.001}, "rig.range.sigma_m"),
        ("sigma-string", {**ok_range, "sigma_m": "1mm"}, "rig.range.sigma_m"),
        ("sigma-nan-string", {**ok_range, "sigma_m": "NaN"}, "rig.range.sigma_m"),
        ("sigma-bool", {**ok_range, "sigma_m": True}, "rig.range.sigma_m"),
        ("quantum-missing", {"sigma_m": 0.001, "axis": "ray"}, "rig.range.quantum_m"),
        ("quantum-negative", {**ok_range, "quantum_m": -1}, "rig.range.quantum_m"),
        ("axis-x", {**ok_range, "axis": "x"}, "rig.range.axis"),
        ("axis-missing", {"sigma_m": 0.001, "quantum_m": 0.0}, "rig.range.axis"),
        ("source-laser", {**ok_range, "source": "laser"}, "rig.range.source"),
    ]
    for name, value, culprit in bad_range:
        @case(f"capture-json-rig.range-{name}")
        def build(folder, assets, value=value, culprit=culprit):
            cap = _capture(folder)
            path = cap / "capture.json"
            doc = json.loads(path.read_text())
            doc["rig"]["range"] = value
            path.write_text(json.dumps(doc))
            return _estimate_argv(cap, folder), culprit

    for key in ("format", "width", "height", "camera", "camera.position"):
        @case(f"capture-json-missing-{key}")
        def build(folder, assets, key=key):
            cap = _capture(folder)
            path = cap / "capture.json"
            doc = json.loads(path.read_text())
            if "." in key:
                del doc[key.split(".")[0]][key.split(".")[1]]
            else:
                del doc[key]
            path.write_text(json.dumps(doc))
            return _estimate_argv(cap, folder), key.split(".")[-1]

    for n in range(6):  # the text cut short, or a random byte swapped for a non-UTF-8 one
        seed = rng.randrange(1 << 30)

        @case(f"capture-json-bytes-{n}")
        def build(folder, assets, seed=seed, n=n):
            r = random.Random(seed)
            cap = _capture(folder)
            path = cap / "capture.json"
            data = bytearray(path.read_bytes())
            if n % 2:
                data = data[: r.randrange(1, len(data) - 2)]
            else:
                data[r.randrange(len(data))] = 0xFF
            path.write_bytes(bytes(data))
            return _estimate_argv(cap, folder), str(path)

    for name, data in {"empty": b"", "array": b"[1, 2, 3]", "nan-width": b'{"format": "nearlight-capture/1", "width": NaN}',
                       "utf16": json.dumps({"format": "nearlight-capture/1"}).encode("utf-16")}.items():  # fmt: skip
        @case(f"capture-json-{name}")
        def build(folder, assets, data=data):
            cap = _capture(folder)
            (cap / "capture.json").write_bytes(data)
            return _estimate_argv(cap, folder), str(cap)


_json_mutation_cases()


def _content_cases() -> None:
    """Captures that read fine but carry no usable signal or impossible geometry (class 7)."""
    base = analytic_capture(width=32, height=24)
    s, P = base.stack, base.P

    def nan_at_surface(stack: np.ndarray) -> np.ndarray:
        stack = stack.copy()
        stack[1, 12, 16, 0] = np.nan
        return stack

    variants: dict[str, tuple[dict[str, Any], str]] = {
        "all-zero": ({"stack": np.zeros_like(s)}, "pol"),
        "all-negative": ({"stack": -np.abs(s) - 0.01}, "pol"),
        "mostly-negative": ({"stack": s - 2 * s.max()}, "pol"),
        "constant": ({"stack": np.full_like(s, 0.25)}, "pol"),
        "constant-per-angle": ({"stack": np.ones_like(s) * np.arange(4, dtype=np.float32)[:, None, None, None]},
                               "specular"),
        "nan-at-surface": ({"stack": nan_at_surface(s)}, "pol1"),
        "inf-at-surface": ({"stack": np.where(np.arange(32)[None, None, :, None] == 16, np.inf, s)}, "pol"),
        "P-shifted-5m": ({"P": P + np.float32([5.0, 0.0, 0.0])}, "channel P"),
        "P-shifted-1m-up": ({"P": P + np.float32([0.0, 0.0, 1.0])}, "channel P"),
        "P-behind-camera": ({"P": 2 * base.camera.position.astype(np.float32) - P}, "channel P"),
        "P-all-nan": ({"P": np.full_like(P, np.nan)}, "P"),
        "P-mirrored": ({"P": P[:, ::-1].copy()}, "channel P"),
        "N-nan-at-surface": ({"N": np.where(np.arange(32)[None, :, None] == 10, np.nan, base.N)}, "channel N"),
    }
    for name, (changes, culprit) in variants.items():
        @case(f"capture-content-{name}")
        def build(folder, assets, changes=changes, culprit=culprit):
            return _estimate_argv(_capture(folder, **changes), folder), culprit

    @case("capture-content-specular-negative")
    def build(folder, assets):
        cap = analytic_capture(width=32, height=24, analyzer_angles_deg=None)
        return _estimate_argv(write_capture(cap.replace(specular=-np.abs(cap.specular) - 1), folder / "cap"),
                              folder), "specular"  # fmt: skip

    @case("capture-content-specular-constant")
    def build(folder, assets):
        cap = analytic_capture(width=32, height=24, analyzer_angles_deg=None)
        return _estimate_argv(write_capture(cap.replace(specular=np.full_like(cap.specular, 0.3)), folder / "cap"),
                              folder), "specular"  # fmt: skip

    for name, action in {"no-json": "capture.json", "no-exr": "capture.exr"}.items():
        @case(f"capture-{name}")
        def build(folder, assets, action=action):
            cap = _capture(folder)
            (cap / action).unlink()
            return _estimate_argv(cap, folder), action

    case("capture-missing-folder")(lambda folder, assets: (_estimate_argv(folder / "nope", folder), str(folder / "nope")))


_content_cases()


# --------------------------------------------------------------------------- output places


def _user_folder(folder: Path, name: str = "mine") -> Path:
    d = folder / name
    d.mkdir()
    (d / "thesis.tex").write_text("\\chapter{Results}\n")
    return d


def _output_place_cases() -> None:
    scene = ROOT / "scenes" / "ts_board.yaml"

    def render(folder: Path, out: Path, *extra: str) -> list[str]:
        return ["render", str(scene), "--out", str(out), "--quiet", *extra]

    @case("out-render-overwrite-user-folder")
    def build(folder, assets):
        d = _user_folder(folder)
        return render(folder, d, "--no-cache", "--overwrite"), str(d)

    @case("out-render-overwrite-capture-plus-file")
    def build(folder, assets):
        cap = _capture(folder)
        (cap / "notes.txt").write_text("mine")
        return render(folder, cap, "--no-cache", "--overwrite"), str(cap)

    @case("out-render-overwrite-empty-folder")
    def build(folder, assets):
        (folder / "empty").mkdir()
        return render(folder, folder / "empty", "--no-cache", "--overwrite"), str(folder / "empty")

    @case("out-render-overwrite-a-file")
    def build(folder, assets):
        f = _write(folder / "data.csv", "a,b\n1,2\n")
        return render(folder, f, "--no-cache", "--overwrite"), str(f)

    @case("out-render-overwrite-lookalike")
    def build(folder, assets):
        d = folder / "look"
        _write(d / "capture.json", '{"format": "my-format/1"}')
        _write(d / "capture.exr", b"\x76\x2f\x31\x01")
        return render(folder, d, "--no-cache", "--overwrite"), str(d)

    @case("out-render-exists")
    def build(folder, assets):
        cap = _capture(folder)
        return render(folder, cap, "--no-cache"), str(cap)

    @case("out-render-parent-is-a-file")
    def build(folder, assets):
        f = _write(folder / "f", "x")
        return render(folder, f / "cap", "--no-cache"), str(f / "cap")

    @case("out-render-cache-is-a-file")
    def build(folder, assets):
        f = _write(folder / "cache", "x")
        return render(folder, folder / "out", "--cache", str(f)), str(f)

    @case("out-render-cache-under-a-file")
    def build(folder, assets):
        f = _write(folder / "cache", "x")
        return render(folder, folder / "out", "--cache", str(f / "renders")), str(f / "renders")

    for place in ("/proc/nearlight-cache", "/sys/nearlight/renders"):  # os.access says yes to root; mkdir fails

        @case(f"out-render-cache-uncreatable-{place.split('/')[1]}")
        def build(folder, assets, place=place):
            return render(folder, folder / "out", "--cache", place), place

    @case("out-show-existing-folder")
    def build(folder, assets):
        cap = _capture(folder)
        (folder / "sheets").mkdir()
        return ["show", str(cap), "--out", str(folder / "sheets")], str(folder / "sheets")

    for ext in ("jpg", "tiff", "pdf", "xyz", ""):
        @case(f"out-show-extension-{ext or 'none'}")
        def build(folder, assets, ext=ext):
            cap = _capture(folder)
            out = folder / (f"sheet.{ext}" if ext else "sheet")
            return ["show", str(cap), "--out", str(out)], str(out)

    @case("out-show-user-file-named-png")
    def build(folder, assets):
        cap = _capture(folder)
        f = _write(folder / "sheet.png", "my notes, not a picture")
        return ["show", str(cap), "--out", str(f)], str(f)

    @case("out-show-default-beside-is-user-file")
    def build(folder, assets):
        cap = _capture(folder)
        _write(folder / "cap.png", "my notes")
        return ["show", str(cap)], str(folder / "cap.png")

    @case("out-estimate-json-user-file")
    def build(folder, assets):
        cap = _capture(folder)
        f = _write(folder / "settings.json", '{"my": "settings"}')
        return ["estimate", str(cap), "--method", "paper-init", "--json", str(f)], str(f)

    @case("out-estimate-json-is-folder")
    def build(folder, assets):
        cap = _capture(folder)
        (folder / "est.json").mkdir()
        return ["estimate", str(cap), "--method", "paper-init", "--json", str(folder / "est.json")], "est.json"

    @case("out-estimate-json-wrong-suffix")
    def build(folder, assets):
        cap = _capture(folder)
        return ["estimate", str(cap), "--method", "paper-init", "--json", str(folder / "est.txt")], "est.txt"

    @case("out-estimate-plot-extension")
    def build(folder, assets):
        cap = _capture(folder)
        return ["estimate", str(cap), "--method", "paper-init", "--json", str(folder / "e.json"),
                "--plot", str(folder / "p.pdf")], "p.pdf"  # fmt: skip

    @case("out-estimate-plot-user-file")
    def build(folder, assets):
        cap = _capture(folder)
        f = _write(folder / "p.png", "thesis figure source")
        return ["estimate", str(cap), "--method", "paper-init", "--json", str(folder / "e.json"),
                "--plot", str(f)], str(f)  # fmt: skip

    @case("out-estimate-plot-parent-is-file")
    def build(folder, assets):
        cap = _capture(folder)
        f = _write(folder / "f", "x")
        return ["estimate", str(cap), "--method", "paper-init", "--json", str(folder / "e.json"),
                "--plot", str(f / "p.png")], str(f / "p.png")  # fmt: skip

    @case("out-report-out-is-a-file")
    def build(folder, assets):
        res = _copy_results(folder, assets)
        f = _write(folder / "report", "x")
        return ["report", str(res), "--out", str(f)], str(f)

    @case("out-report-user-summary")
    def build(folder, assets):
        res = _copy_results(folder, assets)
        d = _user_folder(folder, "rep")
        _write(d / "summary.md", "# My summary\n")
        return ["report", str(res), "--out", str(d)], str(d / "summary.md")

    @case("out-report-user-csv")
    def build(folder, assets):
        res = _copy_results(folder, assets)
        _write(res / "report" / "overall.csv", "name,phone\nann,123\n")
        return ["report", str(res)], "overall.csv"

    @case("out-reproduce-out-is-a-file")
    def build(folder, assets):
        f = _write(folder / "repro", "x")
        return ["reproduce", "--out", str(f), "--quick", "--quiet"], str(f)

    @case("out-reproduce-user-markdown")
    def build(folder, assets):
        d = _user_folder(folder, "repro")
        _write(d / "paper_reproduction.md", "# my draft\n")
        return ["reproduce", "--out", str(d), "--quick", "--quiet"], "paper_reproduction.md"

    @case("out-reproduce-figures-is-a-file")
    def build(folder, assets):
        d = folder / "repro"
        _write(d / "figures", "x")
        return ["reproduce", "--out", str(d), "--quick", "--quiet"], "figures"

    @case("out-sweep-out-is-a-file")
    def build(folder, assets):
        path = _write(folder / "sweep.yaml", _dump(SWEEP))
        f = _write(folder / "results", "x")
        return ["sweep", str(path), "--out", str(f), "--quiet"], str(f)


_output_place_cases()


# --------------------------------------------------------------------------- damaged results (class 6)


def _copy_results(folder: Path, assets: dict[str, Path]) -> Path:
    dst = folder / "results"
    shutil.copytree(assets["results"], dst)
    return dst


def _damaged_results_cases() -> None:
    rng = random.Random(f"{SEED}-parquet")
    damages: dict[str, Callable[[Path], tuple[Path, bytes | None]]] = {}

    def truncate_part(res: Path, frac: float) -> tuple[Path, bytes | None]:
        part = sorted((res / "parts").glob("*.parquet"))[0]
        return part, part.read_bytes()[: int(part.stat().st_size * frac)]

    for n in range(3):
        damages[f"part-truncated-{n}"] = lambda res, f=rng.uniform(0.05, 0.95): truncate_part(res, f)
    damages["part-garbage"] = lambda res: (sorted((res / "parts").glob("*.parquet"))[-1], b"garbage" * 50)
    damages["part-empty"] = lambda res: (sorted((res / "parts").glob("*.parquet"))[0], b"")

    def columnless(res: Path) -> tuple[Path, bytes | None]:
        import pandas as pd

        part = sorted((res / "parts").glob("*.parquet"))[0]
        pd.DataFrame({"x": [1]}).to_parquet(part, index=False)
        return part, None

    damages["part-columnless"] = columnless
    damages["results-truncated"] = lambda res: (res / "results.parquet", (res / "results.parquet").read_bytes()[:100])
    damages["results-garbage"] = lambda res: (res / "results.parquet", b"PAR1" + b"\x00" * 64)

    for name, damage in damages.items():
        for verb in ("report", "compare") if name.startswith("results") else ("report",):
            @case(f"results-{name}-{verb}")
            def build(folder, assets, damage=damage, verb=verb, name=name):
                res = _copy_results(folder, assets)
                if name.startswith("part"):
                    (res / "results.parquet").unlink()  # an unfinished sweep: report reads the parts
                path, data = damage(res)
                if data is not None:
                    path.write_bytes(data)
                argv = ["report", str(res)] if verb == "report" else ["compare", str(res), str(assets["results"])]
                return argv, str(path)

    for name, data in {"truncated": None, "garbage": b"\xff\xfe\x00", "array": b"[]", "no-hash": b'{"name": "x"}'}.items():
        @case(f"results-sweep-json-{name}-resume")
        def build(folder, assets, data=data):
            res = _copy_results(folder, assets)
            manifest = res / "sweep.json"
            manifest.write_bytes(manifest.read_bytes()[:20] if data is None else data)
            return _sweep_argv(assets["sweep"], folder), str(manifest)

    @case("results-not-a-results-folder")
    def build(folder, assets):
        d = _user_folder(folder)
        return ["report", str(d)], str(d)


_damaged_results_cases()


def _show_twins() -> None:
    """``show`` reads captures with the same reader: every damaged-file capture case again through ``show``."""
    for c in [c for c in CASES if c.id.startswith(("capture-exr-", "capture-json-", "capture-no-"))]:
        @case(f"show-{c.id}")
        def build(folder, assets, original=c.build):
            argv, culprit = original(folder, assets)
            return ["show", argv[1], "--out", str(folder / "sheet.png")], culprit


_show_twins()


# --------------------------------------------------------------------------- estimator options


#: Values no declared option accepts, whatever its kind (a number, a count, a choice by name, a flag).
BAD_OPTION_VALUES: list[Any] = ["abc", [1, 2], {"a": 1}]


def _estimator_option_cases() -> None:
    """Every declared option of every built-in method with values none accepts, plus unknown names; through
    ``estimate --set`` (refused before the capture is read) and a sweep file's ``methods[].options``."""
    from nearlight.estimator import METHODS
    from nearlight.estimator.options import declared_options

    rng = random.Random(SEED)
    for method, fn in METHODS.items():
        names = list(declared_options(fn)[0])
        unknown = ["".join(rng.choice("abcdefghijklmnopqrstuvwxyz") for _ in range(8)) for _ in range(2)]
        pairs = [(n, v) for n in names for v in BAD_OPTION_VALUES] + [(u, 1) for u in unknown]
        for k, (name, value) in enumerate(pairs):
            @case(f"option-{method}-{name}-{k}")
            def build(folder, assets, method=method, name=name, value=value):
                return ["estimate", str(folder / "no-capture"), "--method", method,
                        "--set", f"{name}={json.dumps(value)}"], name  # fmt: skip

        name, value = rng.choice(pairs)

        @case(f"sweep-method-option-{method}")
        def build(folder, assets, method=method, name=name, value=value):
            doc = {**SWEEP, "methods": [{"method": method, "options": {name: value}}]}
            return _sweep_argv(_write(folder / "sweep.yaml", _dump(doc)), folder), name


_estimator_option_cases()


# --------------------------------------------------------------------------- running the cases


@pytest.fixture(scope="module")
def assets(tmp_path_factory) -> dict[str, Path]:
    """A finished tiny analytic sweep (results folder and its sweep file), built once."""
    from nearlight.evaluation.engine.run import run_sweep
    from nearlight.evaluation.engine.sweep import load_sweep

    d = tmp_path_factory.mktemp("fuzz-assets")
    sweep = _write(d / "sweep.yaml", _dump(SWEEP))
    run_sweep(load_sweep(sweep), d / "results", progress=False)
    return {"results": d / "results", "sweep": sweep}


@pytest.fixture(autouse=True)
def _no_rendering(monkeypatch):
    """Refusals must come before any Mitsuba tracing: reaching it fails the case."""
    from nearlight.generator import render as render_module

    def refuse(*args, **kwargs):
        raise AssertionError("a broken input reached Mitsuba's tracing instead of being refused")

    monkeypatch.setattr(render_module, "trace_stokes", refuse)
    monkeypatch.setenv("NEARLIGHT_CACHE", "/nonexistent-nearlight-cache")


def _snapshot(folder: Path) -> dict[str, bytes | str | None]:
    """Every file's bytes below ``folder`` (None for a folder), a symbolic link by its target (a case may link a
    file to /dev/zero, which must not be read)."""
    def entry(p: Path) -> bytes | str | None:
        if p.is_symlink():
            return "-> " + os.readlink(p)
        return None if p.is_dir() else p.read_bytes()

    return {str(p.relative_to(folder)): entry(p) for p in sorted(folder.rglob("*"))}


@pytest.mark.parametrize("c", CASES, ids=[c.id for c in CASES])
def test_broken_input_is_one_clear_line(c: Case, tmp_path, assets, capsys, monkeypatch):
    assert_one_clear_line(c, tmp_path, assets, capsys, monkeypatch)


def assert_one_clear_line(c: Case, tmp_path: Path, assets: dict[str, Path], capsys, monkeypatch) -> None:
    """Build case ``c`` in ``tmp_path/case``, run it there, and check the layer's four rules (module docstring);
    shared with the other fuzz files (``tests/test_fuzz_newer_verbs.py``)."""
    folder = tmp_path / "case"
    folder.mkdir()
    argv, culprit = c.build(folder, assets)
    monkeypatch.chdir(folder)
    before = _snapshot(folder)
    capsys.readouterr()
    status = main(argv)
    out, err = capsys.readouterr()
    lines = err.splitlines()
    assert "Traceback" not in err and "Traceback" not in out
    assert status == 2, f"exit {status}; stderr: {err!r}"
    assert len(lines) == 1, f"expected one stderr line, got: {err!r}"
    assert lines[0].startswith("nearlight: error: "), lines[0]
    assert culprit in lines[0], f"{culprit!r} not named in: {lines[0]}"
    assert _snapshot(folder) == before, "the command changed files although it refused the input"


def test_case_count():
    """How many generated cases the layer runs (the README's "several hundred")."""
    ids = [c.id for c in CASES]
    assert len(ids) == len(set(ids)) and len(ids) >= 300
    print(f"\nfuzz layer: {len(ids)} generated broken-input cases (seed {SEED})")


def test_miscalibrated_but_sane_captures_still_estimate(tmp_path, capsys):
    """The control: a camera a few millimetres off and range noise along the rays are accepted (exit 0)."""
    base = analytic_capture(width=48, height=36)
    rng = np.random.default_rng(SEED)
    along = (base.P - base.camera.position) * rng.normal(0, 0.002, size=base.P.shape[:2] + (1,))
    for name, cap in {"P-3mm-off": base.replace(P=base.P + np.float32([0.003, -0.002, 0.001])),
                      "range-noise": base.replace(P=(base.P + along).astype(np.float32), N=None)}.items():  # fmt: skip
        folder = write_capture(cap, tmp_path / name)
        assert main(["estimate", str(folder), "--method", "paper-init"]) == 0, capsys.readouterr().err


def test_verbs_replace_their_own_outputs(tmp_path, assets, capsys):
    """The other control: re-running a verb replaces what it wrote before (exit 0 twice)."""
    cap = write_capture(analytic_capture(width=32, height=24), tmp_path / "cap")
    res = tmp_path / "results"
    shutil.copytree(assets["results"], res)
    runs = [["estimate", str(cap), "--method", "paper-init", "--json", str(tmp_path / "e.json"),
             "--plot", str(tmp_path / "e.png")],
            ["show", str(cap), "--out", str(tmp_path / "sheet.png")],
            ["show", str(cap)],
            ["report", str(res)],
            ["report", str(res), "--out", str(tmp_path / "rep")]]  # fmt: skip
    for argv in runs:
        for _ in range(2):
            assert main(argv) == 0, capsys.readouterr().err
    assert not list(tmp_path.rglob(".*.partial"))
