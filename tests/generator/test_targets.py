"""Calibration targets in scenes (issue 39): the scene keys, the object ids, what the rig knows, the object alone.

Golden values and tolerances:

- render keys of scenes without targets: the keys the code before targets existed computed (commit 95ae2b1, the
  same scene files), so every cached render and every committed result still names the same render;
- the ids: Mitsuba's first hit per pixel-centre ray against the closed-form ray–sphere intersection
  (:func:`nearlight.generator.closed_form.sphere_hits`); the two agree except where a ray grazes a ball (its
  distance from the centre within 1e-4 of the radius: float32 intersection there), so that is the only slack;
- the object's own light: a render with the targets beside the board (no shadow of theirs on it) equals the render
  without them on every object pixel, bit for bit (Mitsuba intersects each shape by itself; nothing in the
  object's light depends on the other shapes), and the parts add up to the full image within float32 rounding
  (3 ulp of the sum);
- ``full`` on that render lands where it lands without the targets to 1e-6 m (both are noise-free: the same
  pixels, the same numbers, at most the rounding of a different hole filling);
- the calibration draws: 400 seeds × 3 axes = 1200 normal draws, whose sample standard deviation is within 10 %
  of the stated error (its relative standard error is 1/√2400 = 2 %: five of them).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from nearlight.capture import read_capture, write_capture
from nearlight.capture.targets import RigTarget
from nearlight.errors import UserError
from nearlight.generator import load_scene
from nearlight.generator.analytic import analytic_capture
from nearlight.generator.closed_form import sphere_hits
from nearlight.generator.nuisances import through_rig
from nearlight.generator.render import render_key
from nearlight.physics.camera import camera_rays

SCENES = Path(__file__).resolve().parents[2] / "scenes"
#: Two chrome balls beside the TS board (off it: their shadows miss it) and a matte card lying on it.
TARGETS = [
    {"type": "mirror_sphere", "position": [0.19, -0.05, 0.03], "radius": 0.025},
    {"type": "mirror_sphere", "position": [-0.19, -0.05, 0.03], "radius": 0.025},
    {"type": "matte_card", "position": [-0.09, 0.09, 0.001], "size": [0.08, 0.06]},
]
#: The sensitivity study's resolution.
SMALL = {"camera.resolution": [160, 120]}


def _board(targets=(), **more):
    return load_scene(SCENES / "ts_board.yaml", overrides={**SMALL, "targets": list(targets), **more})


# --------------------------------------------------------------------------- scene keys


@pytest.mark.parametrize(("name", "key"), [("ts_board", "892b2fbf82fc8625ebab8af7"),
                                           ("two_lamps", "72c4fb1aae47a1ad73068299"),
                                           ("bookend", "2557a3053559facd5cf56fc3")])  # fmt: skip
def test_a_scene_without_targets_keeps_its_render_key_and_its_dump(name, key):
    scene = load_scene(SCENES / f"{name}.yaml")
    assert render_key(scene) == key
    assert "targets" not in scene.model_dump(mode="json")
    assert render_key(load_scene(SCENES / f"{name}.yaml", overrides={"targets": []})) == key


def test_targets_round_trip_and_change_the_render_key():
    scene = _board(TARGETS)
    again = load_scene(scene.model_dump(mode="json"))
    assert again == scene and again.targets == scene.targets
    assert render_key(scene) != render_key(_board())
    card = scene.targets[2]
    assert card.normal is None and card.albedo == 0.8


@pytest.mark.parametrize(("override", "culprit"), [
    ({"targets": [{"type": "cube", "position": [0, 0, 0]}]}, "targets.0"),
    ({"targets": [{"type": "mirror_sphere"}]}, "targets.0.position"),
    ({"targets": [{"type": "mirror_sphere", "position": [0, 0, 0.1], "radius": -1}]}, "targets.0.radius"),
    ({"targets": [{"type": "matte_card", "position": [0, 0, 0.1], "albedo": 1.5}]}, "targets.0.albedo"),
    ({"targets": [{"type": "matte_card", "position": [0, 0, 0.1], "normal": [0, 0, 0]}]}, "targets.0.normal"),
    ({"targets": [{"type": "mirror_sphere", "position": [0.1, 0.25, 0.43], "radius": 0.03}]}, "targets.0"),
    ({"lamp.intersectable": True}, "lamp.intersectable"),
])  # fmt: skip
def test_a_bad_target_is_one_line_naming_its_key(override, culprit):
    with pytest.raises(UserError) as err:
        _board(**{k: v for k, v in override.items() if k != "targets"}, targets=override.get("targets", ()))
    assert culprit in str(err.value) and "\n" not in str(err.value)


# --------------------------------------------------------------------------- capture format (no Mitsuba)


def _with_ids(capture):
    ids = np.zeros((capture.height, capture.width), np.int32)
    ids[capture.surface_mask] = 1
    ids[:4, :6] = 2  # a target in a corner (no range there in the analytic capture: give it some)
    P, N = capture.P.copy(), None if capture.N is None else capture.N.copy()
    P[:4, :6] = [0.0, 0.0, 0.05]
    if N is not None:
        N[:4, :6] = [0.0, 0.0, 1.0]
    target = RigTarget(name="targets.0", type="mirror_sphere", centre=(0.1, 0.0, 0.02), centre_error_m=0.001,
                       radius=0.02)  # fmt: skip
    rig = type(capture.rig)(targets=(target,))
    return capture.replace(P=P, N=N, object_id=ids, objects=("object", "targets.0"), rig=rig)


def test_object_ids_and_rig_targets_round_trip(tmp_path):
    cap = _with_ids(analytic_capture(width=32, height=24))
    back = read_capture(write_capture(cap, tmp_path / "c"))
    assert back.objects == cap.objects and np.array_equal(back.object_id, cap.object_id)
    assert back.rig.targets == cap.rig.targets
    assert np.array_equal(back.object_mask, cap.object_id == 1)
    assert "object_id" not in back.extra


def test_of_object_leaves_only_the_objects_pixels():
    base = analytic_capture(width=32, height=24)
    assert base.of_object() is base  # no ids: every surface pixel is the object's
    cap = _with_ids(base)
    seen = cap.of_object()
    other = cap.object_id == 2
    assert np.isnan(seen.P[other]).all() and (seen.stack[:, other] == 0).all()
    assert np.array_equal(seen.P[~other], cap.P[~other], equal_nan=True)
    assert np.array_equal(seen.stack[:, ~other], cap.stack[:, ~other])


@pytest.mark.parametrize(("change", "culprit"), [
    (lambda doc, exr: doc.pop("objects"), "object_id"),
    (lambda doc, exr: doc.update(objects=["targets.0"]), "objects"),
    (lambda doc, exr: doc.update(objects=["object", "object"]), "objects"),
    (lambda doc, exr: doc["rig"]["targets"][0].pop("radius"), "rig.targets[0].radius"),
    (lambda doc, exr: doc["rig"]["targets"][0].update(type="cube"), "rig.targets[0].type"),
    (lambda doc, exr: doc["rig"]["targets"][0].update(centre_error_m=-1), "rig.targets[0].centre_error_m"),
    (lambda doc, exr: doc["rig"]["targets"][0].update(normal=[0, 0, 1]), "rig.targets[0].normal"),
    (lambda doc, exr: doc["rig"].update(targets="balls"), "rig.targets"),
])  # fmt: skip
def test_a_damaged_id_table_or_rig_target_is_one_line(tmp_path, change, culprit):
    path = write_capture(_with_ids(analytic_capture(width=32, height=24)), tmp_path / "c")
    doc = json.loads((path / "capture.json").read_text())
    change(doc, path / "capture.exr")
    (path / "capture.json").write_text(json.dumps(doc))
    with pytest.raises(UserError) as err:
        read_capture(path)
    assert culprit in str(err.value) and "\n" not in str(err.value)


def test_an_id_beyond_the_objects_listed_is_refused(tmp_path):
    cap = _with_ids(analytic_capture(width=32, height=24))
    cap = cap.replace(object_id=np.where(cap.object_id == 2, 7, cap.object_id).astype(np.int32))
    with pytest.raises(UserError, match=r"channel object_id: expected integers 0 to 2"):
        read_capture(write_capture(cap, tmp_path / "c"))


def test_calibration_draws_move_the_rigs_centres_by_the_stated_error():
    cap = _with_ids(analytic_capture(width=32, height=24))
    offsets = []
    for seed in range(400):
        out = through_rig(cap, seed=seed)
        offsets.append(np.subtract(out.rig.targets[0].centre, cap.rig.targets[0].centre))
        assert out.truth["nuisances"]["targets"]["centre_offsets_m"][0] == pytest.approx(offsets[-1], abs=1e-12)
    assert np.std(offsets) == pytest.approx(0.001, rel=0.10)
    assert np.array_equal(through_rig(cap, seed=7).rig.targets[0].centre, through_rig(cap, seed=7).rig.targets[0].centre)
    exact = cap.replace(rig=type(cap.rig)(targets=(RigTarget(**{**cap.rig.targets[0].__dict__, "centre_error_m": 0.0}),)))
    out = through_rig(exact, seed=3)
    assert out.rig.targets == exact.rig.targets and "nuisances" not in (out.truth or {})


# --------------------------------------------------------------------------- renders


@pytest.fixture(scope="module")
def renders():
    from nearlight.generator import render_clean

    return render_clean(_board(), progress=False), render_clean(_board(TARGETS), progress=False)


@pytest.mark.render
def test_the_ids_are_the_closed_form_first_hits_of_the_balls(renders):
    _, cap = renders
    assert cap.objects == ("object", "targets.0", "targets.1", "targets.2")
    rays = camera_rays(cap.camera.to_world, cap.width, cap.height, cap.camera.fov_x_deg).reshape(-1, 3)
    o = np.broadcast_to(cap.camera.position, rays.shape)
    for k, target in enumerate(TARGETS[:2]):
        hit, _ = sphere_hits(o, rays, np.asarray(target["position"]), target["radius"])
        hit = np.isfinite(hit).reshape(cap.height, cap.width)
        c = np.asarray(target["position"]) - cap.camera.position
        miss = np.linalg.norm(c - np.sum(c * rays, -1)[:, None] * rays, axis=-1).reshape(hit.shape)
        grazing = np.abs(miss - target["radius"]) < 1e-4 * target["radius"]
        differ = (cap.object_id == k + 2) != hit
        assert hit.sum() > 100 and not (differ & ~grazing).any()


@pytest.mark.render
def test_targets_beside_the_board_leave_its_own_light_and_the_full_image_adds_up(renders):
    from scipy.ndimage import binary_dilation

    alone, cap = renders
    obj = cap.object_id == 1
    card = cap.object_id == 4
    # the card lies 1 mm above the board: its shadow is a sliver under 1 px wide along its edge (1 mm × tan of
    # the lamp's incidence, about 0.6 mm, against 2.6 mm per pixel)
    sliver = binary_dilation(card, iterations=1) & obj
    for key in ("truth_specular", "truth_diffuse", "S0", "S1", "S2"):
        assert np.array_equal(cap.extra[key][obj & ~sliver], alone.extra[key][obj & ~sliver]), key
    assert not cap.extra["truth_specular"][~obj].any() and not cap.extra["truth_diffuse"][~obj].any()
    assert (cap.extra["S0"][card] > 0).all()  # the card's light is in the full image, and only there
    parts = cap.extra["truth_specular"] + cap.extra["truth_diffuse"]
    ulp = 3 * np.finfo(np.float32).eps * np.abs(parts)
    assert (np.abs(cap.extra["S0"] - parts)[obj] <= ulp[obj]).all()
    assert np.array_equal(cap.P[obj], alone.P[obj]) and np.isfinite(cap.P[card]).all()


@pytest.mark.render
def test_full_fits_the_boards_pixels_only(renders):
    from nearlight.estimator import estimate

    alone, cap = renders
    a, b = estimate(alone, method="full"), estimate(cap, method="full")
    assert a.ok and b.ok
    assert np.linalg.norm(a.lamp_position - b.lamp_position) < 1e-6


@pytest.mark.render
def test_ids_survive_mitsubas_merging_of_meshes_that_share_a_bsdf():
    """A bookend's two plates share a BSDF, as do two black cards in a pass about the object: Mitsuba merges each
    pair into one nameless mesh, so the ids come from intersecting each object alone (found on the targets
    study's bookend). Every pixel the bookend covers without targets is the object's with them, except where a
    target stands in front of it."""
    from nearlight.generator import render_clean

    cards = [{"type": "matte_card", "position": [x, 0.05, 0.001], "size": [0.03, 0.03]} for x in (-0.08, 0.08)]
    alone = render_clean(load_scene(SCENES / "bookend.yaml", overrides=SMALL), progress=False)
    cap = render_clean(load_scene(SCENES / "bookend.yaml", overrides={**SMALL, "targets": cards}), progress=False)
    assert cap.objects == ("object", "targets.0", "targets.1")
    counts = np.bincount(cap.object_id.ravel(), minlength=4)
    assert counts[1] > 100 and counts[2] > 20 and counts[3] > 20
    assert np.array_equal(cap.object_id == 1, alone.surface_mask & (cap.object_id < 2))
