"""Reading and writing a rig's raw files: 16-bit PNG/TIFF, OpenEXR and ``.npy``, one line per mistake.

PNG and TIFF go through OpenCV (``cv2.imread`` with ``IMREAD_UNCHANGED``:
16-bit values as stored), OpenEXR through the ``OpenEXR`` package the capture
format uses, ``.npy`` through numpy. A raw file is one channel (a mosaic
frame, a depth map) or, for a per-angle colour image, three (stored BGR by
OpenCV's PNG/TIFF, returned RGB).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..files.atomic import check_not_full
from ..errors import UserError

#: File types a raw file may have, by suffix (lower case).
SUFFIXES = (".png", ".tif", ".tiff", ".exr", ".npy")


def read_raw(path: Path, *, key: str, rig_file: Path, channels: tuple[int, ...] = (1,)) -> np.ndarray:
    """One raw image: ``[H, W]`` (one channel) or ``[H, W, 3]`` RGB.

    Parameters
    ----------
    path : Path
        The file.
    key : str
        The rig-file key naming it, for messages.
    rig_file : Path
        The rig file, for messages.
    channels : tuple of int
        Channel counts accepted (1 and/or 3).

    Returns
    -------
    ndarray
        As stored: ``uint8``/``uint16`` for PNG/TIFF, float32 for EXR, the array's dtype for ``.npy``.

    Raises
    ------
    UserError
        Missing or unreadable file, an unknown type, a wrong channel count.
    """
    where = f"{rig_file}: {key}: {path.name}"
    if not path.is_file():
        if path.exists():
            raise UserError(f"{where}: not a regular file (a folder or a device)")
        raise UserError(f"{where}: no such file (paths are relative to the rig file's folder)")
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise UserError(f"{where}: unknown file type {path.suffix!r} (expected {', '.join(SUFFIXES)})")
    if suffix == ".npy":
        try:
            # mapped, not read: a header stating more data than the file holds is refused, not allocated
            img = np.load(path, allow_pickle=False, mmap_mode="r")
        except (ValueError, OSError, EOFError) as exc:
            raise UserError(f"{where}: not a readable .npy file ({exc})") from None
        if not isinstance(img, np.ndarray) or img.dtype.kind not in "uif":
            raise UserError(f"{where}: expected numbers, got dtype {getattr(img, 'dtype', type(img).__name__)}")
    elif suffix == ".exr":
        img = _read_exr(path, where)
    else:
        import cv2

        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise UserError(f"{where}: not a readable {suffix[1:].upper()} image")
        if img.ndim == 3 and img.shape[2] == 3:
            img = img[..., ::-1]  # OpenCV's BGR -> RGB
    if img.ndim == 3 and img.shape[2] == 1:  # one channel with its axis kept (H, W, 1)
        img = img[..., 0]
    n = 1 if img.ndim == 2 else (img.shape[2] if img.ndim == 3 else -1)
    if n not in channels:
        want = " or ".join(f"{c} channel{'s' if c > 1 else ''}" for c in channels)
        raise UserError(f"{where}: expected an image of {want}, got shape {img.shape}")
    if min(img.shape[:2]) == 0:
        raise UserError(f"{where}: an empty image (shape {img.shape})")
    return np.ascontiguousarray(img)


def _read_exr(path: Path, where: str) -> np.ndarray:
    import OpenEXR

    try:
        with OpenEXR.File(str(path), separate_channels=True) as f:
            chans = {name: np.asarray(ch.pixels) for name, ch in f.channels().items()}
    except Exception as exc:  # OpenEXR raises bare RuntimeError/Exception on damaged files
        raise UserError(f"{where}: not a readable OpenEXR file ({exc})") from None
    if len(chans) == 1:
        return next(iter(chans.values())).astype(np.float32)
    if all(n in chans for n in ("R", "G", "B")):
        return np.stack([chans[n] for n in ("R", "G", "B")], axis=-1).astype(np.float32)
    for name in ("Z", "Y"):
        if name in chans:
            return chans[name].astype(np.float32)
    raise UserError(f"{where}: expected one channel, R/G/B or Z, got channels {', '.join(sorted(chans))}")


def write_png16(path: Path, img: np.ndarray) -> None:
    """Write ``[H, W]`` values as a 16-bit grey PNG (values rounded and clipped to 0..65535)."""
    import cv2

    data = np.clip(np.rint(img), 0, 65535).astype(np.uint16)
    ok, png = cv2.imencode(".png", data)
    if not ok:
        raise UserError(f"{path}: cannot encode a PNG")
    path.write_bytes(png.tobytes())  # an OSError (a full disk) reaches the caller, which names it


def write_exr_depth(path: Path, z: np.ndarray) -> None:
    """Write a ``[H, W]`` depth map, metres, as a one-channel (``Z``) float32 OpenEXR file."""
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, {"Z": np.ascontiguousarray(z, np.float32)}).write(str(path))
    check_not_full(path)  # OpenEXR reports no failed write
