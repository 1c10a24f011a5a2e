"""Real rigs: the files a polarization camera and a depth sensor record, to a capture, and back.

``nearlight rig import RIG.yaml --out CAPTURE`` reads a rig file
(:mod:`nearlight.rig.rigfile`: the rig's raw files and calibration, named once; the geometry a
depth map or the object's mesh, :mod:`nearlight.rig.mesh`)
and writes a capture (:mod:`nearlight.rig.importer`); ``nearlight rig export
CAPTURE --out RIGDIR`` is the rig simulator, writing the raw files such a rig
would record (:mod:`nearlight.rig.export`). The rig file is specified in
``docs/rig-files.md``.
"""

from .importer import import_rig
from .rigfile import RigFile, load_rig_file

__all__ = ["RigFile", "import_rig", "load_rig_file"]
