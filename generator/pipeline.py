"""Scene to capture directory: render (cached), add noise, write atomically."""

from __future__ import annotations

import os
from pathlib import Path

from ..capture import write_capture
from ..files.outputs import check_capture_out, check_folder
from .nuisances import through_rig
from .render import check_memory, render_clean
from .scene import Scene


def render_capture(scene: Scene, out_dir: str | os.PathLike, *, cache_dir: str | os.PathLike | None = None,
                   progress: bool = True, overwrite: bool = False) -> Path:  # fmt: skip
    """Render ``scene`` and write its capture to ``out_dir``.

    What the rig records is :func:`nearlight.generator.nuisances.through_rig` of the
    render: the scene's ``nuisances``, camera noise (``capture.noise``) and
    range noise (``capture.range_noise_m``), all given ``capture.seed`` (the
    seed rule of :mod:`nearlight.generator.noise`). The output folder is
    checked before rendering, and written atomically, so a failure never
    leaves a partial capture.

    Parameters
    ----------
    scene : Scene
    out_dir : path-like
        Capture directory to create.
    cache_dir : path-like, optional
        Render cache (see :func:`render_clean`).
    progress : bool
    overwrite : bool
        Replace an existing capture at ``out_dir``.

    Returns
    -------
    Path
        ``out_dir``.

    Raises
    ------
    UserError
        ``out_dir`` exists (without ``overwrite``) or is not writable; or the
        scene cannot be rendered (see :func:`render_clean`).
    """
    out = Path(out_dir)
    check_writable(out, overwrite=overwrite)
    check_memory(scene)
    if cache_dir is not None:
        check_folder(cache_dir, what="render cache folder")
    capture = render_clean(scene, cache_dir=cache_dir, progress=progress)
    cap = scene.capture
    capture = through_rig(capture, nuisances=scene.nuisances, realism=scene.realism, noise=cap.noise,
                      range_noise=cap.range_noise_m, seed=cap.seed)  # fmt: skip
    return write_capture(capture, out, overwrite=overwrite)


def check_writable(out: Path, *, overwrite: bool) -> None:
    """Raise :class:`UserError` unless a capture can be created at ``out`` (see
    :func:`nearlight.files.outputs.check_capture_out`: ``--overwrite`` replaces only a capture)."""
    check_capture_out(out, overwrite=overwrite)
