"""Fuzz layer, rig files: rig files that would give a useless capture, each one clear line.

The rules of ``tests/test_fuzz_inputs.py`` (whose helpers this reuses): each
generated case breaks a good rig folder (the simulator's ``rig export`` of an
analytic board) in its own folder, runs ``nearlight rig import`` in-process
and asserts exit status 2, exactly one stderr line ``nearlight: error: ...``
naming the culprit (the file or key), no traceback, and the case's folder
byte-for-byte unchanged (no capture, no ``.partial`` left). Families:
absurd camera and depth distortion, response gamma, sensor bits and saturation; frames with
NaN/Inf, too few bits or DN far above the white level; arrays of the wrong
shape (a trailing axis of 1 is accepted: a control); damaged ``.npy``
headers; a rig file that is a device (``/dev/zero``), raw files linked to it; paths that leave the
rig file's folder. A full disk under ``rig import`` and ``rig export`` is
tested apart (a writer monkeypatched to raise ``ENOSPC``).
"""

from __future__ import annotations

import errno
import importlib.util
import random
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from nearlight.capture import write_capture
from nearlight.cli import main
from nearlight.errors import no_space
from nearlight.generator.analytic import analytic_capture

pytest.importorskip("polanalyser")
cv2 = pytest.importorskip("cv2")

_spec = importlib.util.spec_from_file_location("_fuzz_inputs", Path(__file__).with_name("test_fuzz_inputs.py"))
_fuzz = sys.modules.setdefault("_fuzz_inputs", importlib.util.module_from_spec(_spec))  # dataclasses need it there
_spec.loader.exec_module(_fuzz)
Case, _write, _dump, SEED = _fuzz.Case, _fuzz._write, _fuzz._dump, _fuzz.SEED


W, H = 64, 48
CASES: list[Case] = []


def case(id: str):
    def add(build):
        CASES.append(Case(id, build))
        return build

    return add


def _rig(folder: Path, assets: dict[str, Path], change=None) -> Path:
    """The good rig folder copied into ``folder/rig``, its rig file changed by ``change(doc, rigdir)``."""
    rigdir = folder / "rig"
    shutil.copytree(assets["rig"], rigdir)
    if change is not None:
        doc = yaml.safe_load((rigdir / "rig.yaml").read_text())
        change(doc, rigdir)
        (rigdir / "rig.yaml").write_text(_dump(doc))
    return rigdir / "rig.yaml"


def _import(rig: Path, folder: Path) -> list[str]:
    return ["rig", "import", str(rig), "--out", str(folder / "cap")]


def _key_case(id: str, culprit: str, change) -> None:
    @case(f"rig-{id}")
    def build(folder, assets):
        return _import(_rig(folder, assets, change), folder), culprit


def _set(section: str, key: str, value):
    def change(doc, rigdir):
        node = doc[section]
        *path, last = key.split(".")
        for p in path:
            node = node.setdefault(p, {})
        node[last] = value

    return change


# --------------------------------------------------------------------------- calibration values

for _i, _dist in enumerate([[1e3, 0, 0, 0], [0, 0, 0, 0, 1e6], [-80.0, 0, 0, 0, 0], [0, 0, 50.0, -50.0],
                            [200.0, 200.0, 0, 0, 200.0, 0, 0, 0]]):  # fmt: skip
    _key_case(f"distortion-{_i}", "camera.distortion", _set("camera", "distortion", _dist))

for _i, _gamma in enumerate([1e6, 1e-6, 50.0, 0.01, 0, -2.2, "2.2", float("inf")]):
    _key_case(f"response-gamma-{_i}", "polarization.response_gamma", _set("polarization", "response_gamma", _gamma))

for _i, _bits in enumerate([0, 64, 33, 1.5, 8, 10, -12]):  # 8 and 10 bits cannot hold the white level 4095
    _key_case(f"sensor-bits-{_i}", "polarization.sensor.bits", _set("polarization", "sensor.bits", _bits))

for _i, _sat in enumerate([1e35, 1e-35, 1e300, 5e-324]):
    _key_case(f"saturation-{_i}", "polarization.saturation", _set("polarization", "saturation", _sat))

for _i, _exp in enumerate([1e-40, 1e40]):
    _key_case(f"exposure-{_i}", "polarization.saturation",
              lambda d, r, e=_exp: d["polarization"]["shots"][0].update(exposure=e))  # fmt: skip

for _i, _white in enumerate([100, 1000]):  # the frame's DN go up to ~3700
    _key_case(f"white-level-below-the-frame-{_i}", "polarization.white_level", _set("polarization", "white_level", _white))

_key_case("black-level-above-every-dn", "black capture",
          lambda d, r: d["polarization"].update(black_level=4094, white_level=4095))


for _i, _dist in enumerate([[1e3, 0, 0, 0], [0, 0, 0, 0, 1e6], [-80.0, 0, 0, 0, 0], [0, 0, 50.0, -50.0],
                            [1e300, 0, 0, 0]]):  # fmt: skip
    _key_case(f"depth-distortion-{_i}", "depth.distortion", _set("depth", "distortion", _dist))


# --------------------------------------------------------------------------- frame and depth files


def _frame_dn(rigdir: Path) -> np.ndarray:
    return cv2.imread(str(rigdir / "frame.png"), cv2.IMREAD_UNCHANGED)


def _frame_as_npy(array_of):
    """Replace frame.png by frame.npy = ``array_of(dn, rng)``."""

    def change(doc, rigdir):
        np.save(rigdir / "frame.npy", array_of(_frame_dn(rigdir), random.Random(f"{SEED}-{id(array_of)}")))
        (rigdir / "frame.png").unlink()
        doc["polarization"]["shots"][0]["files"] = ["frame.npy"]

    return change


def _nan_at(dn, rng, n, value=np.nan):
    f = dn.astype(np.float32)
    for _ in range(n):
        f[rng.randrange(H), rng.randrange(W)] = value
    return f


for _i, _n in enumerate([1, 7, 200]):
    _key_case(f"frame-nan-{_i}", "frame.npy", _frame_as_npy(lambda dn, rng, n=_n: _nan_at(dn, rng, n)))
_key_case("frame-inf", "frame.npy", _frame_as_npy(lambda dn, rng: _nan_at(dn, rng, 3, np.inf)))
_key_case("frame-minus-inf", "frame.npy", _frame_as_npy(lambda dn, rng: _nan_at(dn, rng, 1, -np.inf)))
_key_case("frame-8-bit-under-a-12-bit-white", "frame.png",
          lambda d, r: cv2.imwrite(str(r / "frame.png"), (_frame_dn(r) // 16).astype(np.uint8)))
_key_case("frame-dn-16-times-the-white", "frame.png",
          lambda d, r: cv2.imwrite(str(r / "frame.png"), (_frame_dn(r).astype(np.uint32) * 16).clip(0, 65535)
                                   .astype(np.uint16)))  # fmt: skip
_key_case("frame-float-dn-far-above-white", "frame.npy", _frame_as_npy(lambda dn, rng: dn.astype(np.float64) * 1e6))

for _name, _shape_of in {"hw11": lambda dn: dn[..., None, None], "hw2": lambda dn: np.stack([dn, dn], axis=-1),
                         "1hw": lambda dn: dn[None], "flat": lambda dn: dn.ravel(), "scalar": lambda dn: dn[0, 0],
                         "empty": lambda dn: dn[:0]}.items():  # fmt: skip
    _key_case(f"frame-shape-{_name}", "frame.npy", _frame_as_npy(lambda dn, rng, f=_shape_of: f(dn)))


def _depth_as_npy(array_of):
    def change(doc, rigdir):
        z = cv2.imread(str(rigdir / "depth.png"), cv2.IMREAD_UNCHANGED).astype(np.float32) * 1e-3
        np.save(rigdir / "depth.npy", array_of(z))
        (rigdir / "depth.png").unlink()
        doc["depth"].update(file="depth.npy", scale=1.0)

    return change


for _name, _shape_of in {"hw2": lambda z: np.stack([z, z], axis=-1), "hw11": lambda z: z[..., None, None],
                         "flat": lambda z: z.ravel(), "hw3": lambda z: np.stack([z] * 3, axis=-1)}.items():  # fmt: skip
    _key_case(f"depth-shape-{_name}", "depth.npy", _depth_as_npy(_shape_of))


def _lying_npy_header(path: Path, data: bytes) -> None:
    """An .npy file whose header claims a 100000 x 100000 float64 array (80 GB) over ``data``."""
    header = b"{'descr': '<f8', 'fortran_order': False, 'shape': (100000, 100000), }"
    header += b" " * (117 - len(header)) + b"\n"
    path.write_bytes(b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header + data)


_key_case("depth-npy-header-claims-80-gb", "depth.npy",
          lambda d, r: (_lying_npy_header(r / "depth.npy", b"\x00" * 64), d["depth"].update(file="depth.npy")))
_key_case("frame-npy-truncated", "frame.npy",
          _frame_as_npy(lambda dn, rng: dn.astype(np.float32)))  # then cut below
CASES[-1] = Case(CASES[-1].id, lambda folder, assets, b=CASES[-1].build: _truncate(b(folder, assets), folder))


def _truncate(built, folder):
    npy = folder / "rig" / "frame.npy"
    npy.write_bytes(npy.read_bytes()[:500])
    return built


# --------------------------------------------------------------------------- not a rig file; paths out of the folder


@case("rig-file-is-dev-zero")
def _(folder, assets):
    return _import(Path("/dev/zero"), folder), "/dev/zero"


@case("rig-file-is-a-huge-file")
def _(folder, assets):
    path = _write(folder / "big.yaml", b"#" * ((16 << 20) + 10))
    return _import(path, folder), str(path)


for _i, (_what, _path) in enumerate([("depth", "../depth.png"), ("depth", "/dev/zero"), ("depth", "sub/../../depth.png"),
                                     ("frame", "../rig/frame.png"), ("frame", "/etc/hostname"),
                                     ("frame", "a/b/../../../x.png")]):  # fmt: skip
    def _escape(doc, rigdir, what=_what, path=_path):
        if what == "depth":
            doc["depth"]["file"] = path
        else:
            doc["polarization"]["shots"][0]["files"] = [path]

    _key_case(f"path-escapes-{_what}-{_i}", _path, _escape)


def _mesh_escape(doc, rigdir):
    doc.pop("depth")
    doc["mesh"] = {"file": "../object.ply", "units": "mm"}


_key_case("path-escapes-mesh", "../object.ply", _mesh_escape)


def _link_to_dev_zero(name: str):
    def change(doc, rigdir):
        import os

        (rigdir / name).unlink()
        os.symlink("/dev/zero", rigdir / name)

    return change


_key_case("depth-file-links-to-dev-zero", "depth.png: not a regular file", _link_to_dev_zero("depth.png"))
_key_case("frame-file-links-to-dev-zero", "frame.png: not a regular file", _link_to_dev_zero("frame.png"))


# --------------------------------------------------------------------------- running the cases


@pytest.fixture(scope="module")
def assets(tmp_path_factory) -> dict[str, Path]:
    """The good rig folder: the simulator's export of a 64x48 analytic board (12 bits, white level 4095)."""
    d = tmp_path_factory.mktemp("fuzz-rig")
    write_capture(analytic_capture(width=W, height=H), d / "cap")
    assert main(["rig", "export", str(d / "cap"), "--out", str(d / "rig")]) == 0
    return {"rig": d / "rig", "capture": d / "cap"}


@pytest.mark.parametrize("c", CASES, ids=[c.id for c in CASES])
def test_broken_rig_is_one_clear_line(c: Case, tmp_path, assets, capsys, monkeypatch):
    _fuzz.assert_one_clear_line(c, tmp_path, assets, capsys, monkeypatch)


def test_case_count():
    ids = [c.id for c in CASES]
    assert len(ids) == len(set(ids)) and len(ids) >= 40
    print(f"\nfuzz layer, rig files: {len(ids)} generated broken-rig cases (seed {SEED})")


def test_the_good_rig_and_a_trailing_axis_of_one_import(tmp_path, assets, capsys):
    """The controls: the good rig imports; frame and depth as (H, W, 1) arrays are one-channel images."""
    assert main(_import(assets["rig"] / "rig.yaml", tmp_path)) == 0, capsys.readouterr().err
    (tmp_path / "f").mkdir()
    rig = _rig(tmp_path / "f", assets, lambda d, r: (
        _frame_as_npy(lambda dn, rng: dn[..., None])(d, r), _depth_as_npy(lambda z: z[..., None])(d, r)))  # fmt: skip
    assert main(_import(rig, tmp_path / "f")) == 0, capsys.readouterr().err


def _enospc(*args, **kwargs):
    raise OSError(errno.ENOSPC, "No space left on device")


def test_full_disk_under_rig_import_is_one_line_and_nothing_half_written(tmp_path, assets, capsys, monkeypatch):
    from nearlight.capture import format as capture_format

    (tmp_path / "out").mkdir()
    real = Path.write_text

    def full(self, *args, **kwargs):  # capture.json half-written, then the disk is full
        if self.name == capture_format.JSON_NAME:
            real(self, "{")
            _enospc()
        return real(self, *args, **kwargs)

    monkeypatch.setattr(Path, "write_text", full)
    capsys.readouterr()
    assert main(_import(assets["rig"] / "rig.yaml", tmp_path / "out")) == 2
    _, err = capsys.readouterr()
    assert err == f"nearlight: error: {no_space(tmp_path / 'out' / 'cap')}\n", err  # errors.no_space: the one line
    assert list((tmp_path / "out").iterdir()) == []


def test_full_disk_under_rig_export_is_one_line_and_nothing_half_written(tmp_path, assets, capsys, monkeypatch):
    from nearlight.rig import export

    (tmp_path / "out").mkdir()
    real = export.write_png16

    def full(path, img):  # the frame written, the depth map half-written, then the disk is full
        if path.name == "depth.png":
            path.write_bytes(b"\x89PNG")
            _enospc()
        real(path, img)

    monkeypatch.setattr(export, "write_png16", full)
    capsys.readouterr()
    assert main(["rig", "export", str(assets["capture"]), "--out", str(tmp_path / "out" / "rig")]) == 2
    _, err = capsys.readouterr()
    assert err.startswith(f"nearlight: error: no space left on {tmp_path / 'out' / 'rig'}") and err.count("\n") == 1
    assert list((tmp_path / "out").iterdir()) == []


def test_a_truncated_exr_on_a_full_disk_is_refused_too(tmp_path, assets, capsys, monkeypatch):
    """OpenEXR reports no failed write (a full disk truncates the file silently): a file system with no free
    block after writing the capture's EXR counts as full."""
    import os
    from types import SimpleNamespace

    (tmp_path / "out").mkdir()
    monkeypatch.setattr(os, "statvfs", lambda p: SimpleNamespace(f_bfree=0))
    capsys.readouterr()
    assert main(_import(assets["rig"] / "rig.yaml", tmp_path / "out")) == 2
    _, err = capsys.readouterr()
    assert err.startswith(f"nearlight: error: no space left on {tmp_path / 'out' / 'cap'}") and err.count("\n") == 1
    assert list((tmp_path / "out").iterdir()) == []
    assert main(["rig", "export", str(assets["capture"]), "--out", str(tmp_path / "out" / "rig"),
                 "--depth-format", "exr"]) == 2
    _, err = capsys.readouterr()
    assert err.startswith(f"nearlight: error: no space left on {tmp_path / 'out' / 'rig'}") and err.count("\n") == 1
    assert list((tmp_path / "out").iterdir()) == []
