"""Pictures of an estimate: the E_p(t) curve and observed vs. re-synthesised specular."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..capture import Capture
from .observation import specular_image
from .prediction import render_specular
from .result import Estimate
from ..files.figures import save_png, tonemap
from ..files.outputs import check_file_out


def plot_estimate(capture: Capture, estimate: Estimate, path: str | os.PathLike) -> Path:
    """Write a PNG: E_p(t) (when the method has it), observed and re-synthesised specular.

    The images share one white point (the 99.9th percentile of the observed
    specular), so brightness differences are real.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    path = check_file_out(path, "png", flag="--plot")
    observed = specular_image(capture)
    observed = np.where(capture.surface_mask[..., None], observed, 0.0)
    synth = render_specular(capture, estimate)
    white = float(np.percentile(observed, 99.9)) or 1.0
    d = estimate.diagnostics
    has_curve = "t_grid" in d and "ep" in d
    fig = Figure(figsize=(4.2 * (2 + has_curve), 3.6), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 2 + has_curve)
    if has_curve:
        ax = axes[0]
        ax.plot(d["t_grid"], d["ep"], ".-", ms=3)
        init = estimate.stages.get("init", {})
        if "t" in init:
            ax.axvline(init["t"], color="C1", ls="--", label=f"t* = {init['t']:.3f} m")
            ax.legend()
        ax.set_xscale("log")
        ax.set_xlabel("illuminant distance t (m)")
        ax.set_ylabel("E_p(t) = Σ r_XY")
        ax.set_title("E_p(t) along the peak ray")
    titles = ("observed specular", f"re-synthesised ({estimate.method})")
    for ax, img, title in zip(axes[has_curve:], (observed, synth), titles):
        ax.imshow(tonemap(img, white=white))
        ax.set_title(title)
        ax.set_axis_off()
    return save_png(fig, path)
