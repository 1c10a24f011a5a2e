"""Capture format (v1 and v2): the one module that reads and writes captures.

A capture is a directory holding ``capture.json`` (camera, analyzer angles,
optional ground truth) and ``capture.exr`` (analyzer stack or separated
specular image, range image ``P``, optional normals ``N``, extras). The format
is specified in ``docs/capture-format.md``; this module is its reference
implementation. It reads ``nearlight-capture/1`` and ``nearlight-capture/2``
(v1 keeps its meaning) and writes v2. The generator writes captures with :func:`write_capture`, the
estimator reads them with :func:`read_capture`, and so does anything reading a
real rig's captures.

Arrays follow the physics conventions: images ``[H, W, C]`` with row 0 at the
top, float32 linear radiance; positions in metres in the world frame.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import json
import os
import re
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import UserError, disk_full, one_line
from ..files.atomic import check_not_full, write_folder
from ..files.jsonable import json_text, jsonable
from ..files.outputs import check_capture_out, is_capture_dir
from ..files.schema import all_numbers, is_number
from ..physics.reflectance import every_channel
from .targets import ID_LAYER, OBJECT, RigTarget, read_object_id, read_objects, read_rig_targets

#: The version the writer writes.
FORMAT = "nearlight-capture/2"
#: The version every v1 capture carries (read with its v1 meaning).
FORMAT_V1 = "nearlight-capture/1"
#: Every version the reader reads.
FORMATS = (FORMAT_V1, FORMAT)
JSON_NAME = "capture.json"
EXR_NAME = "capture.exr"

#: Layers whose three channels are named X, Y, Z (vectors); all others are R, G, B.
VECTOR_LAYERS = ("P", "N")
_RGB = ("R", "G", "B")
_XYZ = ("X", "Y", "Z")
_POL = re.compile(r"^pol(\d+)$")


@dataclasses.dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of a capture's images (``capture.json``'s ``camera.intrinsics``, v2), OpenCV's convention.

    A camera-frame point ``(x, y, z)`` (x right, y down, z forward, metres)
    lands at column ``fx·x/z + cx``, row ``fy·y/z + cy``, pixels, with pixel
    ``(0, 0)``'s centre at ``(0, 0)`` and row 0 at the top (nearlight's image
    coordinates put that centre at ``(0.5, 0.5)``). The images are undistorted:
    a rig's lens distortion is undone before a capture is written.

    Attributes
    ----------
    fx, fy : float
        Focal lengths, pixels (> 0).
    cx, cy : float
        Principal point, pixels.
    """

    fx: float
    fy: float
    cx: float
    cy: float


@dataclasses.dataclass(frozen=True)
class Sensor:
    """The camera's noise model (``capture.json``'s ``sensor``, v2), when known: Poisson–Gaussian per pixel.

    A pixel of radiance ``L`` collects ``L / saturation · full_well`` electrons
    on average (Poisson), plus Gaussian read noise of ``read_noise`` electrons
    rms, clipped to the full well and read by a ``bits``-bit ADC over it; so
    its variance in radiance units is about ``(saturation / full_well)² ·
    (L / saturation · full_well + read_noise²)`` below saturation, plus the
    ADC's step² / 12 (step ``saturation / (2^bits − 1)``). The generator's
    model (:mod:`nearlight.generator.noise`) and its field names.

    Attributes
    ----------
    saturation : float
        Radiance (the capture's image units) that fills the full well, > 0.
    full_well : float
        Electrons at saturation, > 0.
    read_noise : float
        Read noise, electrons rms, ≥ 0.
    bits : int
        ADC bits, 1 to 32.
    """

    saturation: float
    full_well: float
    read_noise: float
    bits: int


#: The keys of ``capture.json``'s ``sensor``, in order (all required when the section is present).
SENSOR_KEYS = ("saturation", "full_well", "read_noise", "bits")


@dataclasses.dataclass(frozen=True)
class Camera:
    """Pinhole camera of a capture.

    Attributes
    ----------
    position : ndarray, shape (3,)
        Centre of projection in world coordinates, metres.
    to_world : ndarray, shape (4, 4) or None
        Camera-to-world transform, row-major, as the writer defines it (the
        generator writes Mitsuba's: the camera looks along its local +z);
        optional.
    fov_x_deg : float or None
        Horizontal field of view, degrees; optional.
    intrinsics : Intrinsics or None
        Pinhole intrinsics in OpenCV's convention (v2, optional): what a
        calibrated rig knows; for any camera whose principal point is not the
        image centre or whose pixels are not square.
    """

    position: np.ndarray
    to_world: np.ndarray | None = None
    fov_x_deg: float | None = None
    intrinsics: Intrinsics | None = None


@dataclasses.dataclass(frozen=True)
class LampFilter:
    """The lamps' linear polarizer filters as a rig knows them (``rig.lamp_filter``, v2): one for all lamps.

    Attributes
    ----------
    axis : tuple of float, shape (3,)
        The filter's axis, world (any length; projected into the filter's plane).
    aim : tuple of float, shape (3,)
        The point every filter faces (world, m): its normal runs from the lamp to it.
    """

    axis: tuple[float, float, float]
    aim: tuple[float, float, float]


#: ``rig.range.axis``: the distance along each camera ray, or the depth along the optical axis.
RANGE_AXES = ("ray", "z")
#: ``rig.range.source``: where the range came from.
RANGE_SOURCES = ("depth-map", "light-stripe", "time-of-flight", "mesh", "renderer", "unknown")
#: The keys of ``capture.json``'s ``rig.range``, in order.
RANGE_KEYS = ("sigma_m", "quantum_m", "axis", "source")


@dataclasses.dataclass(frozen=True)
class RangeSensor:
    """The range sensor's error as a rig states it (``rig.range``, v2): Gaussian noise and quantisation.

    Attributes
    ----------
    sigma_m : float
        Standard deviation of the Gaussian range noise, metres, >= 0.
    quantum_m : float
        Step of the depth's quantisation, metres, >= 0 (0: not quantised).
    axis : {"ray", "z"}
        Along what the noise and the steps are: ``"ray"``, the distance along
        each camera ray (a light stripe, time of flight, the generator), or
        ``"z"``, the depth along the optical axis (what a depth map stores).
    source : {"depth-map", "light-stripe", "time-of-flight", "mesh", "renderer", "unknown"}
        Where the range came from.
    """

    sigma_m: float = 0.0
    quantum_m: float = 0.0
    axis: str = "ray"
    source: str = "unknown"


@dataclasses.dataclass(frozen=True)
class Rig:
    """What a rig knows about itself by calibration (``capture.json``'s ``rig``, v2); estimators may use it.

    The defaults are v1's ideal rig.

    Attributes
    ----------
    lamps : int
        Number of lamps lit in the capture.
    analyzer_extinction_ratio : float or None
        Extinction ratio ε ≥ 1 of the camera's analyzer (``k1/k2`` of its
        principal intensity transmittances, ``k1 = 1``); None: ideal.
    lamp_polarizer_extinction_ratio : float or None
        The same for the lamp's polarizer; None: ideal.
    lamp_filter : LampFilter or None
        Every lamp's filter, when the rig knows it; None: unknown. With
        several lamps it lets an estimator predict each lamp's polarization
        angle (``rig.lamp_filter``).
    range : RangeSensor or None
        The range sensor's error (``rig.range``); None: not stated, and
        estimators then measure it from ``P``.
    targets : tuple of RigTarget
        The calibration targets in the scene as the rig knows them (``rig.targets``,
        :mod:`nearlight.capture.targets`); empty: none.
    other : dict
        Every other key of ``rig`` (kept on a round trip).
    """

    lamps: int = 1
    analyzer_extinction_ratio: float | None = None
    lamp_polarizer_extinction_ratio: float | None = None
    lamp_filter: LampFilter | None = None
    range: RangeSensor | None = None
    targets: tuple[RigTarget, ...] = ()
    other: dict[str, Any] = dataclasses.field(default_factory=dict)


@dataclasses.dataclass(frozen=True, eq=False)
class Capture:
    """One capture: what a polarization rig with a range finder records.

    Attributes
    ----------
    width, height : int
        Image size in pixels.
    camera : Camera
    P : ndarray, shape (H, W, 3)
        World position of the surface seen by each pixel, metres; NaN where no
        surface (background).
    N : ndarray, shape (H, W, 3) or None
        Unit surface normals, when the capture has them.
    stack : ndarray, shape (K, H, W, 3) or None
        Radiance through an ideal analyzer at ``analyzer_angles_deg[k]``.
    analyzer_angles_deg : ndarray, shape (K,) or None
        Analyzer angles, degrees, as the rig defines them (the generator
        measures them from the image's horizontal axis, Mitsuba's Stokes x
        axis). Separation only needs their differences.
    specular, diffuse : ndarray, shape (H, W, 3) or None
        Already separated specular / diffuse radiance (the paper's own input).
    lamp_polarizer_axis : ndarray, shape (3,) or None
        World-space axis of the lamp's linear polarizer.
    truth : dict or None
        Ground truth (lamp position, intensity, BSDF; in v2 also ``lamps``,
        ``camera``, ``nuisances``). Estimators must never read it; it is here
        for the evaluation.
    rig : Rig
        What the rig knows about itself by calibration (v2); estimators may
        read it. ``Rig()`` (ideal) for v1 captures.
    sensor : Sensor or None
        The camera's noise model (v2 ``sensor``), when known; estimators may
        read it to weigh pixels by their variance. None: unknown (and for v1).
    object_id : ndarray of int32, shape (H, W), or None
        Which object each pixel sees: 0 nothing, ``i + 1`` ``objects[i]``
        (:mod:`nearlight.capture.targets`); None: every surface pixel is the object's.
    objects : tuple of str
        The names of the ids (``"object"``, ``"targets.<k>"``, ``"lamp"``...); empty without ``object_id``.
    extra : dict of str to ndarray
        Every other EXR layer: ``[H, W, 3]`` for three-channel layers
        (``truth_specular``, ``S0``...), ``[H, W]`` for single channels
        (``mask``).
    meta : dict
        Every other key of ``capture.json`` (kept on a round trip).
    source : Path or None
        The directory this capture was read from.
    """

    width: int
    height: int
    camera: Camera
    P: np.ndarray
    N: np.ndarray | None = None
    stack: np.ndarray | None = None
    analyzer_angles_deg: np.ndarray | None = None
    specular: np.ndarray | None = None
    diffuse: np.ndarray | None = None
    lamp_polarizer_axis: np.ndarray | None = None
    truth: dict | None = None
    rig: Rig = dataclasses.field(default_factory=Rig)
    sensor: Sensor | None = None
    object_id: np.ndarray | None = None
    objects: tuple[str, ...] = ()
    extra: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)
    meta: dict[str, Any] = dataclasses.field(default_factory=dict)
    source: Path | None = None

    @property
    def surface_mask(self) -> np.ndarray:
        """``[H, W]`` bool: pixels that see a surface (finite ``P``)."""
        return every_channel(np.isfinite(self.P))

    @property
    def object_mask(self) -> np.ndarray:
        """``[H, W]`` bool: pixels that see the object under study (the surface mask when the capture has no
        ``object_id``)."""
        if self.object_id is None:
            return self.surface_mask
        return self.object_id == self.objects.index(OBJECT) + 1

    def of_object(self) -> Capture:
        """The capture as an estimator of the object sees it: pixels of anything else (a calibration target, a
        lamp seen directly) have no range (``P``, ``N`` NaN) and no radiance (0), as the background has none, so
        no method fits them. The capture itself when it has no ``object_id``.

        Why 0 and not NaN: the estimators' image statistics (the noise level, the separation) are written for
        finite images, and a pixel without range is never fitted; where such pixels are enclosed by the object
        the range-hole filling (:func:`nearlight.estimator.geometry.enclosed_holes`) gives them a surface point
        with no light, which no fit reads as a measurement (measured on the TS board with two mirror balls and a
        card: ``full``'s lamp moved by < 1e-6 m against the render without them when their pixels are cut; NaN
        radiance moved it by 3 cm).
        """
        if self.object_id is None:
            return self
        other = (self.object_id != 0) & ~self.object_mask
        if not other.any():
            return self

        def cut(img: np.ndarray | None, value: float) -> np.ndarray | None:
            return None if img is None else np.where(other[..., None], np.float32(value), img)

        return self.replace(P=cut(self.P, np.nan), N=cut(self.N, np.nan), specular=cut(self.specular, 0.0),
                            diffuse=cut(self.diffuse, 0.0),
                            stack=None if self.stack is None else np.stack([cut(img, 0.0) for img in self.stack]))

    @property
    def name(self) -> str:
        """Human name for messages: the source directory, or ``<capture>``."""
        return str(self.source) if self.source is not None else "<capture>"

    def replace(self, **changes: Any) -> Capture:
        """A copy with some fields replaced (arrays are not copied)."""
        return dataclasses.replace(self, **changes)


# --------------------------------------------------------------------------- reading


def read_capture(path: str | os.PathLike) -> Capture:
    """Read a capture directory (or its ``capture.json``).

    Parameters
    ----------
    path : path-like
        The capture directory, or the ``capture.json`` inside it.

    Returns
    -------
    Capture

    Raises
    ------
    UserError
        With a one-line message naming the file, key or channel, when the
        capture is not valid format v1 or v2.
    """
    path = Path(path)
    folder = path.parent if path.name == JSON_NAME else path
    json_path, exr_path = folder / JSON_NAME, folder / EXR_NAME
    if not folder.is_dir():
        raise UserError(f"{folder}: not a capture directory (expected a folder with {JSON_NAME} and {EXR_NAME})")
    if not json_path.is_file():
        raise UserError(f"{json_path}: missing (a capture directory holds {JSON_NAME} and {EXR_NAME})")
    try:
        doc = json.loads(json_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise UserError(f"{json_path}: not valid JSON ({exc})") from None
    if not isinstance(doc, dict) or doc.get("format") not in FORMATS:
        got = doc.get("format") if isinstance(doc, dict) else type(doc).__name__
        want = " or ".join(repr(f) for f in FORMATS)
        raise UserError(f"{json_path}: format: expected {want}, got {got!r}")
    v2 = doc["format"] == FORMAT
    meta = dict(doc)

    def take(key: str, required: bool = False) -> Any:
        if key not in meta and required:
            raise UserError(f"{json_path}: {key}: missing")
        return meta.pop(key, None)

    take("format")
    units = take("units")
    if units not in (None, "m"):
        raise UserError(f"{json_path}: units: expected 'm', got {units!r}")
    width = _positive_int(take("width", True), json_path, "width")
    height = _positive_int(take("height", True), json_path, "height")
    cam = take("camera", True)
    if not isinstance(cam, dict):
        raise UserError(f"{json_path}: camera: expected an object")
    position = _vector(cam.get("position"), json_path, "camera.position", (3,))
    to_world = cam.get("to_world")
    to_world = None if to_world is None else _vector(to_world, json_path, "camera.to_world", (4, 4))
    fov = cam.get("fov_x_deg")
    if fov is not None and not (is_number(fov) and 0 < fov < 180):
        raise UserError(f"{json_path}: camera.fov_x_deg: expected a number in (0, 180), got {fov!r}")
    intrinsics = _intrinsics(cam.get("intrinsics"), json_path) if v2 else None
    angles = take("analyzer_angles_deg")
    if angles is not None:
        angles = _vector(angles, json_path, "analyzer_angles_deg", None)
        if angles.ndim != 1 or angles.size == 0:
            raise UserError(f"{json_path}: analyzer_angles_deg: expected a non-empty list of numbers")
    axis = take("lamp_polarizer_axis")
    axis = None if axis is None else _vector(axis, json_path, "lamp_polarizer_axis", (3,))
    truth = take("truth")
    rig, sensor, objects = Rig(), None, ()
    if v2:
        rig = _rig(take("rig"), json_path)
        sensor = _sensor(take("sensor"), json_path)
        objects = read_objects(take("objects"), json_path)
        _check_truth_v2(truth, json_path, rig)

    if not exr_path.is_file():
        raise UserError(f"{exr_path}: missing (a capture directory holds {JSON_NAME} and {EXR_NAME})")
    layers = _read_layers(exr_path, height, width)

    def layer(name: str, names: tuple[str, ...]) -> np.ndarray | None:
        chans = layers.pop(name, None)
        if chans is None:
            return None
        missing = [c for c in names if c not in chans]
        if missing:
            raise UserError(f"{exr_path}: channel {name}.{missing[0]} missing (layer {name} needs {'/'.join(names)})")
        return np.stack([chans[c] for c in names], axis=-1)

    P = layer("P", _XYZ)
    if P is None:
        raise UserError(f"{exr_path}: channels P.X, P.Y, P.Z missing (the range image is required)")
    N = layer("N", _XYZ)
    pol_idx = sorted(int(m.group(1)) for name in layers if (m := _POL.match(name)))
    stack = None
    if pol_idx:
        if angles is None:
            raise UserError(f"{json_path}: analyzer_angles_deg missing but {exr_path.name} has pol<k> channels")
        if pol_idx != list(range(len(angles))):
            want = ", ".join(f"pol{k}" for k in range(len(angles)))
            raise UserError(
                f"{exr_path}: analyzer layers {', '.join(f'pol{k}' for k in pol_idx)} do not match "
                f"analyzer_angles_deg ({len(angles)} angles: expected {want})"
            )
        stack = np.stack([layer(f"pol{k}", _RGB) for k in pol_idx])
    elif angles is not None and "specular" not in layers:
        raise UserError(f"{exr_path}: channel pol0.R missing (analyzer_angles_deg lists {len(angles)} angles)")
    specular = layer("specular", _RGB)
    diffuse = layer("diffuse", _RGB)
    if stack is None and specular is None:
        raise UserError(f"{exr_path}: no image: expected pol<k>.R/G/B channels or specular.R/G/B")

    ids = layers.pop(ID_LAYER, None)
    if ids is not None and set(ids) != {""}:
        raise UserError(f"{exr_path}: layer {ID_LAYER}: expected one channel named {ID_LAYER}, got "
                        f"{', '.join(f'{ID_LAYER}.{c}' for c in ids)}")  # fmt: skip
    object_id = read_object_id(None if ids is None else ids[""], objects, exr_path)
    mask = every_channel(np.isfinite(P))
    if not mask.any():
        raise UserError(f"{exr_path}: channel P.X: no finite position (no surface in the range image)")
    for name, img in (("N", N), ("specular", specular), ("diffuse", diffuse)):
        if img is not None and not np.all(np.isfinite(img[mask])):
            raise UserError(f"{exr_path}: channel {name}: NaN or Inf at surface pixels")
    if stack is not None:
        bad = [k for k in range(len(stack)) if not np.all(np.isfinite(stack[k][mask]))]
        if bad:
            raise UserError(f"{exr_path}: channel pol{bad[0]}: NaN or Inf at surface pixels")

    extra: dict[str, np.ndarray] = {}
    for name, chans in layers.items():
        if set(chans) == {""}:
            extra[name] = chans[""]
        elif set(_RGB) <= set(chans):
            extra[name] = np.stack([chans[c] for c in _RGB], axis=-1)
        elif set(_XYZ) <= set(chans):
            extra[name] = np.stack([chans[c] for c in _XYZ], axis=-1)
        else:
            for c, arr in chans.items():
                extra[f"{name}.{c}"] = arr

    return Capture(
        width=width,
        height=height,
        camera=Camera(position=position, to_world=to_world, fov_x_deg=None if fov is None else float(fov),
                      intrinsics=intrinsics),
        P=P,
        N=N,
        stack=stack,
        analyzer_angles_deg=angles,
        specular=specular,
        diffuse=diffuse,
        lamp_polarizer_axis=axis,
        truth=truth,
        rig=rig,
        sensor=sensor,
        object_id=object_id,
        objects=objects,
        extra=extra,
        meta=meta,
        source=folder,
    )


def _read_layers(exr_path: Path, height: int, width: int) -> dict[str, dict[str, np.ndarray]]:
    """``{layer: {channel suffix: [H, W] float32}}``; suffix ``""`` for undotted names."""
    import OpenEXR

    with _quiet_fds() as chatter:
        try:
            # The header first: a data window other than capture.json's size is refused
            # before OpenEXR allocates its pixels (a damaged header can claim any size).
            with OpenEXR.File(str(exr_path), header_only=True) as f:
                header = f.header()  # read inside: closing the file empties it
                (x0, y0), (x1, y1) = (np.asarray(v).tolist() for v in header["dataWindow"])
                first = next((str(c.name) for c in header.get("channels", [])), "*")
            w, h = int(x1) - int(x0) + 1, int(y1) - int(y0) + 1
            if (w, h) != (width, height):
                raise UserError(
                    f"{exr_path}: channel {first}: shape {h}x{w} does not match capture.json's {height}x{width} "
                    "(height x width)"
                )
            with OpenEXR.File(str(exr_path), separate_channels=True) as f:
                channels = {name: ch.pixels for name, ch in f.channels().items()}
            error = None
        except UserError:
            raise
        except Exception as exc:  # OpenEXR raises bare RuntimeError/Exception on corrupt files
            error = exc
    said = [line.replace(f"{exr_path}: ", "") for line in chatter if line.strip()]
    if error is not None or said:
        # OpenEXR's own messages (written straight to the terminal by its C++ core) say more
        # than its exception: the first one becomes the reason.
        reason = said[0] if said else str(error)
        raise UserError(f"{exr_path}: not a readable OpenEXR file (damaged or truncated: {reason})")
    layers: dict[str, dict[str, np.ndarray]] = {}
    for name, pix in channels.items():
        if pix.shape != (height, width):
            raise UserError(
                f"{exr_path}: channel {name}: shape {pix.shape[0]}x{pix.shape[1]} does not match "
                f"capture.json's {height}x{width} (height x width)"
            )
        if pix.dtype.kind not in "f":
            raise UserError(f"{exr_path}: channel {name}: expected FLOAT or HALF, got {pix.dtype}")
        base, _, suffix = name.rpartition(".") if "." in name else (name, "", "")
        layers.setdefault(base, {})[suffix] = pix.astype(np.float32, copy=False)
    return layers


@contextlib.contextmanager
def _quiet_fds() -> Iterator[list[str]]:
    """Send what C/C++ code writes to file descriptors 1 and 2 to a list of lines instead of the terminal.

    OpenEXR reports damaged files on stderr/stdout itself, beside its exception;
    nearlight's one error line must be all the user sees.
    """
    lines: list[str] = []
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError, AttributeError):
            pass
    try:
        saved = [os.dup(1), os.dup(2)]
    except OSError:  # no such descriptors (embedded): nothing to hide
        yield lines
        return
    with tempfile.TemporaryFile() as sink:
        try:
            os.dup2(sink.fileno(), 1)
            os.dup2(sink.fileno(), 2)
            yield lines
        finally:
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved:
                os.close(fd)
            sink.seek(0)
            lines.extend(sink.read(1 << 16).decode("utf-8", errors="replace").splitlines())


def _ratio(x: Any, where: Path, key: str) -> float | None:
    """An extinction ratio: a number >= 1, or None (ideal)."""
    if x is None:
        return None
    if not (is_number(x) and x >= 1):
        raise UserError(f"{where}: {key}: expected a number >= 1 or null, got {x!r}")
    return float(x)


def _rig(x: Any, where: Path) -> Rig:
    """``rig`` of a v2 ``capture.json`` (absent: the ideal rig)."""
    if x is None:
        return Rig()
    if not isinstance(x, dict):
        raise UserError(f"{where}: rig: expected an object, got {x!r}")
    other = dict(x)
    lamps = other.pop("lamps", 1)
    if not (isinstance(lamps, int) and not isinstance(lamps, bool) and lamps > 0):
        raise UserError(f"{where}: rig.lamps: expected a positive integer, got {lamps!r}")
    return Rig(
        lamps=lamps,
        analyzer_extinction_ratio=_ratio(
            other.pop("analyzer_extinction_ratio", None), where, "rig.analyzer_extinction_ratio"
        ),
        lamp_polarizer_extinction_ratio=_ratio(
            other.pop("lamp_polarizer_extinction_ratio", None), where, "rig.lamp_polarizer_extinction_ratio"
        ),
        lamp_filter=_lamp_filter(other.pop("lamp_filter", None), where),
        range=_range_sensor(other.pop("range", None), where),
        targets=read_rig_targets(other.pop("targets", None), where),
        other=other,
    )


def _lamp_filter(x: Any, where: Path) -> LampFilter | None:
    """``rig.lamp_filter`` of a v2 ``capture.json``: ``{axis, aim}``, two world 3-vectors (absent or null: None)."""
    if x is None:
        return None
    if not (isinstance(x, dict) and set(x) == {"axis", "aim"}):
        raise UserError(f"{where}: rig.lamp_filter: expected an object {{axis, aim}}, got {x!r}")
    out = {}
    for key in ("axis", "aim"):
        v = x[key]
        if not (isinstance(v, list) and len(v) == 3 and all(is_number(c) for c in v)):
            raise UserError(f"{where}: rig.lamp_filter.{key}: expected 3 numbers (world), got {v!r}")
        out[key] = tuple(float(c) for c in v)
    if not np.linalg.norm(out["axis"]) > 0:
        raise UserError(f"{where}: rig.lamp_filter.axis: expected a nonzero vector, got {x['axis']!r}")
    return LampFilter(**out)


def _range_sensor(x: Any, where: Path) -> RangeSensor | None:
    """``rig.range`` of a v2 ``capture.json``: ``{sigma_m, quantum_m, axis[, source]}`` (absent or null: None)."""
    if x is None:
        return None
    if not isinstance(x, dict):
        raise UserError(f"{where}: rig.range: expected an object {{{', '.join(RANGE_KEYS)}}}, got {x!r}")
    unknown = [k for k in x if k not in RANGE_KEYS]
    if unknown:
        raise UserError(f"{where}: rig.range.{unknown[0]}: unknown key (expected {', '.join(RANGE_KEYS)})")
    for key in ("sigma_m", "quantum_m"):
        if key not in x:
            raise UserError(f"{where}: rig.range.{key}: missing (expected a number >= 0, metres)")
        if not (is_number(x[key]) and x[key] >= 0):
            raise UserError(f"{where}: rig.range.{key}: expected a number >= 0 (metres), got {x[key]!r}")
    axis = x.get("axis")
    if not (isinstance(axis, str) and axis in RANGE_AXES):
        raise UserError(f"{where}: rig.range.axis: expected \"ray\" or \"z\", got {axis!r}")
    source = x.get("source", "unknown")
    if not (isinstance(source, str) and source in RANGE_SOURCES):
        raise UserError(f"{where}: rig.range.source: expected one of {', '.join(RANGE_SOURCES)}, got {source!r}")
    return RangeSensor(sigma_m=float(x["sigma_m"]), quantum_m=float(x["quantum_m"]), axis=axis, source=source)


def _intrinsics(x: Any, where: Path) -> Intrinsics | None:
    """``camera.intrinsics`` of a v2 ``capture.json`` (absent or null: None)."""
    if x is None:
        return None
    if not isinstance(x, dict):
        raise UserError(f"{where}: camera.intrinsics: expected an object {{fx, fy, cx, cy}}, got {x!r}")
    values = {}
    for key in ("fx", "fy", "cx", "cy"):
        v = x.get(key)
        if not is_number(v) or (key in ("fx", "fy") and v <= 0):
            want = "a number > 0" if key in ("fx", "fy") else "a number"
            raise UserError(f"{where}: camera.intrinsics.{key}: expected {want}, got {v!r}")
        values[key] = float(v)
    return Intrinsics(**values)


def _sensor(x: Any, where: Path) -> Sensor | None:
    """``sensor`` of a v2 ``capture.json`` (absent or null: None, the noise model unknown)."""
    if x is None:
        return None
    if not isinstance(x, dict):
        raise UserError(f"{where}: sensor: expected an object {{{', '.join(SENSOR_KEYS)}}}, got {x!r}")
    unknown = sorted(set(x) - set(SENSOR_KEYS))
    if unknown:
        raise UserError(f"{where}: sensor.{unknown[0]}: unknown key (expected {', '.join(SENSOR_KEYS)})")
    for key in ("saturation", "full_well"):
        if not (is_number(x.get(key)) and x[key] > 0):
            raise UserError(f"{where}: sensor.{key}: expected a number > 0, got {x.get(key)!r}")
    if not (is_number(x.get("read_noise")) and x["read_noise"] >= 0):
        raise UserError(f"{where}: sensor.read_noise: expected a number >= 0, got {x.get('read_noise')!r}")
    bits = x.get("bits")
    if not (isinstance(bits, int) and not isinstance(bits, bool) and 1 <= bits <= 32):
        raise UserError(f"{where}: sensor.bits: expected an integer from 1 to 32, got {bits!r}")
    return Sensor(saturation=float(x["saturation"]), full_well=float(x["full_well"]),
                  read_noise=float(x["read_noise"]), bits=bits)  # fmt: skip


def _check_truth_v2(truth: Any, where: Path, rig: Rig | None = None) -> None:
    """Check the v2 keys of ``truth`` (``lamps``, ``camera``, ``nuisances``); v1's keys keep v1's (no) checks.

    With several lamps, ``truth.lamps`` must have as many as ``rig.lamps`` and there is no one lamp for v1's
    ``lamp_position`` and ``lamp_intensity`` to be: either of them is an error, so that single-lamp scoring fails
    loudly instead of grading against one of the lamps.
    """
    if truth is None:
        return
    if not isinstance(truth, dict):
        raise UserError(f"{where}: truth: expected an object, got {type(truth).__name__}")
    lamps = truth.get("lamps")
    if lamps is not None:
        if not isinstance(lamps, list) or not lamps:
            raise UserError(f"{where}: truth.lamps: expected a non-empty list of lamps, got {lamps!r}")
        for i, lamp in enumerate(lamps):
            key = f"truth.lamps[{i}]"
            if not isinstance(lamp, dict):
                raise UserError(f"{where}: {key}: expected an object, got {lamp!r}")
            _vector(lamp.get("position"), where, f"{key}.position", (3,))
            for name in ("intensity", "polarizer_axis"):
                if lamp.get(name) is not None:
                    _vector(lamp[name], where, f"{key}.{name}", (3,))
            if lamp.get("intensity") is not None and min(lamp["intensity"]) < 0:
                raise UserError(f"{where}: {key}.intensity: expected 3 numbers >= 0, got {lamp['intensity']!r}")
            radius = lamp.get("radius_m", 0.0)
            if not (is_number(radius) and radius >= 0):
                raise UserError(f"{where}: {key}.radius_m: expected a number >= 0, got {radius!r}")
            _ratio(lamp.get("polarizer_extinction_ratio"), where, f"{key}.polarizer_extinction_ratio")
            aniso = lamp.get("anisotropy")
            if aniso is not None:
                if not isinstance(aniso, dict):
                    raise UserError(f"{where}: {key}.anisotropy: expected null or an object {{k, axis}}, got {aniso!r}")
                if not (is_number(aniso.get("k")) and aniso["k"] >= 0):
                    raise UserError(f"{where}: {key}.anisotropy.k: expected a number >= 0, got {aniso.get('k')!r}")
                axis = _vector(aniso.get("axis"), where, f"{key}.anisotropy.axis", (3,))
                if not np.linalg.norm(axis) > 0:
                    raise UserError(f"{where}: {key}.anisotropy.axis: expected a non-zero vector, got {aniso['axis']!r}")
        if rig is not None and rig.lamps != len(lamps):
            raise UserError(
                f"{where}: truth.lamps: lists {len(lamps)} lamp{'s' * (len(lamps) > 1)}, rig.lamps says {rig.lamps} "
                "(absent: 1)"
            )
        if len(lamps) > 1:
            for v1_key in ("lamp_position", "lamp_intensity"):
                if v1_key in truth:
                    raise UserError(
                        f"{where}: truth.{v1_key}: a capture with {len(lamps)} lamps has no single lamp; "
                        "each lamp is in truth.lamps"
                    )
    cam = truth.get("camera")
    if cam is not None:
        if not isinstance(cam, dict):
            raise UserError(f"{where}: truth.camera: expected an object, got {cam!r}")
        _vector(cam.get("position"), where, "truth.camera.position", (3,))
        if cam.get("to_world") is not None:
            _vector(cam["to_world"], where, "truth.camera.to_world", (4, 4))
        fov = cam.get("fov_x_deg")
        if fov is not None and not (is_number(fov) and 0 < fov < 180):
            raise UserError(f"{where}: truth.camera.fov_x_deg: expected a number in (0, 180), got {fov!r}")
    nuisances = truth.get("nuisances")
    if nuisances is not None and not isinstance(nuisances, dict):
        raise UserError(f"{where}: truth.nuisances: expected an object, got {nuisances!r}")


def _positive_int(x: Any, where: Path, key: str) -> int:
    if not (isinstance(x, int) and not isinstance(x, bool) and x > 0):
        raise UserError(f"{where}: {key}: expected a positive integer, got {x!r}")
    return x


def _vector(x: Any, where: Path, key: str, shape: tuple[int, ...] | None) -> np.ndarray:
    try:
        arr = np.asarray(x, dtype=float) if all_numbers(x) else None
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.dtype == object or not np.all(np.isfinite(arr)) or (shape is not None and arr.shape != shape):
        want = "a list of numbers" if shape is None else ("3 numbers" if shape == (3,) else f"numbers of shape {shape}")
        raise UserError(f"{where}: {key}: expected {want}, got {x!r}")
    return arr


# --------------------------------------------------------------------------- writing


def write_capture(capture: Capture, path: str | os.PathLike, *, overwrite: bool = False) -> Path:
    """Write ``capture`` as a capture directory, atomically.

    Both files are written into a temporary sibling directory
    (``.<name>.<random>.partial``) which is renamed into place only when
    complete, so an interrupted write never leaves a directory that looks like
    a finished capture.

    Parameters
    ----------
    capture : Capture
    path : path-like
        The capture directory to create.
    overwrite : bool, optional
        Replace an existing capture directory at ``path``. Only a capture
        (:func:`nearlight.files.outputs.is_capture_dir`: exactly ``capture.json``
        and ``capture.exr``) is ever replaced; anything else at ``path`` is
        refused and left untouched.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    UserError
        When ``path`` exists (and ``overwrite`` is false, or it is not a
        capture) or cannot be written.
    """
    import OpenEXR

    path = check_capture_out(path, overwrite=overwrite)

    def fill(tmp: Path) -> None:
        (tmp / JSON_NAME).write_text(json_text(capture_json(capture)))
        if OpenEXR.global_thread_count() == 0:
            # OpenEXR compresses on the calling thread by default; its pool of one
            # thread per core writes a 640x480 capture in 0.26 s instead of 0.39 s.
            OpenEXR.set_global_thread_count(os.cpu_count() or 1)
        header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
        try:
            OpenEXR.File(header, _channels(capture)).write(str(tmp / EXR_NAME))
        except RuntimeError as exc:  # OpenEXR's I/O errors (a full disk: "No space left on device")
            raise OSError(errno.ENOSPC if disk_full(exc) else errno.EIO, one_line(exc)) from None
        check_not_full(tmp / EXR_NAME)

    # Checked again at the last moment: only a capture is ever replaced.
    return write_folder(path, fill, existing=lambda p: is_capture_dir(p) or check_capture_out(p, overwrite=overwrite))


def capture_json(capture: Capture) -> dict[str, Any]:
    """The ``capture.json`` document of ``capture`` (a JSON-ready dict)."""
    cam: dict[str, Any] = {"position": _list(capture.camera.position)}
    if capture.camera.to_world is not None:
        cam["to_world"] = _list(capture.camera.to_world)
    if capture.camera.fov_x_deg is not None:
        cam["fov_x_deg"] = float(capture.camera.fov_x_deg)
    if capture.camera.intrinsics is not None:
        cam["intrinsics"] = {k: float(v) for k, v in dataclasses.asdict(capture.camera.intrinsics).items()}
    doc: dict[str, Any] = {
        "format": FORMAT,
        "units": "m",
        "width": int(capture.width),
        "height": int(capture.height),
        "camera": cam,
    }
    if capture.analyzer_angles_deg is not None:
        doc["analyzer_angles_deg"] = _list(capture.analyzer_angles_deg)
    if capture.lamp_polarizer_axis is not None:
        doc["lamp_polarizer_axis"] = _list(capture.lamp_polarizer_axis)
    rig = capture.rig
    doc["rig"] = {"lamps": int(rig.lamps)}
    for key in ("analyzer_extinction_ratio", "lamp_polarizer_extinction_ratio"):
        if getattr(rig, key) is not None:
            doc["rig"][key] = float(getattr(rig, key))
    if rig.lamp_filter is not None:
        doc["rig"]["lamp_filter"] = {"axis": _list(rig.lamp_filter.axis), "aim": _list(rig.lamp_filter.aim)}
    if rig.range is not None:
        doc["rig"]["range"] = {"sigma_m": float(rig.range.sigma_m), "quantum_m": float(rig.range.quantum_m),
                               "axis": str(rig.range.axis), "source": str(rig.range.source)}  # fmt: skip
    if rig.targets:
        doc["rig"]["targets"] = [t.to_json() for t in rig.targets]
    for key, value in rig.other.items():
        doc["rig"].setdefault(key, jsonable(value))
    if capture.objects:
        doc["objects"] = list(capture.objects)
    if capture.sensor is not None:
        sensor = capture.sensor
        doc["sensor"] = {"saturation": float(sensor.saturation), "full_well": float(sensor.full_well),
                         "read_noise": float(sensor.read_noise), "bits": int(sensor.bits)}  # fmt: skip
    if capture.truth is not None:
        doc["truth"] = jsonable(capture.truth)
    for key, value in capture.meta.items():
        doc.setdefault(key, jsonable(value))
    return doc


def _channels(capture: Capture) -> dict[str, np.ndarray]:
    """Flat ``{channel name: [H, W] float32}`` for the EXR writer."""
    layers: dict[str, np.ndarray | None] = {"P": capture.P, "N": capture.N}
    if capture.stack is not None:
        layers.update({f"pol{k}": img for k, img in enumerate(capture.stack)})
    layers.update(specular=capture.specular, diffuse=capture.diffuse)
    if capture.object_id is not None:
        layers[ID_LAYER] = capture.object_id
    layers.update(capture.extra)
    out: dict[str, np.ndarray] = {}
    shape = (capture.height, capture.width)
    for name, arr in layers.items():
        if arr is None:
            continue
        arr = np.asarray(arr, dtype=np.float32)
        if arr.shape == shape:
            out[name] = np.ascontiguousarray(arr)
        elif arr.shape == (*shape, 3):
            names = _XYZ if name in VECTOR_LAYERS else _RGB
            for i, c in enumerate(names):
                out[f"{name}.{c}"] = np.ascontiguousarray(arr[..., i])
        else:
            raise ValueError(f"layer {name}: shape {arr.shape}, expected {shape} or {(*shape, 3)}")
    return out


def _list(a: Any) -> Any:
    return np.asarray(a, dtype=float).tolist()
