"""nearlight: a physically-based benchmark for near point-light position and
specular reflectance estimation from polarization images.

The repository root is this package: a module's dotted name is its path
(``generator/render.py`` is ``nearlight.generator.render``). Pipeline stages,
dependencies pointing one way (docs/architecture.md)::

    nearlight.scenes     (YAML)        what to render
    nearlight.generator  (Mitsuba 3)   scene file -> capture
    nearlight.capture    (numpy)       capture format v1, read and written here only
    nearlight.estimator  (numpy/scipy) capture -> estimate
    nearlight.evaluation               sweeps, metrics, tables, reports

and beside them, imported by every stage and importing none:
``nearlight.physics`` (the closed-form physics, numpy only), ``nearlight.files``
(output places, YAML, JSON, figures) and ``nearlight.errors``.
"""

from importlib.metadata import PackageNotFoundError, version as _version

try:
    __version__ = _version("nearlight")
except PackageNotFoundError:  # pragma: no cover - running from a bare checkout
    __version__ = "0+unknown"

# Absolute, not relative: pytest imports this file on its own (the repository root is
# the package, and tests/ sits inside it), where a relative import has no parent.
from nearlight.errors import UserError

__all__ = ["UserError", "__version__"]
