"""The object's mesh to ``P`` and ``N`` per pixel: one ray through each pixel centre, cast by Embree.

A rig file's ``mesh`` section (instead of ``depth``) names a PLY or OBJ file,
its units and its pose (``docs/rig-files.md``). The mesh is read by trimesh,
moved into the world, and cast with one ray per pixel centre of the capture's
camera (OpenCV's pinhole, the rig file's ``camera.intrinsics`` and
``camera.pose``; the images are undistorted to that pinhole on import). Embree
(``embreex``, through trimesh's ``ray_pyembree``) finds the first triangle
each ray hits; the hit point is then recomputed in float64 from that
triangle's plane (Embree works in float32). ``N`` is the triangle's vertex
normals interpolated at the hit (barycentric) when the file has vertex
normals, else its face normal; either way on the side of the triangle the ray
hit (the face normal turned towards the camera; interpolated normals turned to
agree with it, so a grazing ray's normal may lean slightly away from the camera).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import MissingExtra, UserError
from .rigfile import RigFile

#: Mesh file types, by suffix (lower case).
MESH_SUFFIXES = (".ply", ".obj")


def mesh_geometry(rig: RigFile) -> tuple[np.ndarray, np.ndarray]:
    """``P`` and ``N`` of every pixel from the rig file's mesh.

    Parameters
    ----------
    rig : RigFile
        With ``mesh`` set.

    Returns
    -------
    P : ndarray, shape (H, W, 3)
        First hit of each pixel's ray, world frame, metres; NaN where the ray misses.
    N : ndarray, shape (H, W, 3)
        Unit normals there, on the side of the triangle the camera sees; NaN where ``P`` is.

    Raises
    ------
    UserError
        One line naming the rig file, ``mesh.file`` and the mesh file: missing,
        of an unknown type, unreadable, without triangles, or not seen by the camera.
    """
    spec = rig.mesh
    vertices, faces, vertex_normals = read_mesh(spec.file, rig_file=rig.path)
    R, t = spec.to_world[:3, :3], spec.to_world[:3, 3]
    vertices = (vertices * spec.units) @ R.T + t
    if vertex_normals is not None:
        vertex_normals = vertex_normals @ R.T  # a rotation: units scale all axes alike, normals keep their direction
    origin, rays = rig_rays(rig)
    tri = _first_hits(vertices, faces, origin, rays)
    hit = tri >= 0
    if not hit.any():
        raise UserError(f"{rig.path}: mesh.file: {spec.file.name}: the camera sees no part of the mesh (check "
                        "mesh.pose, mesh.frame, mesh.units and camera.intrinsics)")  # fmt: skip
    corners = vertices[faces[tri[hit]]]  # [n, 3, 3]
    d = rays[hit]
    face_n = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    # the hit again, in float64: the ray meets the triangle's plane at t = n·(v0 − o) / n·d
    dist = np.einsum("ij,ij->i", face_n, corners[:, 0] - origin) / np.einsum("ij,ij->i", face_n, d)
    X = origin + dist[:, None] * d
    face_n = np.where(np.einsum("ij,ij->i", face_n, d)[:, None] > 0, -face_n, face_n)  # the side the ray hit
    if vertex_normals is None:
        n = face_n
    else:  # on the hit side: a grazing ray may see a vertex normal lean away, which is kept, not flipped
        n = np.einsum("ij,ijk->ik", _barycentric(corners, X), vertex_normals[faces[tri[hit]]])
        n = np.where(np.einsum("ij,ij->i", n, face_n)[:, None] < 0, -n, n)
        usable = np.isfinite(n).all(axis=-1) & (np.linalg.norm(n, axis=-1) > 0)
        n = np.where(usable[:, None], n, face_n)  # a file's zero or NaN normals: the face normal there
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    P = np.full(rays.shape, np.nan)
    N = np.full(rays.shape, np.nan)
    P[hit], N[hit] = X, n
    return P.reshape(rig.height, rig.width, 3), N.reshape(rig.height, rig.width, 3)


def read_mesh(path: Path, *, rig_file: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """A PLY or OBJ triangle mesh as stored (file units, mesh frame).

    Parameters
    ----------
    path : Path
        The mesh file.
    rig_file : Path
        The rig file, for messages.

    Returns
    -------
    vertices : ndarray, shape (V, 3), float64
    faces : ndarray, shape (F, 3), int
        Vertex indices of each triangle (polygons are triangulated by trimesh).
    vertex_normals : ndarray, shape (V, 3) or None
        The file's vertex normals, None when it has none. An OBJ holding
        several objects is joined into one mesh, without its normals.
    """
    where = f"{rig_file}: mesh.file: {path.name}"
    if not path.is_file():
        raise UserError(f"{where}: no such file (paths are relative to the rig file's folder)")
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise UserError(f"{where}: unknown mesh type {path.suffix!r} (expected {', '.join(MESH_SUFFIXES)})")
    try:
        import trimesh
    except ImportError:
        raise MissingExtra("rig") from None
    try:
        loaded = trimesh.load(str(path), file_type=suffix[1:], process=False)
    except Exception as exc:  # trimesh's parsers raise ValueError, IndexError, KeyError, … on damaged files
        raise UserError(f"{where}: not a readable {suffix[1:].upper()} mesh ({exc})") from None
    if isinstance(loaded, trimesh.Scene):
        loaded = loaded.to_mesh() if loaded.geometry else None
    faces = getattr(loaded, "faces", None)
    if faces is None or len(faces) == 0:
        raise UserError(f"{where}: no triangles in it (a point cloud or an empty file; give a triangle mesh)")
    # trimesh keeps the normals a file gave in its cache; otherwise it would compute them on first access
    normals = np.asarray(loaded.vertex_normals, float) if "vertex_normals" in loaded._cache else None
    return np.asarray(loaded.vertices, float), np.asarray(faces, np.int64), normals


def rig_rays(rig: RigFile) -> tuple[np.ndarray, np.ndarray]:
    """The camera's position and the unit ray through each pixel centre, world frame.

    OpenCV's pinhole: pixel ``(col, row)`` looks along
    ``((col − cx)/fx, (row − cy)/fy, 1)`` in the camera frame (x right,
    y down, z forward), turned into the world by ``camera.pose``.

    Returns
    -------
    origin : ndarray, shape (3,)
        Metres.
    rays : ndarray, shape (H·W, 3)
        Unit directions, row-major over the image.
    """
    c = rig.camera
    row, col = np.mgrid[0 : rig.height, 0 : rig.width]
    local = np.stack([(col - c.cx) / c.fx, (row - c.cy) / c.fy, np.ones(col.shape)], axis=-1).reshape(-1, 3)
    rays = local @ rig.pose[:3, :3].T
    return rig.pose[:3, 3].copy(), rays / np.linalg.norm(rays, axis=-1, keepdims=True)


def _first_hits(vertices: np.ndarray, faces: np.ndarray, origin: np.ndarray, rays: np.ndarray) -> np.ndarray:
    """Index of the first triangle each ray hits, −1 for a miss (Embree through trimesh)."""
    import trimesh

    try:
        from trimesh.ray.ray_pyembree import RayMeshIntersector
    except ImportError:  # embreex ships wheels for x86-64 only; trimesh's own caster takes minutes per image
        raise UserError("rig import of a mesh: needs embreex (Embree's ray caster; wheels for x86-64 only): "
                        "pip install 'nearlight[rig]' on an x86-64 machine") from None  # fmt: skip
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
    return RayMeshIntersector(mesh).intersects_first(np.broadcast_to(origin, rays.shape), rays)


def _barycentric(corners: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Barycentric coordinates ``[n, 3]`` of points ``X`` ``[n, 3]`` in triangles ``corners`` ``[n, 3, 3]``."""
    e1, e2, p = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0], X - corners[:, 0]
    d11, d12, d22 = (np.einsum("ij,ij->i", a, b) for a, b in ((e1, e1), (e1, e2), (e2, e2)))
    p1, p2 = np.einsum("ij,ij->i", p, e1), np.einsum("ij,ij->i", p, e2)
    den = d11 * d22 - d12 * d12
    b1, b2 = (d22 * p1 - d12 * p2) / den, (d11 * p2 - d12 * p1) / den
    return np.stack([1 - b1 - b2, b1, b2], axis=-1)
