"""Rig files to a capture: demosaic, linearise, merge exposures, undistort, and place the depth map's points.

The steps, in order (``docs/rig-files.md``):

1. each shot's frame(s) read as stored; a file whose ``row0`` is ``bottom`` is
   flipped to row 0 at the top, and the angles (a mosaic pattern's, or
   ``angles_deg``), given as stored, negated with it (a flip mirrors the
   image: counter-clockwise becomes clockwise); angles are kept modulo 180°;
2. a mosaic demosaiced by polanalyser (bilinear, ``COLOR_PolarMono`` /
   ``COLOR_PolarRGB``) on its stored digital numbers (uint16 as the sensor gave
   them; float frames are rescaled to uint16 by polanalyser itself);
   polanalyser's four images are the pattern's positions (1, 1), (0, 1),
   (0, 0), (1, 0) (its 0°, 45°, 90°, 135° for the IMX250 pattern), so any
   2×2 arrangement of angles is read by its positions;
3. linearised: ``v = (DN − black) / (white − black)``, the inverse response
   (:func:`nearlight.physics.camera.inverse_response`, white 1), times
   ``saturation / exposure``; several shots are merged to HDR: per pixel the
   exposure-weighted mean ``Σ t·(v/t) / Σ t`` over the shots where it is not
   saturated (no DN within 2 % of white level under the demosaicing kernel),
   the shortest shot where all are;
4. undistorted with OpenCV (``cv2.undistort``, the same intrinsics kept);
5. the depth map's pixels back-projected (undistorted by ``cv2.undistortPoints``),
   moved into the camera frame (``depth.to_camera``), projected with the
   camera's intrinsics and kept by nearest pixel and nearest depth; pixels no
   point lands on are NaN (holes, format v2); then into the world by the
   camera's ``pose``. Or, when the rig file gives the object's mesh instead,
   ``P`` and ``N`` ray-cast from it through each pixel centre
   (:mod:`nearlight.rig.mesh`).

Refused on the way, one line each naming the file and key (``docs/rig-files.md``,
"What rig import refuses"): frames with NaN, too few bits or DN far above the
white level, a black capture, distortion that blacks out the image or does not
invert, and a depth map mirrored relative to the frames
(:func:`check_depth_silhouette`: the object's silhouette fits the range
clearly better flipped).

A depth map has no normals: none are written, and the estimator fits them to
``P`` (as it does for the generator's range noise). A mesh's normals are
written as ``N``, and the estimator uses them.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..capture import Camera, Capture, Intrinsics, RangeSensor, Rig, Sensor, write_capture
from ..capture.silhouette import mirrored
from ..errors import UserError
from ..files.outputs import check_capture_out
from ..physics.camera import inverse_response
from .images import read_raw
from .mesh import mesh_geometry
from .rigfile import RigFile, load_rig_file

#: A demosaiced pixel counts as saturated when a DN it was interpolated from is within this fraction of white level.
SATURATED = 0.98
#: Frames may exceed ``white_level`` by this fraction of the black-to-white span (a sensor's own DN never do).
DN_SLACK = 0.05
#: ``camera.distortion`` is refused when undistorting keeps less than this fraction of the pixels with signal.
DISTORTION_KEEP = 0.5
#: ``depth.distortion`` is refused when its undistortion, distorted again, misses the pixels by more (median, px).
DEPTH_DISTORTION_PX = 0.5
#: ... or when it scales the field (95th percentile of the undistorted points' distance from the principal point
#: over the pinhole's) outside this range: k1 = 1000 squeezes a 50° depth map to 0.15 of its field; a strong
#: pincushion (k1 = 0.3) to 0.93 at its corners; a fisheye's barrel spreads it.
DEPTH_SPREAD = (0.5, 10.0)
#: Radiance units per full well (``saturation / exposure``) a capture's float32 images hold.
SCALE_RANGE = (1e-30, 1e30)
#: When ``cv2.undistortPoints`` stops: 100 iterations, or a step below 1e-12 (normalised image coordinates).
UNDISTORT_CRITERIA = (3, 100, 1e-12)  # cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS
#: Mitsuba's camera axes (left, up, forward) from OpenCV's (right, down, forward).
CV_TO_MITSUBA = np.diag([-1.0, -1.0, 1.0, 1.0])


def import_rig(rig_path: str | os.PathLike, out: str | os.PathLike, *, overwrite: bool = False) -> Path:
    """Read a rig file and its raw files, write the capture.

    Parameters
    ----------
    rig_path : path-like
        The rig file.
    out : path-like
        The capture directory to write (:func:`nearlight.capture.write_capture`'s rules).
    overwrite : bool
        Replace a capture at ``out``.

    Returns
    -------
    Path
        ``out``.
    """
    check_capture_out(out, overwrite=overwrite)
    return write_capture(rig_capture(load_rig_file(rig_path)), out, overwrite=overwrite)


def rig_capture(rig: RigFile) -> Capture:
    """The capture a rig file describes (see the module docstring for the steps).

    Returns
    -------
    Capture
        ``stack`` ``[K, H, W, 3]`` (mono: the one channel in R, G and B), its
        ``analyzer_angles_deg``, ``P`` in the world frame (metres, NaN where no
        depth or where the mesh is missed), ``N`` (unit, facing the camera) from
        a mesh, None from a depth map, the camera with ``intrinsics``, ``pose`` as ``to_world``
        (Mitsuba's axes), ``fov_x_deg`` when the principal point is the image
        centre and pixels are square; ``sensor`` for a single shot with a known
        noise model; ``rig.range`` for an integer depth map whose rotation to
        the camera is the identity (its steps, ``depth.scale``, along ``z``).
    """
    stacks, saturated = [], []
    angles = None
    for i, shot in enumerate(rig.shots):
        scale = rig.saturation / shot.exposure
        if not SCALE_RANGE[0] <= scale <= SCALE_RANGE[1]:  # float32 radiance (and the capture's sensor) would not hold it
            raise UserError(f"{rig.path}: polarization.saturation: {rig.saturation:g} / polarization.shots[{i}].exposure "
                            f"{shot.exposure:g} = {scale:g} radiance units per full well, outside "
                            f"{SCALE_RANGE[0]:g} to {SCALE_RANGE[1]:g}")  # fmt: skip
        stack, sat, angles = _shot(rig, i)
        stacks.append(stack * scale)
        saturated.append(sat)
    stack = _merge(stacks, saturated, [s.exposure for s in rig.shots])
    _check_not_black(rig, stack, "polarization.black_level, polarization.white_level, polarization.response_gamma")
    if rig.camera.distortion:
        lit = float((stack > 0).any(axis=(0, -1)).mean())
        stack = np.stack([_undistort(img, rig) for img in stack])
        after = float((stack > 0).any(axis=(0, -1)).mean()) if np.isfinite(stack).all() else 0.0
        if after < DISTORTION_KEEP * lit:
            raise UserError(f"{rig.path}: camera.distortion: undistorting with these coefficients leaves "
                            f"{100 * after:.0f} % of the image with signal (the frames have {100 * lit:.0f} %): "
                            "check their order (OpenCV's: k1 k2 p1 p2 [k3 ...]) and their size")  # fmt: skip
    stated = None
    if rig.mesh is not None:
        P, N = mesh_geometry(rig)
    else:
        (P, stated), N = _depth_points(rig), None
    if rig.mesh is None:
        check_depth_silhouette(rig, stack, P)
    cam = rig.camera
    intrinsics = Intrinsics(fx=cam.fx, fy=cam.fy, cx=cam.cx, cy=cam.cy)
    centred = (np.isclose(cam.fx, cam.fy, rtol=1e-6) and np.isclose(cam.cx, (rig.width - 1) / 2, atol=1e-3)
               and np.isclose(cam.cy, (rig.height - 1) / 2, atol=1e-3))  # fmt: skip
    fov = float(np.degrees(2 * np.arctan(rig.width / 2 / cam.fx))) if centred else None
    sensor = None
    if rig.sensor is not None and len(rig.shots) == 1:
        # the model of the recorded DN: the full well at white level (black level subtracted)
        sensor = Sensor(saturation=rig.saturation / rig.shots[0].exposure, **rig.sensor)
    return Capture(
        width=rig.width,
        height=rig.height,
        camera=Camera(position=rig.pose[:3, 3].copy(), to_world=rig.pose @ CV_TO_MITSUBA, fov_x_deg=fov,
                      intrinsics=intrinsics),  # fmt: skip
        P=P.astype(np.float32),
        N=None if N is None else N.astype(np.float32),
        stack=stack.astype(np.float32),
        analyzer_angles_deg=np.asarray(angles, float),
        sensor=sensor,
        rig=Rig(range=stated),
        meta={"imported": {"rig_file": str(rig.path), "shots": len(rig.shots), "mosaic": rig.mosaic}},
    )


def _shot(rig: RigFile, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Shot ``i`` linearised (before ``saturation / exposure``): stack ``[K, H, W, 3]``, saturated ``[K, H, W]``, angles."""
    shot = rig.shots[i]
    key = f"polarization.shots[{i}].files"
    span = rig.white_level - rig.black_level
    if rig.mosaic is not None:
        frame = read_raw(shot.files[0], key=key, rig_file=rig.path)
        _check_shape(frame, rig, key, shot.files[0], what=f"a {rig.mosaic} mosaic frame")
        _check_dn(frame, rig, key, shot.files[0])
        pattern = rig.pattern
        if rig.camera_row0 == "bottom":
            frame, pattern = frame[::-1], -pattern[::-1]
        dn, angles = demosaic(frame, pattern, colour=rig.mosaic == "colour")
        hot = np.where(frame >= rig.black_level + SATURATED * span, 65535, 0).astype(np.uint16)
        sat = demosaic(hot, pattern, colour=rig.mosaic == "colour")[0].max(axis=-1) > 0
    else:
        imgs = []
        for f in shot.files:
            img = read_raw(f, key=key, rig_file=rig.path, channels=(1, 3))
            _check_shape(img, rig, key, f, what="an image")
            _check_dn(img, rig, key, f)
            imgs.append(img[::-1] if rig.camera_row0 == "bottom" else img)
        dn = np.stack([np.broadcast_to(np.asarray(im, float)[..., None], (*im.shape[:2], 3)) if im.ndim == 2
                       else np.asarray(im, float) for im in imgs])  # fmt: skip
        sat = (dn >= rig.black_level + SATURATED * span).any(axis=-1)
        angles = -rig.angles_deg if rig.camera_row0 == "bottom" else rig.angles_deg
    v = np.clip((np.asarray(dn, float) - rig.black_level) / span, 0.0, None)
    return inverse_response(v, rig.response_gamma, 1.0), sat, np.mod(np.asarray(angles, float), 180.0)


def demosaic(frame: np.ndarray, pattern: np.ndarray, *, colour: bool) -> tuple[np.ndarray, np.ndarray]:
    """A polarization mosaic to four analyzer images, by polanalyser's bilinear demosaicing.

    Parameters
    ----------
    frame : ndarray, shape (H, W)
        The raw frame, row 0 at the top (uint8/uint16 as the sensor gave it;
        float is rescaled to uint16 by polanalyser: a relative error of about
        1/65535 of the frame's maximum).
    pattern : ndarray, shape (2, 2)
        Micro-polarizer angles of the 2×2 super-pixel at the frame's top-left, degrees.
    colour : bool
        A colour sensor: each 2×2 polarization block is one colour, the blocks in an RGGB Bayer pattern (IMX250MYR).

    Returns
    -------
    images : ndarray, shape (4, H, W, 3), float64
        Demosaiced values (mono: the one channel in R, G and B).
    angles : ndarray, shape (4,)
        Their analyzer angles, degrees.
    """
    import polanalyser as pa

    out = pa.demosaicing(frame, pa.COLOR_PolarRGB if colour else pa.COLOR_PolarMono)
    images = np.stack([np.asarray(o, float) for o in out])
    images = images[..., ::-1] if colour else np.repeat(images[..., None], 3, axis=-1)  # OpenCV's BGR -> RGB
    # polanalyser's four images are those of the positions (1,1), (0,1), (0,0), (1,0) (checked in tests)
    angles = np.array([pattern[1, 1], pattern[0, 1], pattern[0, 0], pattern[1, 0]], float)
    return images, angles


def _merge(stacks: list[np.ndarray], saturated: list[np.ndarray], exposures: list[float]) -> np.ndarray:
    """Exposure-weighted mean of the shots' radiance where unsaturated; the shortest shot where all are saturated."""
    if len(stacks) == 1:
        return stacks[0]
    t = np.asarray(exposures, float)
    w = np.stack([(~s)[..., None] * ti for s, ti in zip(saturated, t)])  # [S, K, H, W, 1]
    total = w.sum(axis=0)
    mean = (w * np.stack(stacks)).sum(axis=0) / np.where(total > 0, total, 1.0)
    return np.where(total > 0, mean, stacks[int(np.argmin(t))])


def _undistort(img: np.ndarray, rig: RigFile) -> np.ndarray:
    import cv2

    K, dist = rig.camera.K, np.asarray(rig.camera.distortion, float)
    return np.stack([cv2.undistort(np.ascontiguousarray(img[..., c], np.float32), K, dist) for c in range(3)], axis=-1)


def _check_dn(img: np.ndarray, rig: RigFile, key: str, path: Path) -> None:
    """Refuse frame values no sensor of this rig file records: NaN/Inf, too few bits for the white level, DN far
    above it (more than :data:`DN_SLACK` of the black-to-white span)."""
    where = f"{rig.path}: {key}: {path.name}"
    if img.dtype.kind == "f" and not np.isfinite(img).all():
        r, c = np.argwhere(~np.isfinite(img).reshape(img.shape[0], img.shape[1], -1).all(axis=-1))[0]
        raise UserError(f"{where}: NaN or Inf pixel (first at row {r}, column {c}); a frame holds the sensor's DN")
    if img.dtype.kind in "ui" and rig.white_level > np.iinfo(img.dtype).max:
        bits = np.iinfo(img.dtype).bits
        raise UserError(f"{where}: an image of {bits} bits (DN up to {np.iinfo(img.dtype).max}) cannot reach "
                        f"polarization.white_level {rig.white_level:g}: check the white level or the file")  # fmt: skip
    top = float(img.max())
    if top > rig.white_level + DN_SLACK * (rig.white_level - rig.black_level):
        raise UserError(f"{where}: DN up to {top:g}, far above polarization.white_level {rig.white_level:g} (a sensor "
                        "records no DN above its full well): check the white level, or the file's bit depth")  # fmt: skip


def _check_not_black(rig: RigFile, stack: np.ndarray, keys: str) -> None:
    """Refuse a capture with no signal at all (every linearised value 0, also once stored as float32)."""
    if not (np.isfinite(stack) & (stack.astype(np.float32) > 0)).any():
        files = ", ".join(sorted({f.name for s in rig.shots for f in s.files}))
        raise UserError(f"{rig.path}: polarization: the frames ({files}) give a black capture: no pixel above "
                        f"the black level once linearised (check {keys})")  # fmt: skip


def _check_shape(img: np.ndarray, rig: RigFile, key: str, path: Path, *, what: str) -> None:
    if img.shape[:2] != (rig.height, rig.width):
        raise UserError(f"{rig.path}: {key}: {path.name}: {what} of {img.shape[0]}x{img.shape[1]} does not match "
                        f"camera.height x camera.width {rig.height}x{rig.width}")  # fmt: skip


def check_depth_silhouette(rig: RigFile, stack: np.ndarray, P: np.ndarray) -> None:
    """Refuse a depth map mirrored relative to the frames: the object's silhouette in the frames (signal) and
    in the range (valid depth) overlap clearly better with the depth flipped (:func:`nearlight.capture.silhouette.mirrored`;
    never refused: an object filling the image, a symmetric silhouette, a lit background)."""
    found = mirrored(np.nanmean(stack, axis=(0, -1)), np.isfinite(P).all(axis=-1))
    if found is not None:
        flip, best, base = found
        rows = " (its rows in the other order: flip the file, or set depth.row0)" if flip.startswith("up") else ""
        raise UserError(f"{rig.path}: depth.file: {rig.depth_file.name}: the depth map is mirrored relative to the "
                        f"image: flipped {flip}, its valid depth covers the object's silhouette in the frames "
                        f"({100 * best:.0f} % of the pixels with signal, {100 * base:.0f} % as stored); flip it {flip}{rows}")  # fmt: skip


def _check_depth_distortion(rig: RigFile, xy: np.ndarray, pixels: np.ndarray) -> None:
    """Refuse ``depth.distortion`` that does not invert over the depth map: the undistorted points, distorted
    again (``cv2.projectPoints``), must land within :data:`DEPTH_DISTORTION_PX` of their pixels (median)."""
    import cv2

    d = rig.depth
    with np.errstate(all="ignore"):
        ok = np.isfinite(xy).all(axis=1)
        back = np.full_like(pixels, np.nan)
        if ok.any():
            obj = np.concatenate([xy[ok], np.ones((int(ok.sum()), 1))], axis=1).reshape(-1, 1, 3)
            back[ok] = cv2.projectPoints(obj, np.zeros(3), np.zeros(3), d.K, np.asarray(d.distortion, float))[0].reshape(-1, 2)
        miss = np.linalg.norm(back - pixels, axis=1)
    med = float(np.median(np.where(np.isfinite(miss), miss, np.inf))) if miss.size else 0.0
    pinhole = np.hypot((pixels[:, 0] - d.cx) / d.fx, (pixels[:, 1] - d.cy) / d.fy)
    spread = (float(np.percentile(np.hypot(*xy[ok].T), 95) / max(np.percentile(pinhole[ok], 95), 1e-12))
              if ok.any() else 0.0)  # fmt: skip
    if med <= DEPTH_DISTORTION_PX and not DEPTH_SPREAD[0] <= spread <= DEPTH_SPREAD[1]:
        raise UserError(f"{rig.path}: depth.distortion: undistorting with these coefficients scales the depth map's "
                        f"field by {spread:.3g} (the 95th percentile of the distance from the principal point; a lens: "
                        f"{DEPTH_SPREAD[0]:.2g} to {DEPTH_SPREAD[1]:g}): check their order (OpenCV's: k1 k2 p1 p2 "
                        "[k3 ...]) and their size")  # fmt: skip
    if not med <= DEPTH_DISTORTION_PX:
        raise UserError(f"{rig.path}: depth.distortion: these coefficients do not invert over the depth map (its "
                        f"pixels, undistorted and distorted again, land {med:.3g} px away, median): check their "
                        "order (OpenCV's: k1 k2 p1 p2 [k3 ...]) and their size")  # fmt: skip


def _depth_points(rig: RigFile) -> tuple[np.ndarray, RangeSensor | None]:
    """``P`` ``[H, W, 3]`` in the world frame from the depth map (z along the depth sensor's axis), and what the
    capture's ``rig.range`` states: an integer file's steps (``quantum_m`` the depth scale, along ``z``) when the
    depth sensor's rotation to the camera is the identity (its ``z`` then the camera's), else None."""
    key = "depth.file"
    raw = read_raw(rig.depth_file, key=key, rig_file=rig.path)
    h, w = raw.shape
    if rig.depth_size is not None and (w, h) != rig.depth_size:
        raise UserError(f"{rig.path}: {key}: {rig.depth_file.name}: {h}x{w} does not match depth.height x "
                        f"depth.width {rig.depth_size[1]}x{rig.depth_size[0]}")  # fmt: skip
    if rig.depth_size is None and (w, h) != (rig.width, rig.height):
        raise UserError(f"{rig.path}: {key}: {rig.depth_file.name}: {h}x{w} does not match camera.height x "
                        f"camera.width {rig.height}x{rig.width} (give depth.width and depth.height for a depth "
                        "sensor of another size)")  # fmt: skip
    if rig.depth_row0 == "bottom":
        raw = raw[::-1]
    scale = rig.depth_scale
    if scale is None:
        scale = 1e-3 if raw.dtype.kind in "ui" else 1.0  # integer files: millimetres
    z = raw.astype(float) * scale
    valid = np.isfinite(z) & (z > 0)
    v, u = np.nonzero(valid)
    d = rig.depth
    if d.distortion:
        import cv2

        pts = np.stack([u, v], axis=-1).astype(np.float64).reshape(-1, 1, 2)
        # iterated to convergence (OpenCV's default stops after 5 iterations: pixels off under strong distortion)
        xy = cv2.undistortPoints(pts, d.K, np.asarray(d.distortion, float), criteria=UNDISTORT_CRITERIA).reshape(-1, 2)
        _check_depth_distortion(rig, xy, pts.reshape(-1, 2))
    else:
        xy = np.stack([(u - d.cx) / d.fx, (v - d.cy) / d.fy], axis=-1)
    X = np.concatenate([xy, np.ones((xy.shape[0], 1))], axis=1) * z[v, u][:, None]
    Xc = X @ rig.depth_to_camera[:3, :3].T + rig.depth_to_camera[:3, 3]
    c = rig.camera
    front = Xc[:, 2] > 0
    Xc = Xc[front]
    col = np.rint(c.fx * Xc[:, 0] / Xc[:, 2] + c.cx).astype(np.int64)
    row = np.rint(c.fy * Xc[:, 1] / Xc[:, 2] + c.cy).astype(np.int64)
    inside = (col >= 0) & (col < rig.width) & (row >= 0) & (row < rig.height)
    col, row, Xc = col[inside], row[inside], Xc[inside]
    order = np.argsort(-Xc[:, 2])  # far first: the nearest point written last wins its pixel
    P = np.full((rig.height, rig.width, 3), np.nan)
    P[row[order], col[order]] = Xc[order] @ rig.pose[:3, :3].T + rig.pose[:3, 3]
    if not np.isfinite(P).all(axis=-1).any():
        raise UserError(f"{rig.path}: {key}: {rig.depth_file.name}: no depth lands in the camera's image "
                        "(check depth.to_camera, the intrinsics and depth.scale)")  # fmt: skip
    stated = None
    if raw.dtype.kind in "ui" and np.allclose(rig.depth_to_camera[:3, :3], np.eye(3), atol=1e-12):
        stated = RangeSensor(quantum_m=float(scale), axis="z", source="depth-map")
    return P, stated
