"""The rig file (``nearlight-rig/1``): a rig's raw files and calibration, named once (``docs/rig-files.md``).

A lab writes one rig file per capture (or keeps one and swaps the file names):
which files hold the polarization frames and the depth map, and what the
calibration says (intrinsics, distortion, poses, black and white levels). This
module reads and checks it; every mistake is one line naming the file and the
key (:class:`~nearlight.errors.UserError`). Paths in it are relative to the
rig file's folder.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import UserError
from ..files.schema import all_numbers, is_number
from ..files.yamlfile import load_yaml_file

#: The version tag every rig file carries (``format``).
RIG_FORMAT = "nearlight-rig/1"
#: The 2×2 micro-polarizer pattern of Sony's IMX250MZR/MYR (polanalyser's): angles, degrees, as stored.
IMX250_PATTERN = ((90.0, 45.0), (135.0, 0.0))
#: Named patterns for ``polarization.pattern``.
PATTERNS = {"IMX250": IMX250_PATTERN}
#: Mosaic kinds: a mono sensor, or a colour one (each 2×2 polarization block one colour, the blocks in an RGGB Bayer).
MOSAICS = ("mono", "colour")
#: The response gammas a rig file may state: a camera's response is within these (1: linear, 2.2: sRGB-like);
#: γ = 1e6 would turn every unsaturated DN into 0 (a black capture), γ = 1e-6 into white.
GAMMA_RANGE = (0.1, 10.0)
#: Most ADC bits of ``polarization.sensor.bits``: what the capture reader accepts (``capture.format``).
MAX_BITS = 32
_TOP_KEYS = ("format", "camera", "polarization", "depth", "mesh")
#: Mesh length units (``mesh.units``): metres per unit.
MESH_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
#: Frames a mesh's pose may map into (``mesh.frame``).
MESH_FRAMES = ("world", "camera")


@dataclasses.dataclass(frozen=True)
class Pinhole:
    """Intrinsics in OpenCV's convention (pixel ``(0, 0)``'s centre at ``(0, 0)``, row 0 at the top), pixels."""

    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, ...] = ()

    @property
    def K(self) -> np.ndarray:
        """``[3, 3]`` camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


@dataclasses.dataclass(frozen=True)
class Shot:
    """One exposure: its files (one mosaic frame, or one image per analyzer angle) and relative exposure time."""

    files: tuple[Path, ...]
    exposure: float


@dataclasses.dataclass(frozen=True)
class MeshSpec:
    """The object's mesh and where it is (``mesh`` section).

    Attributes
    ----------
    file : Path
        PLY or OBJ file.
    to_world : ndarray, shape (4, 4)
        Mesh coordinates, **in metres** (the file's values times ``units``), to
        the world frame: ``mesh.pose`` (or ``rotation``, ``translation``),
        composed with ``camera.pose`` when ``mesh.frame`` is ``camera``.
    units : float
        Metres per mesh unit.
    """

    file: Path
    to_world: np.ndarray
    units: float


@dataclasses.dataclass(frozen=True)
class RigFile:
    """A checked rig file (``docs/rig-files.md`` has every key).

    Attributes
    ----------
    path : Path
        The rig file.
    width, height : int
        The camera's image size, pixels.
    camera : Pinhole
        The polarization camera's intrinsics and distortion.
    pose : ndarray, shape (4, 4)
        Camera-to-world transform, OpenCV camera axes (x right, y down, z forward), metres.
    camera_row0 : {"top", "bottom"}
        Where the camera's files keep image row 0.
    mosaic : {"mono", "colour"} or None
        A mosaic sensor, or None for one image per analyzer angle.
    pattern : ndarray, shape (2, 2)
        A mosaic's micro-polarizer angles as stored, degrees.
    angles_deg : ndarray, shape (K,)
        Analyzer angles of per-angle images, degrees.
    shots : tuple of Shot
        One or more exposures (several are merged to HDR).
    black_level, white_level : float
        Digital numbers of no light and of a full well.
    response_gamma : float
        The camera's response ``V = white·(L/white)^(1/γ)``; 1: linear.
    saturation : float
        Radiance (the capture's units) of a full well at exposure 1.
    sensor : dict or None
        ``full_well``, ``read_noise``, ``bits`` when the noise model is known.
    depth_file : Path or None
        The depth map; None when the geometry is a mesh.
    depth : Pinhole or None
    depth_size : (int, int) or None
        ``(width, height)`` the depth map must have, when given.
    depth_to_camera : ndarray, shape (4, 4)
        Depth-sensor frame to camera frame (both OpenCV axes), metres.
    depth_row0 : {"top", "bottom"}
    depth_scale : float or None
        Metres per stored unit; None: the file type's default (16-bit PNG/TIFF: 0.001, EXR/.npy: 1).
    mesh : MeshSpec or None
        The object's mesh, instead of a depth map (exactly one of the two).
    """

    path: Path
    width: int
    height: int
    camera: Pinhole
    pose: np.ndarray
    camera_row0: str
    mosaic: str | None
    pattern: np.ndarray | None
    angles_deg: np.ndarray | None
    shots: tuple[Shot, ...]
    black_level: float
    white_level: float
    response_gamma: float
    saturation: float
    sensor: dict[str, Any] | None
    depth_file: Path | None
    depth: Pinhole | None
    depth_size: tuple[int, int] | None
    depth_to_camera: np.ndarray | None
    depth_row0: str | None
    depth_scale: float | None
    mesh: MeshSpec | None


def load_rig_file(path: str | os.PathLike) -> RigFile:
    """Read and check a rig file.

    Parameters
    ----------
    path : path-like
        The rig file (YAML).

    Returns
    -------
    RigFile

    Raises
    ------
    UserError
        One line naming the file and key when a key is missing or wrong; files
        it names are checked when they are read (:mod:`nearlight.rig.importer`).
    """
    path = Path(path)
    doc = load_yaml_file(path, what="rig file")
    where = _Where(path)
    if not isinstance(doc, dict):
        raise UserError(f"{path}: expected a rig file (a YAML mapping with format: {RIG_FORMAT}), got {type(doc).__name__}")
    if doc.get("format") != RIG_FORMAT:
        raise UserError(f"{path}: format: expected {RIG_FORMAT!r}, got {doc.get('format')!r}")
    where.unknown(doc, _TOP_KEYS, "")
    cam = where.section(doc, "camera")
    where.unknown(cam, ("width", "height", "intrinsics", "distortion", "pose", "row0"), "camera.")
    width = where.int(cam, "camera.width")
    height = where.int(cam, "camera.height")
    camera = where.pinhole(cam, "camera")
    pose = where.matrix(cam.get("pose"), "camera.pose")
    pol = where.section(doc, "polarization")
    where.unknown(pol, ("mosaic", "pattern", "angles_deg", "shots", "black_level", "white_level",
                        "response_gamma", "saturation", "sensor"), "polarization.")  # fmt: skip
    mosaic = pol.get("mosaic")
    if mosaic is not None and mosaic not in MOSAICS:
        raise UserError(f"{path}: polarization.mosaic: expected one of {', '.join(MOSAICS)} (or absent for "
                        f"one image per angle), got {mosaic!r}")  # fmt: skip
    pattern = angles = None
    if mosaic is not None:
        pattern = where.pattern(pol.get("pattern", "IMX250"))
        if width % 2 or height % 2 or (mosaic == "colour" and (width % 4 or height % 4)):
            k = 2 if mosaic == "mono" else 4
            raise UserError(f"{path}: camera.width, camera.height: a {mosaic} mosaic needs multiples of {k}, "
                            f"got {width}x{height}")  # fmt: skip
    else:
        if "pattern" in pol:
            raise UserError(f"{path}: polarization.pattern: only for a mosaic (set polarization.mosaic)")
        angles = where.numbers(pol.get("angles_deg"), "polarization.angles_deg", None)
        if angles.ndim != 1 or angles.size < 3 or np.unique(np.mod(angles, 180.0)).size < 3:
            raise UserError(f"{path}: polarization.angles_deg: expected at least 3 distinct angles (mod 180), "
                            f"got {pol.get('angles_deg')!r}")  # fmt: skip
    if mosaic == "colour" and cam.get("row0") == "bottom":
        raise UserError(f"{path}: camera.row0: bottom is not supported for a colour mosaic (flipping its rows would "
                        "change its Bayer order); store the frame with row 0 at the top")  # fmt: skip
    shots = where.shots(pol.get("shots"), 1 if mosaic else len(angles))
    black = where.number(pol, "polarization.black_level", 0.0, low=0.0)
    white = where.number(pol, "polarization.white_level", None, low=black, strict=True)
    gamma = where.number(pol, "polarization.response_gamma", 1.0, low=0.0, strict=True)
    if not GAMMA_RANGE[0] <= gamma <= GAMMA_RANGE[1]:  # beyond, the inverse response makes the capture black or white
        raise where.fail("polarization.response_gamma", f"a number from {GAMMA_RANGE[0]:g} to {GAMMA_RANGE[1]:g} "
                         "(a camera's response: 1 linear, 2.2 sRGB-like)", gamma)  # fmt: skip
    saturation = where.number(pol, "polarization.saturation", 1.0, low=0.0, strict=True)
    sensor = pol.get("sensor")
    if sensor is not None:
        if not isinstance(sensor, dict):
            raise UserError(f"{path}: polarization.sensor: expected an object {{full_well, read_noise, bits}}")
        where.unknown(sensor, ("full_well", "read_noise", "bits"), "polarization.sensor.")
        sensor = {"full_well": where.number(sensor, "polarization.sensor.full_well", None, low=0.0, strict=True),
                  "read_noise": where.number(sensor, "polarization.sensor.read_noise", None, low=0.0),
                  "bits": where.int(sensor, "polarization.sensor.bits")}  # fmt: skip
        if not 1 <= sensor["bits"] <= MAX_BITS:  # the capture reader's range
            raise where.fail("polarization.sensor.bits", f"an integer from 1 to {MAX_BITS}", sensor["bits"])
        if white > 2 ** sensor["bits"] - 1:
            raise UserError(f"{path}: polarization.sensor.bits: {sensor['bits']} bits hold DN up to "
                            f"{2 ** sensor['bits'] - 1}, below polarization.white_level {white:g}")  # fmt: skip
    if ("depth" in doc) == ("mesh" in doc):
        raise UserError(f"{path}: depth, mesh: expected exactly one (a depth map or the object's mesh), got "
                        f"{'both' if 'depth' in doc else 'neither'}")  # fmt: skip
    if "depth" in doc:
        depth, mesh = _depth(where, where.section(doc, "depth")), None
    else:
        depth = dict.fromkeys(("depth_file", "depth", "depth_size", "depth_to_camera", "depth_row0", "depth_scale"))
        mesh = _mesh(where, where.section(doc, "mesh"), pose)
    return RigFile(
        path=path, width=width, height=height, camera=camera, pose=pose, camera_row0=where.row0(cam, "camera"),
        mosaic=mosaic, pattern=pattern, angles_deg=angles, shots=shots, black_level=black, white_level=white,
        response_gamma=gamma, saturation=saturation, sensor=sensor, mesh=mesh, **depth,
    )  # fmt: skip


def _depth(where: _Where, dep: dict) -> dict[str, Any]:
    """The ``depth`` section's fields of :class:`RigFile`."""
    where.unknown(dep, ("file", "intrinsics", "distortion", "width", "height", "to_camera", "row0", "scale"), "depth.")
    depth_size = None
    if "width" in dep or "height" in dep:
        depth_size = (where.int(dep, "depth.width"), where.int(dep, "depth.height"))
    scale = dep.get("scale")
    if scale is not None:
        scale = where.number(dep, "depth.scale", None, low=0.0, strict=True)
    return {"depth_file": where.file(dep, "depth.file"), "depth": where.pinhole(dep, "depth"), "depth_size": depth_size,
            "depth_to_camera": where.matrix(dep.get("to_camera"), "depth.to_camera"),
            "depth_row0": where.row0(dep, "depth"), "depth_scale": scale}  # fmt: skip


def _mesh(where: _Where, sec: dict, camera_pose: np.ndarray) -> MeshSpec:
    """The ``mesh`` section: the file, its units, and its pose composed into mesh-metres -> world."""
    where.unknown(sec, ("file", "units", "pose", "rotation", "translation", "frame"), "mesh.")
    units = sec.get("units")
    if units is None:
        raise UserError(f"{where.path}: mesh.units: missing (a mesh file has no units: {', '.join(MESH_UNITS)})")
    if not isinstance(units, str) or units not in MESH_UNITS:
        raise where.fail("mesh.units", f"one of {', '.join(MESH_UNITS)}", units)
    if "pose" in sec and ("rotation" in sec or "translation" in sec):
        raise UserError(f"{where.path}: mesh.pose: give either pose (4x4) or rotation and translation, not both")
    if "pose" in sec:
        pose = where.matrix(sec["pose"], "mesh.pose")
    else:
        pose = np.eye(4)
        if "rotation" in sec:
            pose[:3, :3] = where.rotation(sec["rotation"], "mesh.rotation")
        if "translation" in sec:
            pose[:3, 3] = where.numbers(sec["translation"], "mesh.translation", (3,))
    frame = sec.get("frame", "world")
    if frame not in MESH_FRAMES:
        raise where.fail("mesh.frame", f"one of {', '.join(MESH_FRAMES)}", frame)
    to_world = camera_pose @ pose if frame == "camera" else pose
    return MeshSpec(file=where.file(sec, "mesh.file"), to_world=to_world, units=MESH_UNITS[units])


def _is_rotation(R: np.ndarray) -> bool:
    """``R`` ``[3, 3]`` is a proper rotation (orthonormal to 1e-6, determinant > 0)."""
    return bool(np.allclose(R @ R.T, np.eye(3), atol=1e-6) and np.linalg.det(R) > 0)


class _Where:
    """Checks of rig-file values, each failing with one line naming the file and the key."""

    def __init__(self, path: Path):
        self.path = path

    def fail(self, key: str, want: str, got: Any) -> UserError:
        return UserError(f"{self.path}: {key}: expected {want}, got {got!r}")

    def unknown(self, doc: dict, keys: tuple[str, ...], prefix: str) -> None:
        extra = sorted(str(k) for k in doc if k not in keys)
        if extra:
            raise UserError(f"{self.path}: {prefix}{extra[0]}: unknown key (expected one of {', '.join(keys)})")

    def section(self, doc: dict, key: str) -> dict:
        if key not in doc:
            raise UserError(f"{self.path}: {key}: missing")
        if not isinstance(doc[key], dict):
            raise self.fail(key, "a mapping", doc[key])
        return doc[key]

    def int(self, doc: dict, key: str) -> int:
        v = doc.get(key.rpartition(".")[2])
        if v is None:
            raise UserError(f"{self.path}: {key}: missing")
        if not (isinstance(v, int) and not isinstance(v, bool) and v > 0):
            raise self.fail(key, "a positive integer", v)
        return v

    def number(self, doc: dict, key: str, default: float | None, *, low: float, strict: bool = False) -> float:
        v = doc.get(key.rpartition(".")[2], default)
        if v is None:
            raise UserError(f"{self.path}: {key}: missing")
        ok = is_number(v)
        if not ok or (v <= low if strict else v < low):
            raise self.fail(key, f"a number {'>' if strict else '>='} {low:g}", v)
        return float(v)

    def numbers(self, v: Any, key: str, shape: tuple[int, ...] | None) -> np.ndarray:
        if v is None:
            raise UserError(f"{self.path}: {key}: missing")
        try:  # numbers only: numpy would also read "135" or true as a number
            arr = np.asarray(v, dtype=float) if all_numbers(v) else None
        except (TypeError, ValueError):
            arr = None
        if arr is None or not np.all(np.isfinite(arr)) or (shape is not None and arr.shape != shape):
            want = "a list of numbers" if shape is None else f"numbers of shape {list(shape)}"
            raise self.fail(key, want, v)
        return arr

    def matrix(self, v: Any, key: str) -> np.ndarray:
        if v is None:
            return np.eye(4)
        m = self.numbers(v, key, (4, 4))
        if not (_is_rotation(m[:3, :3]) and np.allclose(m[3], [0, 0, 0, 1])):
            raise self.fail(key, "a 4x4 rigid transform (a rotation and a translation, last row 0 0 0 1)", v)
        return m

    def rotation(self, v: Any, key: str) -> np.ndarray:
        R = self.numbers(v, key, (3, 3))
        if not _is_rotation(R):
            raise self.fail(key, "a 3x3 rotation matrix (orthonormal, determinant +1)", v)
        return R

    def pinhole(self, doc: dict, prefix: str) -> Pinhole:
        k = doc.get("intrinsics")
        if k is None:
            raise UserError(f"{self.path}: {prefix}.intrinsics: missing (fx, fy, cx, cy in pixels, OpenCV's convention)")
        if not isinstance(k, dict):
            raise self.fail(f"{prefix}.intrinsics", "a mapping {fx, fy, cx, cy}", k)
        self.unknown(k, ("fx", "fy", "cx", "cy"), f"{prefix}.intrinsics.")
        values = {c: self.number(k, f"{prefix}.intrinsics.{c}", None, low=0.0, strict=c in ("fx", "fy")) for c in
                  ("fx", "fy", "cx", "cy")}  # fmt: skip
        dist = doc.get("distortion")
        dist = () if dist is None else tuple(self.numbers(dist, f"{prefix}.distortion", None).tolist())
        if len(dist) not in (0, 4, 5, 8, 12, 14):
            raise self.fail(f"{prefix}.distortion", "OpenCV's 4, 5, 8, 12 or 14 coefficients (k1 k2 p1 p2 [k3 ...])",
                            doc.get("distortion"))  # fmt: skip
        return Pinhole(**values, distortion=dist)

    def pattern(self, v: Any) -> np.ndarray:
        key = "polarization.pattern"
        if isinstance(v, str):
            if v not in PATTERNS:
                raise self.fail(key, f"a known pattern ({', '.join(PATTERNS)}) or a 2x2 list of angles", v)
            return np.array(PATTERNS[v], float)
        arr = self.numbers(v, key, (2, 2)) if isinstance(v, list) else None
        if arr is None:
            raise self.fail(key, f"a known pattern ({', '.join(PATTERNS)}) or a 2x2 list of angles", v)
        if np.unique(np.mod(arr, 180.0)).size != 4:
            raise self.fail(key, "4 distinct angles (mod 180)", v)
        return arr

    def file(self, doc: dict, key: str) -> Path:
        v = doc.get(key.rpartition(".")[2])
        if v is None:
            raise UserError(f"{self.path}: {key}: missing")
        if not isinstance(v, str) or not v:
            raise self.fail(key, "a file name", v)
        return self.inside(key, v)

    def inside(self, key: str, name: str) -> Path:
        """``name`` in the rig file's folder: an absolute path, or one that climbs out with ``..``, is refused
        (by its text: a symbolic link inside the folder is followed)."""
        if "\x00" in name or os.path.isabs(name) or ".." in Path(os.path.normpath(name)).parts:
            raise UserError(f"{self.path}: {key}: {name!r}: outside the rig file's folder (paths in a rig file are "
                            "relative to its folder and stay inside it)")  # fmt: skip
        return self.path.parent / name

    def shots(self, v: Any, n_files: int) -> tuple[Shot, ...]:
        key = "polarization.shots"
        if not isinstance(v, list) or not v:
            raise self.fail(key, "a non-empty list of {files: [...], exposure: t}", v)
        out = []
        for i, shot in enumerate(v):
            k = f"{key}[{i}]"
            if not isinstance(shot, dict):
                raise self.fail(k, "a mapping {files: [...], exposure: t}", shot)
            self.unknown(shot, ("files", "exposure"), f"{k}.")
            files = shot.get("files")
            if not isinstance(files, list) or not all(isinstance(f, str) and f for f in files):
                raise self.fail(f"{k}.files", "a list of file names", files)
            if len(files) != n_files:
                want = "1 file (a mosaic frame)" if n_files == 1 else f"{n_files} files (one per polarization.angles_deg)"
                raise UserError(f"{self.path}: {k}.files: {len(files)} files do not match the angles: expected {want}")
            exposure = self.number(shot, f"{k}.exposure", 1.0, low=0.0, strict=True)
            out.append(Shot(files=tuple(self.inside(f"{k}.files", f) for f in files), exposure=exposure))
        return tuple(out)

    def row0(self, doc: dict, prefix: str) -> str:
        v = doc.get("row0", "top")
        if v not in ("top", "bottom"):
            raise self.fail(f"{prefix}.row0", "top or bottom", v)
        return v
