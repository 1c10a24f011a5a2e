"""nearlight: a physically-based benchmark for near point-light position and
specular reflectance estimation from polarization images.

Pipeline stages, dependencies pointing one way::

    nearlight.generator  (Mitsuba 3)   scene file -> capture
    nearlight.capture    (numpy)       capture format v1, read and written here only
    nearlight.estimator  (numpy/scipy) capture -> estimate
    nearlight.evaluation               sweeps, metrics, tables, reports
"""

from importlib.metadata import PackageNotFoundError, version as _version

try:
    __version__ = _version("nearlight")
except PackageNotFoundError:  # pragma: no cover - running from a bare checkout
    __version__ = "0+unknown"

from nearlight.errors import UserError

__all__ = ["UserError", "__version__"]
