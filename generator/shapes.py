"""Objects as Mitsuba shape dicts: board, sphere, cylinder, bookend, torus, PLY mesh.

Each builder takes the validated object spec, the Mitsuba BSDF dict and a
scratch folder (for generated meshes) and returns ``{name: shape dict}``;
every shape is placed by :func:`nearlight.generator.scene.placement`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from .scene import Board, Bookend, Cylinder, Mesh, Sphere, Torus, placement

#: Object types that enclose a volume (a lamp can be inside them).
CLOSED = ("sphere", "cylinder", "torus", "mesh")


def _frame(columns: tuple[Any, Any, Any], origin: Any) -> np.ndarray:
    m = np.eye(4)
    for i, c in enumerate(columns):
        m[:3, i] = c
    m[:3, 3] = origin
    return m


def _rectangle(local: np.ndarray, bsdf: dict) -> dict:
    return {"type": "rectangle", "to_world": local, "bsdf": bsdf}


def board(obj: Board, bsdf: dict, scratch: Path) -> dict[str, dict]:
    w, h = obj.size
    return {"board": _rectangle(placement(obj) @ np.diag([w / 2, h / 2, 1.0, 1.0]), bsdf)}


def sphere(obj: Sphere, bsdf: dict, scratch: Path) -> dict[str, dict]:
    return {"sphere": {"type": "sphere", "to_world": placement(obj) @ np.diag([obj.radius] * 3 + [1.0]), "bsdf": bsdf}}


def cylinder(obj: Cylinder, bsdf: dict, scratch: Path) -> dict[str, dict]:
    place, r, half = placement(obj), obj.radius, obj.length / 2
    disc = np.diag([r, r, 1.0, 1.0])
    flip = np.diag([1.0, -1.0, -1.0, 1.0])
    return {
        "cylinder": {"type": "cylinder", "p0": [0.0, 0.0, -half], "p1": [0.0, 0.0, half], "radius": r,
                     "to_world": place, "bsdf": bsdf},
        "cylinder_top": {"type": "disk", "to_world": place @ _frame(np.eye(3), (0, 0, half)) @ disc, "bsdf": bsdf},
        "cylinder_bottom": {"type": "disk", "to_world": place @ _frame(np.eye(3), (0, 0, -half)) @ flip @ disc,
                            "bsdf": bsdf},
    }  # fmt: skip


def bookend(obj: Bookend, bsdf: dict, scratch: Path) -> dict[str, dict]:
    place, w = placement(obj), obj.width
    beta = math.radians(obj.bend_deg)
    x = np.array([1.0, 0.0, 0.0])
    d_b = np.array([0.0, math.cos(beta), math.sin(beta)])
    n_b = np.array([0.0, math.sin(beta), -math.cos(beta)])
    plate_a = _frame((x * w / 2, (0, obj.length_a / 2, 0), (0, 0, 1)), (0, obj.length_a / 2, 0))
    plate_b = _frame((x * w / 2, -d_b * obj.length_b / 2, n_b), d_b * obj.length_b / 2)
    return {"bookend_a": _rectangle(place @ plate_a, bsdf), "bookend_b": _rectangle(place @ plate_b, bsdf)}


def torus_mesh(major: float, minor: float, segments: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Triangle mesh of a torus around z: ``(vertices [V,3], normals [V,3], faces [F,3])``."""
    nu, nv = segments
    u = np.linspace(0, 2 * np.pi, nu, endpoint=False)[:, None]
    v = np.linspace(0, 2 * np.pi, nv, endpoint=False)[None, :]
    normals = np.stack(np.broadcast_arrays(np.cos(v) * np.cos(u), np.cos(v) * np.sin(u), np.sin(v) + 0 * u), -1)
    centre = np.stack(np.broadcast_arrays(major * np.cos(u), major * np.sin(u), 0 * u + 0 * v), -1)
    verts = centre + minor * normals
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    a, b = i * nv + j, ((i + 1) % nu) * nv + j
    c, d = ((i + 1) % nu) * nv + (j + 1) % nv, i * nv + (j + 1) % nv
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return verts.reshape(-1, 3), normals.reshape(-1, 3), faces


def write_ply(path: Path, vertices: np.ndarray, normals: np.ndarray, faces: np.ndarray) -> Path:
    """Write a binary little-endian PLY with vertex normals."""
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {len(vertices)}\nproperty float x\nproperty float y\nproperty float z\n"
        "property float nx\nproperty float ny\nproperty float nz\n"
        f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    vdata = np.concatenate([vertices, normals], axis=1).astype("<f4")
    fdata = np.zeros(len(faces), dtype=[("n", "u1"), ("idx", "<i4", (3,))])
    fdata["n"], fdata["idx"] = 3, faces
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(vdata.tobytes())
        f.write(fdata.tobytes())
    return path


def torus(obj: Torus, bsdf: dict, scratch: Path) -> dict[str, dict]:
    ply = write_ply(scratch / "torus.ply", *torus_mesh(obj.major_radius, obj.minor_radius, obj.segments))
    return {"torus": {"type": "ply", "filename": str(ply), "to_world": placement(obj), "bsdf": bsdf}}


def mesh(obj: Mesh, bsdf: dict, scratch: Path) -> dict[str, dict]:
    scale = np.diag([obj.scale] * 3 + [1.0])
    return {"mesh": {"type": "ply", "filename": obj.file, "to_world": placement(obj) @ scale, "bsdf": bsdf}}


#: Shape builders by ``object.type``.
BUILDERS: dict[str, Callable[[Any, dict, Path], dict[str, dict]]] = {
    "board": board,
    "sphere": sphere,
    "cylinder": cylinder,
    "bookend": bookend,
    "torus": torus,
    "mesh": mesh,
}
