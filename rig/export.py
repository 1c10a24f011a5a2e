"""The rig simulator: a capture to the raw files a polarization camera and a depth sensor would record.

Writes, into a new folder, what :mod:`nearlight.rig.importer` reads back
(``docs/rig-files.md``): a 16-bit PNG mosaic frame (``frame.png``: the IMX250
pattern, mono or colour) with the generator's camera noise
(:func:`nearlight.generator.noise.adc_counts`: shot and read noise, full well, ADC;
one home of that model), a depth map (``depth.png``, 16-bit, in units of
``depth_scale`` metres, millimetres by default; 0 = no return) seen by the
camera itself, and the rig file (``rig.yaml``) with the calibration the
capture's camera implies. The mosaic's pixels sample the capture's Stokes
images (its analyzer stack fitted by :func:`nearlight.physics.polarization.linear_stokes`)
at each micro-polarizer's angle, through an ideal analyzer; a mono sensor sees
the mean of R, G and B.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import yaml

from ..capture import Capture
from ..files.atomic import write_folder
from ..errors import UserError
from ..files.outputs import check_capture_out
from ..physics.camera import auto_saturation
from ..physics.polarization import analyzer_matrix, linear_stokes
from .images import write_exr_depth, write_png16
from .importer import CV_TO_MITSUBA
from .rigfile import IMX250_PATTERN, RIG_FORMAT

RIG_NAME, FRAME_NAME = "rig.yaml", "frame.png"
DEPTH_NAME = {"png": "depth.png", "exr": "depth.exr"}
#: Colour of each 2×2 polarization block of a colour sensor (RGGB Bayer over blocks): channel index.
_BAYER = ((0, 1), (1, 2))


def export_rig(capture: Capture, out: str | os.PathLike, *, mosaic: str = "mono", seed: int = 0,
               full_well: float = 20000.0, read_noise: float = 5.0, bits: int = 12,
               depth_scale: float = 1e-3, depth_format: str = "png") -> Path:  # fmt: skip
    """Write the raw rig files of ``capture`` into the new folder ``out``.

    Parameters
    ----------
    capture : Capture
        With an analyzer stack (at least 3 distinct angles), ``P``, and a
        camera with ``to_world`` and ``fov_x_deg`` (or ``intrinsics``).
    out : path-like
        A folder that does not exist yet; written atomically (a hidden
        ``.NAME.*.partial`` sibling renamed into place).
    mosaic : {"mono", "colour"}
    seed : int
        Camera noise seed (``noise_rngs(seed)[0]``, the generator's seed rule).
    full_well, read_noise, bits : float, float, int
        The camera's noise model (electrons, electrons rms, ADC bits);
        saturation is the generator's ``auto`` (the brightest clean mosaic
        pixel at 90 % of the full well).
    depth_scale : float
        Metres per unit of the depth PNG (1e-3: millimetres).
    depth_format : {"png", "exr"}
        ``depth.png`` (16-bit, quantised to ``depth_scale``) or ``depth.exr``
        (float32 metres, one channel ``Z``: a range finder's own precision).

    Returns
    -------
    Path
        ``out``.
    """
    from ..generator.noise import adc_counts, noise_rngs
    from ..generator.scene import NoiseSpec

    out = Path(out)
    if out.exists() or out.is_symlink():
        _already_exists(out)
    check_capture_out(out, overwrite=False)
    if capture.stack is None or capture.analyzer_angles_deg is None:
        raise UserError(f"{capture.name}: no analyzer stack (pol<k> channels): a rig export samples the analyzer "
                        "images, a separated specular image is not enough")  # fmt: skip
    if capture.camera.to_world is None or (capture.camera.fov_x_deg is None and capture.camera.intrinsics is None):
        raise UserError(f"{capture.name}: camera.to_world and camera.fov_x_deg (or camera.intrinsics) missing: "
                        "a rig export needs the camera's calibration")  # fmt: skip
    H, W = capture.height, capture.width
    if mosaic not in ("mono", "colour"):
        raise UserError(f"--mosaic: expected mono or colour, got {mosaic!r}")
    k = 2 if mosaic == "mono" else 4
    if H % k or W % k:
        raise UserError(f"{capture.name}: {W}x{H} pixels: a {mosaic} mosaic needs a width and height that are "
                        f"multiples of {k}")  # fmt: skip
    clean = mosaic_frame(capture, colour=mosaic == "colour")
    noise = NoiseSpec(full_well=full_well, read_noise=read_noise, bits=bits, saturation="auto")
    saturation = auto_saturation(clean)
    rng, _ = noise_rngs(seed)
    z_shot, z_read = rng.standard_normal(clean.shape), rng.standard_normal(clean.shape)
    dn = adc_counts(clean, z_shot, z_read, noise=noise, saturation=saturation)

    cam = capture.camera
    if cam.intrinsics is not None:
        fx, fy, cx, cy = cam.intrinsics.fx, cam.intrinsics.fy, cam.intrinsics.cx, cam.intrinsics.cy
    else:  # nearlight's pinhole: square pixels, centred (pixel centres at k + 0.5 there, k in OpenCV's)
        fx = fy = W / 2 / np.tan(np.radians(cam.fov_x_deg) / 2)
        cx, cy = W / 2 - 0.5, H / 2 - 0.5
    pose = np.asarray(cam.to_world, float) @ CV_TO_MITSUBA  # CV_TO_MITSUBA is its own inverse
    local = (capture.P - pose[:3, 3]) @ pose[:3, :3]  # camera frame, OpenCV axes
    if depth_format not in ("png", "exr"):
        raise UserError(f"--depth-format: expected png or exr, got {depth_format!r}")
    if depth_format == "exr":
        depth_scale = 1.0
    z = np.where(np.isfinite(local[..., 2]) & (local[..., 2] > 0), local[..., 2] / depth_scale, 0.0)
    if depth_format == "png" and z.max() > 65535:
        raise UserError(f"{capture.name}: depth up to {z.max() * depth_scale:.2f} m does not fit a 16-bit PNG in units "
                        f"of {depth_scale} m (--depth-scale)")  # fmt: skip
    rig = {
        "format": RIG_FORMAT,
        "camera": {"width": W, "height": H, "intrinsics": {"fx": float(fx), "fy": float(fy), "cx": float(cx),
                                                            "cy": float(cy)},
                   "pose": pose.tolist()},
        "polarization": {"mosaic": mosaic, "pattern": [list(r) for r in IMX250_PATTERN],
                         "shots": [{"files": [FRAME_NAME], "exposure": 1.0}],
                         "black_level": 0, "white_level": 2**bits - 1, "saturation": float(saturation),
                         "sensor": {"full_well": float(full_well), "read_noise": float(read_noise), "bits": int(bits)}},
        "depth": {"file": DEPTH_NAME[depth_format], "intrinsics": {"fx": float(fx), "fy": float(fy), "cx": float(cx), "cy": float(cy)},
                  "scale": float(depth_scale)},
    }  # fmt: skip

    def fill(tmp: Path) -> None:
        write_png16(tmp / FRAME_NAME, dn)
        if depth_format == "png":
            write_png16(tmp / DEPTH_NAME["png"], z)
        else:
            write_exr_depth(tmp / DEPTH_NAME["exr"], z)
        header = f"# nearlight rig export of {capture.name} (rig simulator, noise seed {seed})\n"
        (tmp / RIG_NAME).write_text(header + yaml.safe_dump(rig, sort_keys=False))

    return write_folder(out, fill, existing=_already_exists)  # a full disk, a quota: nothing half-written is left


def _already_exists(out: Path) -> None:
    raise UserError(f"{out}: already exists (rig export writes a new folder; choose another --out)")


def mosaic_frame(capture: Capture, *, colour: bool) -> np.ndarray:
    """The clean radiance a polarization mosaic records: ``[H, W]``, the IMX250 pattern at the top-left.

    Each pixel is the analyzer image at its micro-polarizer's angle,
    ``½ (S0 + S1 cos 2θ + S2 sin 2θ)`` from the capture's Stokes fit; a mono
    sensor sees the mean of R, G and B, a colour one the channel of its block
    (blocks of 2×2 in an RGGB Bayer). NaN (background) is 0.
    """
    stokes = linear_stokes(np.nan_to_num(capture.stack), capture.analyzer_angles_deg)  # [3, H, W, C]
    H, W = capture.height, capture.width
    frame = np.empty((H, W))
    for r in range(2):
        for c in range(2):
            row = analyzer_matrix([IMX250_PATTERN[r][c]])[0]  # ½ (1, cos 2θ, sin 2θ)
            img = np.tensordot(row, stokes[:, r::2, c::2], axes=1)  # [H/2, W/2, C]
            if colour:
                sub = np.empty(img.shape[:2])
                for br in range(2):
                    for bc in range(2):
                        sub[br::2, bc::2] = img[br::2, bc::2, _BAYER[br][bc]]
                frame[r::2, c::2] = sub
            else:
                frame[r::2, c::2] = img.mean(axis=-1)
    return np.clip(frame, 0.0, None)
