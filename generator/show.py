"""Contact sheet of a capture: a few analyzer images, specular, diffuse, DoLP, AoLP."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from nearlight.capture import Capture, read_capture
from nearlight.errors import UserError
from nearlight.generator.polarimetry import fit_stokes


def _tonemap(img: np.ndarray, white: float) -> np.ndarray:
    """Linear radiance to display: divide by ``white``, clip, sRGB-like gamma 1/2.2."""
    return np.clip(np.nan_to_num(img) / white, 0.0, 1.0) ** (1 / 2.2)


def panels(capture: Capture) -> list[tuple[str, np.ndarray, dict]]:
    """``(title, image, imshow kwargs)`` for the sheet."""
    out: list[tuple[str, np.ndarray, dict]] = []
    if capture.stack is not None:
        stack, angles = capture.stack, capture.analyzer_angles_deg
        white = float(np.nanpercentile(stack, 99.9)) or 1.0
        for k in np.unique(np.linspace(0, len(angles) - 1, min(4, len(angles))).round().astype(int)):
            out.append((f"analyzer {angles[k]:g}°", _tonemap(stack[k], white), {}))
        fit = fit_stokes(stack, angles)
        specular, diffuse = fit.amplitude, 2 * fit.imin
        lum = fit.S0.mean(-1)
        dolp = np.where(lum > 1e-3 * lum.max(), fit.amplitude.mean(-1) / np.maximum(lum, 1e-30), np.nan)
        aolp = np.degrees(0.5 * np.arctan2(fit.S2.mean(-1), fit.S1.mean(-1)))
        aolp = np.where(np.isfinite(dolp), aolp, np.nan)
    else:
        specular, diffuse, dolp, aolp = capture.specular, capture.diffuse, None, None
    for name, img in (("specular (Imax−Imin)", specular), ("diffuse (2·Imin)", diffuse)):
        if img is not None:
            out.append((name, _tonemap(img, float(np.nanpercentile(img, 99.9)) or 1.0), {}))
    if dolp is not None:
        out.append(("DoLP", dolp, {"cmap": "viridis", "vmin": 0, "vmax": 1, "colorbar": True}))
        out.append(("AoLP (deg)", aolp, {"cmap": "twilight", "vmin": -90, "vmax": 90, "colorbar": True}))
    return out


def contact_sheet(path: str | os.PathLike, out: str | os.PathLike) -> Path:
    """Write the contact sheet PNG of the capture at ``path`` to ``out``.

    Raises
    ------
    UserError
        The capture cannot be read, or ``out`` cannot be written.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    capture = read_capture(path)
    items = panels(capture)
    cols = 4
    rows = -(-len(items) // cols)
    aspect = capture.height / capture.width
    fig, axes = plt.subplots(rows, cols, figsize=(4 * cols, 4 * aspect * rows + 0.6), squeeze=False)
    for ax in axes.flat:
        ax.axis("off")
    for ax, (title, img, kw) in zip(axes.flat, items):
        colorbar = kw.pop("colorbar", False)
        im = ax.imshow(img, **kw)
        ax.set_title(title, fontsize=10)
        if colorbar:
            fig.colorbar(im, ax=ax, fraction=0.046, pad=0.02)
    fig.suptitle(f"{capture.name}  ({capture.width}×{capture.height})", fontsize=11)
    fig.tight_layout()
    out = Path(out)
    try:
        fig.savefig(out, dpi=100)
    except OSError as exc:
        raise UserError(f"{out}: cannot write there ({exc.strerror or exc})") from None
    finally:
        plt.close(fig)
    return out
