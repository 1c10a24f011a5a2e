"""Import paths the simulator does not take: per-angle images with a response curve, a separate depth sensor."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from nearlight.capture import RangeSensor, read_capture
from nearlight.generator.analytic import analytic_capture
from nearlight.rig.importer import CV_TO_MITSUBA, import_rig

cv2 = pytest.importorskip("cv2")
pytest.importorskip("polanalyser")

W, H = 128, 96


def camera_calibration(cap):
    """OpenCV intrinsics and pose of an analytic capture's camera (square pixels, centred)."""
    f = W / 2 / np.tan(np.radians(cap.camera.fov_x_deg) / 2)
    return {"fx": float(f), "fy": float(f), "cx": W / 2 - 0.5, "cy": H / 2 - 0.5}, cap.camera.to_world @ CV_TO_MITSUBA


def write_rig(folder, doc):
    (folder / "rig.yaml").write_text(yaml.safe_dump(doc))
    return folder / "rig.yaml"


def exact_depth(cap, pose):
    """z of the capture's P in the camera frame, metres, 0 off the surface."""
    z = ((cap.P - pose[:3, 3]) @ pose[:3, :3])[..., 2]
    return np.where(np.isfinite(z), z, 0.0).astype(np.float32)


@pytest.mark.parametrize("row0", ["top", "bottom"])
def test_per_angle_png_with_a_response_curve(tmp_path, row0):
    cap = analytic_capture(width=W, height=H, analyzer_angles_deg=[0, 60, 120], phase_deg=30.0)
    K, pose = camera_calibration(cap)
    sat = 1.1 * float(np.nanmax(cap.stack))
    gamma = 2.2
    files = []
    for k, img in enumerate(cap.stack):
        dn = np.rint(65535 * (np.nan_to_num(img) / sat) ** (1 / gamma)).astype(np.uint16)  # gamma-encoded, 16 bit
        if row0 == "bottom":
            dn = dn[::-1]
        cv2.imwrite(str(tmp_path / f"a{k}.png"), np.ascontiguousarray(dn[..., ::-1]))  # OpenCV writes BGR
        files.append(f"a{k}.png")
    np.save(tmp_path / "depth.npy", exact_depth(cap, pose))
    # stored bottom-up, the angles as stored are the upright ones negated
    angles = [0, 60, 120] if row0 == "top" else [0, -60, -120]
    rig = write_rig(tmp_path, {
        "format": "nearlight-rig/1",
        "camera": {"width": W, "height": H, "intrinsics": K, "pose": pose.tolist(), "row0": row0},
        "polarization": {"angles_deg": angles, "shots": [{"files": files}], "white_level": 65535,
                         "response_gamma": gamma, "saturation": sat},
        "depth": {"file": "depth.npy", "intrinsics": K},
    })  # fmt: skip
    import_rig(rig, tmp_path / "c")
    imp = read_capture(tmp_path / "c")
    assert imp.analyzer_angles_deg.tolist() == [0, 60, 120]
    m = cap.surface_mask
    # gamma decoding of a 16-bit value: |dL| <= sat * gamma * v^(gamma-1) * 0.5/65535 <= sat * gamma * 0.5/65535
    bound = sat * gamma * 0.5 / 65535
    assert np.abs(imp.stack - cap.stack)[:, m].max() <= bound * 1.001
    assert np.abs(imp.stack - cap.stack)[:, m].max() > 0.1 * bound  # the 16-bit rounding is really there
    # float depth in metres (.npy): P to float32 rounding
    assert np.nanmax(np.abs(imp.P - cap.P)[m]) < 2e-6
    # the camera the capture states is the analytic one
    assert np.allclose(imp.camera.to_world, cap.camera.to_world) and imp.camera.fov_x_deg == pytest.approx(50.0)


def test_a_separate_depth_sensor_through_its_extrinsics(tmp_path):
    # a depth sensor 3 cm to the camera's right and turned 2 degrees about its y axis, with its own
    # (finer) intrinsics; its depth map is ray-cast onto the analytic board (z = 0, 0.4 m square)
    cap = analytic_capture(width=W, height=H)
    K, pose = camera_calibration(cap)
    a = np.radians(2.0)
    to_camera = np.eye(4)
    to_camera[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    to_camera[:3, 3] = [0.03, 0.0, 0.0]
    Wd, Hd = 256, 192
    Kd = {"fx": 240.0, "fy": 238.0, "cx": 130.2, "cy": 94.7}
    u, v = np.meshgrid(np.arange(Wd), np.arange(Hd))
    d_local = np.stack([(u - Kd["cx"]) / Kd["fx"], (v - Kd["cy"]) / Kd["fy"], np.ones_like(u, float)], -1)
    depth_pose = pose @ to_camera
    d_world = d_local @ depth_pose[:3, :3].T
    origin = depth_pose[:3, 3]
    t = -origin[2] / d_world[..., 2]  # the board's plane z = 0; d_local's z is 1, so t is the depth
    hit = origin + t[..., None] * d_world
    on_board = (t > 0) & (np.abs(hit[..., 0]) <= 0.2) & (np.abs(hit[..., 1]) <= 0.2)
    z_mm = np.where(on_board, np.rint(t * 1e4), 0).astype(np.uint16)  # 16-bit PNG in 0.1 mm
    cv2.imwrite(str(tmp_path / "depth.png"), z_mm)
    cv2.imwrite(str(tmp_path / "f.png"), np.full((H, W), 100, np.uint16))
    rig = write_rig(tmp_path, {
        "format": "nearlight-rig/1",
        "camera": {"width": W, "height": H, "intrinsics": K, "pose": pose.tolist()},
        "polarization": {"mosaic": "mono", "shots": [{"files": ["f.png"]}], "white_level": 4095},
        "depth": {"file": "depth.png", "intrinsics": Kd, "width": Wd, "height": Hd, "scale": 1e-4,
                  "to_camera": to_camera.tolist()},
    })  # fmt: skip
    import_rig(rig, tmp_path / "c")
    imp = read_capture(tmp_path / "c")
    got = imp.surface_mask
    # every imported point lies on the board's plane (to the depth's 0.1 mm quantisation along its ray):
    # a wrong extrinsic or intrinsic would scale or tilt the depth sensor's rays off it
    assert np.abs(imp.P[got][:, 2]).max() < 1e-4
    # placed in the pixel its projection into the camera rounds to (nearest pixel)
    local = (imp.P - pose[:3, 3]) @ pose[:3, :3]
    col = K["fx"] * local[..., 0] / local[..., 2] + K["cx"]
    row = K["fy"] * local[..., 1] / local[..., 2] + K["cy"]
    cols, rows = np.meshgrid(np.arange(W), np.arange(H))
    assert np.abs(col - cols)[got].max() <= 0.5 + 1e-3 and np.abs(row - rows)[got].max() <= 0.5 + 1e-3
    # a finer depth sensor covers nearly all of the camera's view of the board (holes are NaN)
    both = got & cap.surface_mask
    assert both.sum() >= 0.97 * cap.surface_mask.sum()
    # and P is a board point seen within half a pixel (in col and row) of the pixel's centre: within
    # √2/2 of the pixel's footprint on the board, distance/fx/cos(incidence), of the camera's own point
    ray = cap.P - pose[:3, 3]
    dist = np.linalg.norm(ray, axis=-1)
    cos_inc = np.abs(ray[..., 2]) / dist  # the board's normal is +z
    bound = np.sqrt(0.5) * dist / K["fx"] / cos_inc + 1e-4  # + the depth's quantisation
    err = np.linalg.norm(imp.P - cap.P, axis=-1)
    assert np.all(err[both] <= bound[both])
    assert np.median(err[both] / bound[both]) > 0.2  # the resampling is really there
    # a rotated depth sensor's z is not the camera's: its steps are not stated
    assert imp.rig.range is None


@pytest.mark.parametrize("scale", [None, 1e-4])
def test_an_integer_depth_map_states_its_quantisation_along_z(tmp_path, scale):
    cap = analytic_capture(width=W, height=H)
    K, pose = camera_calibration(cap)
    unit = 1e-3 if scale is None else scale  # 16-bit PNG: millimetres unless depth.scale
    cv2.imwrite(str(tmp_path / "depth.png"), np.rint(exact_depth(cap, pose) / unit).astype(np.uint16))
    cv2.imwrite(str(tmp_path / "f.png"), np.full((H, W), 100, np.uint16))
    depth = {"file": "depth.png", "intrinsics": K, "to_camera": [[1, 0, 0, 0.01], [0, 1, 0, 0], [0, 0, 1, 0],
                                                                  [0, 0, 0, 1]]}  # fmt: skip
    if scale is not None:
        depth["scale"] = scale
    rig = write_rig(tmp_path, {
        "format": "nearlight-rig/1",
        "camera": {"width": W, "height": H, "intrinsics": K, "pose": pose.tolist()},
        "polarization": {"mosaic": "mono", "shots": [{"files": ["f.png"]}], "white_level": 4095},
        "depth": depth,
    })  # fmt: skip
    import_rig(rig, tmp_path / "c")
    imp = read_capture(tmp_path / "c")
    assert imp.rig.range == RangeSensor(sigma_m=0.0, quantum_m=unit, axis="z", source="depth-map")


def _distort(x, y, k1, k2, p1, p2, k3):
    """OpenCV's lens model (5 coefficients), normalised coordinates: written here, independently of OpenCV."""
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2**3
    return (x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
            y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y)  # fmt: skip


def test_depth_distortion_is_undone(tmp_path):
    # a depth camera (the camera itself) with barrel distortion: each depth pixel's ray is found here
    # by fixed-point inversion of the lens model to 1e-13, and the depth map ray-cast along it
    cap = analytic_capture(width=W, height=H)
    K, pose = camera_calibration(cap)
    dist = (-0.25, 0.08, 0.001, -0.0005, 0.0)
    u, v = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    xd, yd = (u - K["cx"]) / K["fx"], (v - K["cy"]) / K["fy"]
    x, y = xd.copy(), yd.copy()
    for _ in range(500):
        fx_, fy_ = _distort(x, y, *dist)
        x, y = x - (fx_ - xd), y - (fy_ - yd)
    assert np.abs(np.subtract(_distort(x, y, *dist), (xd, yd))).max() < 1e-13
    d_world = np.stack([x, y, np.ones_like(x)], -1) @ pose[:3, :3].T
    t = -pose[2, 3] / d_world[..., 2]
    hit = pose[:3, 3] + t[..., None] * d_world
    on_board = (t > 0) & (np.abs(hit[..., 0]) <= 0.2) & (np.abs(hit[..., 1]) <= 0.2)
    np.save(tmp_path / "depth.npy", np.where(on_board, t, 0.0))
    cv2.imwrite(str(tmp_path / "f.png"), np.full((H, W), 100, np.uint16))
    rig = write_rig(tmp_path, {
        "format": "nearlight-rig/1",
        "camera": {"width": W, "height": H, "intrinsics": K, "pose": pose.tolist()},
        "polarization": {"mosaic": "mono", "shots": [{"files": ["f.png"]}], "white_level": 4095},
        "depth": {"file": "depth.npy", "intrinsics": K, "distortion": list(dist)},
    })  # fmt: skip
    import_rig(rig, tmp_path / "c")
    imp = read_capture(tmp_path / "c")
    got = imp.surface_mask
    # each imported point is one of the ray-cast points (a wrong undistortion would put the depth on
    # other rays: off the board's plane and away from every one of them)
    from scipy.spatial import cKDTree

    gap, _ = cKDTree(hit[on_board]).query(imp.P[got].astype(np.float64))
    assert gap.max() < 1e-6  # float32 P of ~0.5 m: rounding ~3e-8
    assert np.abs(imp.P[got][:, 2]).max() < 1e-6
    # placed in the pixel its pinhole projection rounds to (the camera's images are undistorted)
    local = (imp.P - pose[:3, 3]) @ pose[:3, :3]
    col = K["fx"] * local[..., 0] / local[..., 2] + K["cx"]
    row = K["fy"] * local[..., 1] / local[..., 2] + K["cy"]
    assert np.abs(col - u)[got].max() <= 0.5 + 1e-6 and np.abs(row - v)[got].max() <= 0.5 + 1e-6
    # without undoing the distortion the same depth map lands up to several pixels away (the test can fail)
    shift = np.hypot((x - xd) * K["fx"], (y - yd) * K["fy"])[on_board]
    assert shift.max() > 3
