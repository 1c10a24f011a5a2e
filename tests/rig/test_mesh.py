"""Rig files with the object's mesh instead of a depth map: ray-cast P and N, round trips, one-line errors.

No Mitsuba: analytic captures (generator/analytic.py) exported by the rig
simulator, their depth map swapped for a mesh of the same object (a board of
two triangles; an icosphere for the sphere) and its pose. Measured at the
commit of docs/rig-files.md's round-trip table, which holds these rows too
(mono mosaic, full well 1e6 e-, "lamp": |Δ lamp position| of ``full``
between the original and the imported capture over the camera–lamp
distance):

| object | mesh | size | max abs P error | N error | lamp | σ |
|---|---|---|---|---|---|---|
| board | OBJ, 2 triangles, mm, face normals | 160x120 | 2e-16 m | 0 | 0.67 % | -0.36 % |
| sphere | PLY, icosphere 5 (20480 triangles, cm), radial vertex normals, pose in the camera frame | 320x240 | inside by ≤ 43 µm (the tessellation) | max 0.027°, mean 0.0088° | 0.25 % | +0.62 % |

A 640x480 cast of an icosphere of 20480 triangles: 0.35 s (Embree).
"""

from __future__ import annotations

import shutil
import time

import numpy as np
import pytest
import yaml

from nearlight.capture import read_capture, write_capture
from nearlight.cli import main
from nearlight.estimator import estimate
from nearlight.generator.analytic import analytic_capture
from nearlight.rig.export import export_rig
from nearlight.rig.importer import CV_TO_MITSUBA, import_rig
from nearlight.rig.mesh import mesh_geometry
from nearlight.rig.rigfile import load_rig_file

pytest.importorskip("polanalyser")
trimesh = pytest.importorskip("trimesh")
pytest.importorskip("embreex")


def with_mesh(tmp_path, cap, mesh, name, section, **kw):
    """Export ``cap``, write ``mesh`` as ``name`` beside the rig file, swap ``depth`` for ``mesh: section``."""
    write_capture(cap, tmp_path / "orig")
    export_rig(read_capture(tmp_path / "orig"), tmp_path / "rig", full_well=1e6, depth_format="exr", **kw)
    mesh.export(tmp_path / "rig" / name)
    path = tmp_path / "rig" / "rig.yaml"
    doc = yaml.safe_load(path.read_text())
    doc.pop("depth")
    doc["mesh"] = {"file": name, **section}
    path.write_text(yaml.safe_dump(doc))
    return path


def lamp_change(cap, imp):
    e0, e1 = estimate(cap, method="full"), estimate(imp, method="full")
    d = np.linalg.norm(e0.lamp_position - cap.camera.position)
    return np.linalg.norm(e1.lamp_position - e0.lamp_position) / d, e1.sigma / e0.sigma - 1


def angle(a, b):
    """Angle between directions ``[..., 3]``, radians: atan2 of |a×b| and a·b (arccos of a float32 dot is ±3e-4)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def rot_z(deg):
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_board_from_an_obj_in_millimetres(tmp_path):
    cap = analytic_capture(width=160, height=120)
    # the 0.4 m board in its own frame, millimetres, turned 90 degrees and lifted 5 cm: the pose undoes both
    corners = np.array([[-200, -200, 50], [200, -200, 50], [200, 200, 50], [-200, 200, 50]], float)
    corners = corners @ rot_z(90).T
    board = trimesh.Trimesh(corners, [[0, 1, 2], [0, 2, 3]], process=False)
    rig = with_mesh(tmp_path, cap, board, "board.obj",
                    {"units": "mm", "rotation": rot_z(-90).tolist(), "translation": [0.0, 0.0, -0.05]})  # fmt: skip
    assert "vn " not in (rig.parent / "board.obj").read_text()  # no vertex normals: face normals are used
    import_rig(rig, tmp_path / "imp")
    imp = read_capture(tmp_path / "imp")
    both = cap.surface_mask & imp.surface_mask
    # the same pixel centres hit the same plane: only the board's edge pixels may differ (a ray exactly on it)
    assert (cap.surface_mask == imp.surface_mask).mean() > 0.999
    # P: two flat triangles are the board exactly; what is left is float32 storage of ~0.6 m (< 1e-7 m)
    assert np.abs(imp.P - cap.P)[both].max() < 1e-6
    # N: the face normal, written into the capture, +z up to rounding (turned to face the camera)
    assert np.abs(imp.N - cap.N)[both].max() < 1e-6
    lamp, sigma = lamp_change(cap, imp)
    # measured 0.67 %, as with float depth (tests/rig/test_roundtrip.py): only the demosaicing is left
    assert lamp < 0.01 and abs(sigma) < 0.01


def test_sphere_from_an_icosphere_with_vertex_normals(tmp_path):
    cap = analytic_capture(shape="sphere", width=320, height=240)
    centre, radius = np.array([0.0, 0.0, 0.15]), 0.15
    ico = trimesh.creation.icosphere(subdivisions=5, radius=radius * 100)  # centimetres, at its own origin
    # the sphere's own (radial) normals at the vertices, written into the PLY (trimesh's computed ones are
    # area-weighted face normals, up to 0.15 degrees off radial)
    sphere = trimesh.Trimesh(ico.vertices, ico.faces, vertex_normals=ico.vertices / (radius * 100), process=False)
    # pose in the camera frame (OpenCV axes): camera-from-world times world-from-object
    cam_pose = np.asarray(cap.camera.to_world, float) @ CV_TO_MITSUBA
    obj = np.eye(4)
    obj[:3, 3] = centre
    rig = with_mesh(tmp_path, cap, sphere, "sphere.ply",
                    {"units": "cm", "frame": "camera", "pose": (np.linalg.inv(cam_pose) @ obj).tolist()})  # fmt: skip
    import_rig(rig, tmp_path / "imp")
    imp = read_capture(tmp_path / "imp")
    # The tessellation error: a flat triangle lies inside the sphere by at most r − sqrt(r² − ρ²), ρ its
    # circumradius (its deepest point is its circumcentre); so every imported P is between r − δ and r of the
    # centre (+ float32 storage), while the true P is at r
    tri = sphere.triangles / 100
    a, b, c = (np.linalg.norm(tri[:, i] - tri[:, j], axis=-1) for i, j in ((1, 2), (0, 2), (0, 1)))
    rho = (a * b * c / (4 * sphere.area_faces / 1e4)).max()
    delta = radius - np.sqrt(radius**2 - rho**2)
    both = cap.surface_mask & imp.surface_mask
    r = np.linalg.norm(imp.P[both] - centre, axis=-1)
    assert r.max() < radius + 1e-6 and r.min() > radius - delta - 1e-6
    assert (radius - r).max() > 0.5 * delta  # the tessellation is really there
    # the mask differs only at the silhouette: rays passing between the polytope and the sphere
    assert (cap.surface_mask & ~imp.surface_mask).sum() < 0.01 * cap.surface_mask.sum()
    assert not (imp.surface_mask & ~cap.surface_mask).any()  # the polytope is inside the sphere
    # N: radial vertex normals interpolated at the hit X = Σ b_i v_i are Σ b_i v_i / r, the radial direction
    # through X itself, to float32 storage of P and N (~1e-7 rad); face normals would be off by up to half a
    # triangle's angular size (about 1 degree here), so this tells the two apart. Also at the silhouette:
    # a grazing ray's interpolated normal is kept on the side of the triangle hit, not flipped.
    assert angle(imp.N[both], imp.P[both] - centre).max() < 1e-6
    # against the true normal, radial through the sphere's hit on the same ray, |ΔP| <= δ / cos θ nearer:
    # about δ·tan θ / r apart (θ the incidence); where θ < 60 degrees, δ·√3 / r, plus the disagreement of the
    # original's own N with its float32 P
    view = cap.camera.position - cap.P
    cos_view = np.sum(cap.N * view, axis=-1) / np.linalg.norm(view, axis=-1)
    front = both & (cos_view > 0.5)
    truth_slack = angle(cap.P[front] - centre, cap.N[front]).max()
    err = angle(imp.N[front], cap.N[front])
    bound = delta * np.sqrt(3) / radius + truth_slack
    print(f"icosphere 5: delta {delta * 1e6:.0f} um, N error max {np.degrees(err.max()):.3f} deg, "
          f"mean {np.degrees(err.mean()):.4f} deg, bound {np.degrees(bound):.3f} deg (truth's own {truth_slack:.2g} rad)")
    assert err.max() < bound
    lamp, sigma = lamp_change(cap, imp)
    print(f"sphere: lamp {lamp:.4f}, sigma {sigma:+.4f}")
    assert lamp < 0.01 and abs(sigma) < 0.01  # measured 0.25 % and +0.62 % (icosphere 4: lamp 0.27 %, σ +0.92 %)


def test_a_640x480_cast_of_20k_triangles_takes_seconds(tmp_path):
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=0.15)  # 20480 triangles
    sphere.export(tmp_path / "s.ply")
    doc = {"format": "nearlight-rig/1",
           "camera": {"width": 640, "height": 480, "intrinsics": {"fx": 600.0, "fy": 600.0, "cx": 319.5, "cy": 239.5}},
           "polarization": {"mosaic": "mono", "shots": [{"files": ["f.png"]}], "white_level": 4095},
           "mesh": {"file": "s.ply", "units": "m", "translation": [0.0, 0.0, 0.5]}}  # fmt: skip
    (tmp_path / "rig.yaml").write_text(yaml.safe_dump(doc))
    rig = load_rig_file(tmp_path / "rig.yaml")
    t0 = time.perf_counter()
    P, N = mesh_geometry(rig)
    seconds = time.perf_counter() - t0
    print(f"640x480 cast of {len(sphere.faces)} triangles: {seconds:.2f} s")
    hit = np.isfinite(P).all(axis=-1)
    # the sphere's disc: radius 600 * 0.15 / sqrt(0.5² − 0.15²) = 189 px, about 112,000 pixels
    assert 0.9 * np.pi * 189**2 < hit.sum() < np.pi * 189**2
    assert np.allclose(np.linalg.norm(P[hit] - [0, 0, 0.5], axis=-1), 0.15, atol=1e-4)
    assert (np.sum(N[hit] * -P[hit], axis=-1) > 0).all()  # facing the camera at the origin
    assert seconds < 30  # measured 0.35 s; trimesh's own caster (rtree, no Embree) took 115 s for 5120 triangles


@pytest.fixture(scope="module")
def meshdir(tmp_path_factory):
    """A good rig folder with a mesh (the board as an OBJ), through the command."""
    tmp = tmp_path_factory.mktemp("rig")
    write_capture(analytic_capture(width=64, height=48), tmp / "cap")
    assert main(["rig", "export", str(tmp / "cap"), "--out", str(tmp / "rig")]) == 0
    corners = np.array([[-0.2, -0.2, 0], [0.2, -0.2, 0], [0.2, 0.2, 0], [-0.2, 0.2, 0]])
    trimesh.Trimesh(corners, [[0, 1, 2], [0, 2, 3]], process=False).export(tmp / "rig" / "board.obj")
    doc = yaml.safe_load((tmp / "rig" / "rig.yaml").read_text())
    doc.pop("depth")
    doc["mesh"] = {"file": "board.obj", "units": "m"}
    (tmp / "rig" / "rig.yaml").write_text(yaml.safe_dump(doc))
    return tmp / "rig"


def test_the_good_mesh_rig_imports(meshdir, tmp_path, capsys):
    assert main(["rig", "import", str(meshdir / "rig.yaml"), "--out", str(tmp_path / "c")]) == 0
    cap = read_capture(tmp_path / "c")
    assert cap.N is not None and np.isfinite(cap.N[cap.surface_mask]).all()


def _text(name, text):
    return lambda d, f: ((f / name).write_text(text), d["mesh"].update(file=name))


def _mesh(**kw):
    return lambda d, f: d["mesh"].update(**kw)


CASES = {
    "missing mesh file": (_mesh(file="nope.ply"), "mesh.file: nope.ply: no such file"),
    "unknown mesh type": (_text("board.stl", "solid x\nendsolid x\n"), "mesh.file: board.stl: unknown mesh type '.stl'"),
    "unreadable ply": (_text("bad.ply", "hello"), "mesh.file: bad.ply: not a readable PLY mesh"),
    "obj without triangles": (_text("empty.obj", "v 0 0 0\n"), "mesh.file: empty.obj: no triangles in it"),
    "pose of the wrong shape": (_mesh(pose=[[1, 0, 0], [0, 1, 0], [0, 0, 1]]), "mesh.pose: expected numbers of shape [4, 4]"),
    "pose not rigid": (_mesh(pose=[[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]),
                       "mesh.pose: expected a 4x4 rigid transform"),
    "rotation not a rotation": (_mesh(rotation=[[1, 0, 0], [0, 1, 0], [0, 0, -1]]), "mesh.rotation: expected a 3x3 rotation"),
    "translation of the wrong shape": (_mesh(translation=[0, 0]), "mesh.translation: expected numbers of shape [3]"),
    "pose and rotation": (_mesh(pose=np.eye(4).tolist(), rotation=np.eye(3).tolist()),
                          "mesh.pose: give either pose (4x4) or rotation and translation"),
    "mesh behind the camera": (_mesh(translation=[0, 0, 2.0]), "mesh.file: board.obj: the camera sees no part of the mesh"),
    "missing units": (lambda d, f: d["mesh"].pop("units"), "mesh.units: missing"),
    "unknown units": (_mesh(units="inch"), "mesh.units: expected one of m, cm, mm"),
    "units as a list": (_mesh(units=[0.001]), "mesh.units: expected one of m, cm, mm, got [0.001]"),
    "unknown frame": (_mesh(frame="lamp"), "mesh.frame: expected one of world, camera"),
    "unknown mesh key": (_mesh(scale=2), "mesh.scale: unknown key"),
    "depth and mesh": (lambda d, f: d.update(depth={"file": "depth.png"}), "depth, mesh: expected exactly one"),
    "neither depth nor mesh": (lambda d, f: d.pop("mesh"), "depth, mesh: expected exactly one (a depth map or the object's mesh), got neither"),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_mesh_is_one_line_exit_2(meshdir, tmp_path, capsys, case):
    change, message = CASES[case]
    folder = tmp_path / "r"
    shutil.copytree(meshdir, folder)
    doc = yaml.safe_load((folder / "rig.yaml").read_text())
    change(doc, folder)
    rig = folder / "rig.yaml"
    rig.write_text(yaml.safe_dump(doc))
    code = main(["rig", "import", str(rig), "--out", str(tmp_path / "c")])
    out, err = capsys.readouterr()
    assert code == 2 and out == ""
    assert err.count("\n") == 1, err
    assert err.startswith(f"nearlight: error: {rig}: {message}"), err
    assert not (tmp_path / "c").exists()
