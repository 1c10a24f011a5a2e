"""Generator: scene files to polarized captures, rendered with Mitsuba 3.

Public API::

    load_scene(source, *, overrides=()) -> Scene
    render_clean(scene, *, cache_dir=None, progress=True) -> Capture
    add_camera_noise(capture, *, noise, seed) -> Capture
    add_range_noise(capture, *, sigma_m, seed) -> Capture
    render_capture(scene, out_dir, *, cache_dir=None, progress=True, overwrite=False) -> Path
    through_rig(clean, *, nuisances=None, realism="none", noise=None, range_noise=0.0, seed=0) -> Capture

Mitsuba is imported only when something is rendered.
"""

from .pipeline import render_capture
from .noise import add_camera_noise, add_range_noise
from .nuisances import through_rig
from .render import render_clean
from .scene import Scene, load_scene

__all__ = ["Scene", "add_camera_noise", "add_range_noise", "load_scene", "render_capture", "render_clean", "through_rig"]
