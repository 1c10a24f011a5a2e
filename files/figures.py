"""Pictures people look at: tone mapping and labelled panel grids (PNG).

One place for turning linear radiance into something a person can read, used
by the contact sheet (``nearlight show``), the estimator's plots and the paper
reproduction's figures. matplotlib is imported lazily with the Agg backend.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import UserError
from .atomic import atomic_write
from .outputs import check_file_out



def pyplot() -> Any:
    """``matplotlib.pyplot`` on the Agg backend (PNG files, never a window), imported when a figure is first
    drawn: matplotlib is not needed to run a sweep, only to draw one."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt

def tonemap(img: np.ndarray, *, white: float | None = None, gamma: float = 2.2) -> np.ndarray:
    """Linear radiance to display values in [0, 1].

    Parameters
    ----------
    img : ndarray, shape (H, W, 3) or (H, W)
        Linear radiance; NaN (background) shows black.
    white : float, optional
        Radiance shown as white; default the 99.5th percentile of the finite
        positive values, so one hot pixel does not darken the picture.
    gamma : float, optional
        Display gamma.

    Returns
    -------
    ndarray, same shape, float in [0, 1]
    """
    img = np.nan_to_num(np.asarray(img, dtype=float), nan=0.0, posinf=0.0, neginf=0.0)
    if white is None:
        pos = img[img > 0]
        white = float(np.percentile(pos, 99.5)) if pos.size else 1.0
    white = white if white > 0 else 1.0
    return np.clip(img / white, 0.0, 1.0) ** (1.0 / gamma)


def panel_grid(
    panels: Sequence[tuple[str, np.ndarray] | tuple[str, np.ndarray, dict[str, Any]]],
    path: str | os.PathLike,
    *,
    ncols: int | None = None,
    title: str | None = None,
    panel_size: float = 3.2,
    title_size: int = 10,
) -> Path:
    """Write labelled images side by side as one PNG.

    Parameters
    ----------
    panels : sequence of (label, image) or (label, image, imshow options)
        Images ``[H, W, 3]`` already in [0, 1] (see :func:`tonemap`), or
        ``[H, W]`` maps shown with their options (e.g. ``cmap``, ``vmin``,
        ``vmax``; a colour bar is added).
    path : path-like
        The PNG to write (parent folders are created).
    ncols : int, optional
        Panels per row; default all in one row up to 4.
    title : str, optional
    panel_size : float, optional
        Width of one panel, inches.
    title_size : int, optional
        Font size of the figure title (panel labels are one point smaller).

    Returns
    -------
    Path

    Raises
    ------
    UserError
        ``path`` cannot be written, or holds a file that is not a PNG image
        (see :func:`nearlight.files.outputs.check_file_out`).
    """
    path = check_file_out(path, "png")
    plt = pyplot()

    n = len(panels)
    ncols = ncols or min(n, 4)
    nrows = -(-n // ncols)
    h, w = np.asarray(panels[0][1]).shape[:2]
    fig, axes = plt.subplots(
        nrows, ncols, figsize=(panel_size * ncols, panel_size * nrows * h / w + 0.5 * nrows), squeeze=False
    )
    for ax in axes.flat:
        ax.axis("off")
    for ax, (label, img, *opts) in zip(axes.flat, panels):
        shown = ax.imshow(img, interpolation="nearest", **(opts[0] if opts else {}))
        if np.asarray(img).ndim == 2:
            fig.colorbar(shown, ax=ax, fraction=0.046, pad=0.02)
        ax.set_title(label, fontsize=title_size - 1)
    if title:
        fig.suptitle(title, fontsize=title_size)
    fig.tight_layout()
    return save_png(fig, path)


def save_png(fig: Any, path: str | os.PathLike, *, dpi: int = 100) -> Path:
    """Save a matplotlib figure as PNG at ``path``, atomically (a temporary sibling renamed into
    place), and close it (every caller is done with the figure once it is on disk).

    Raises
    ------
    UserError
        ``path`` cannot be written.
    """
    import matplotlib.pyplot as plt

    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=dpi, format="png"))
    except OSError as exc:
        raise UserError(f"{path}: cannot write the figure ({exc.strerror or exc})") from None
    finally:
        plt.close(fig)
    return path
