"""Contact sheet of a capture: a few analyzer images, specular, diffuse, DoLP, AoLP."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..capture import Capture, read_capture
from ..files.figures import panel_grid, tonemap
from ..physics.polarization import aolp, dolp, separate_stokes
from .polarimetry import fit_stokes


def _white(img: np.ndarray) -> float:
    """White point of a contact-sheet image: its 99.9th percentile (1 when black)."""
    return float(np.nanpercentile(img, 99.9)) or 1.0


def panels(capture: Capture) -> list[tuple[str, np.ndarray, dict]]:
    """``(title, image, imshow kwargs)`` for the sheet."""
    out: list[tuple[str, np.ndarray, dict]] = []
    if capture.stack is not None:
        stack, angles = capture.stack, capture.analyzer_angles_deg
        white = _white(stack)
        for k in np.unique(np.linspace(0, len(angles) - 1, min(4, len(angles))).round().astype(int)):
            out.append((f"analyzer {angles[k]:g}°", tonemap(stack[k], white=white), {}))
        fit = fit_stokes(stack, angles)
        specular, diffuse = separate_stokes(fit.S0, fit.S1, fit.S2)
        lum = fit.S0.mean(-1)
        dolp_img = np.where(lum > 1e-3 * lum.max(), dolp(lum, fit.amplitude.mean(-1)), np.nan)
        aolp_img = np.where(np.isfinite(dolp_img), np.degrees(aolp(fit.S1.mean(-1), fit.S2.mean(-1))), np.nan)
    else:
        specular, diffuse, dolp_img, aolp_img = capture.specular, capture.diffuse, None, None
    for name, img in (("specular (Imax−Imin)", specular), ("diffuse (2·Imin)", diffuse)):
        if img is not None:
            out.append((name, tonemap(img, white=_white(img)), {}))
    if dolp_img is not None:
        out.append(("DoLP", dolp_img, {"cmap": "viridis", "vmin": 0, "vmax": 1}))
        out.append(("AoLP (deg)", aolp_img, {"cmap": "twilight", "vmin": -90, "vmax": 90}))
    return out


def contact_sheet(path: str | os.PathLike, out: str | os.PathLike) -> Path:
    """Write the contact sheet PNG of the capture at ``path`` to ``out``.

    Raises
    ------
    UserError
        The capture cannot be read, or ``out`` cannot be written.
    """
    capture = read_capture(path)
    return panel_grid(
        panels(capture), out, ncols=4, panel_size=4.0, title=f"{capture.name}  ({capture.width}×{capture.height})",
        title_size=11,
    )
