"""Method ``render-compare`` (nearlight.rendercompare): a fit through a Mitsuba BSDF, reached by name."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from nearlight.capture import write_capture
from nearlight.cli import main
from nearlight.errors import UserError
from nearlight.estimator import estimate
from nearlight.generator.analytic import analytic_capture

#: The §4.1 board (scenes/ts_board.yaml) at 64 x 48, its material Mitsuba's Beckmann conductor: the lobe
#: render-compare's default fits, so the fit can be exact.
BECKMANN_BOARD = {
    "camera.resolution": [64, 48],
    "material": {"model": "mitsuba",
                 "bsdf": {"type": "roughconductor", "material": "none", "distribution": "beckmann", "alpha": 0.14}},
}  # fmt: skip


@pytest.fixture(scope="module")
def beckmann_board():
    from nearlight.generator import load_scene, render_clean

    scene = load_scene(Path(__file__).resolve().parents[2] / "scenes" / "ts_board.yaml", overrides=BECKMANN_BOARD)
    return render_clean(scene, progress=False)


@pytest.mark.render
def test_recovers_the_lamp_and_roughness_of_its_own_lobe(beckmann_board):
    cap = beckmann_board
    truth = np.asarray(cap.truth["lamp_position"])
    est = estimate(cap, method="render-compare")
    stage = est.stages["render-compare"]
    distance = np.linalg.norm(truth - np.asarray(est.diagnostics["ray_origin"]))  # lamp to the highlight
    # The model is the renderer's own lobe and lamp (polarizer included) at the capture's exact P and N:
    # what is left is float32 rounding of render and fit. Measured: 15 µm of 0.52 m (2.9e-5), alpha 0.139999;
    # 10x margin. Without the lamp's polarizer (lamp_polarizer=False) the same fit is 9.8e-4 off: this fails.
    assert np.linalg.norm(est.lamp_position - truth) < 3e-4 * distance
    assert stage["alpha"] == pytest.approx(0.14, rel=1e-3)
    assert est.sigma == pytest.approx(0.14 / np.sqrt(2), rel=1e-2)  # σ = alpha/√2 for Beckmann
    assert stage["lamp_polarizer"] and stage["bsdf"] == "beckmann" and stage["loss_curve"][-1] < 1e-6
    assert est.stages["render-compare"]["iterations"] >= 1 and est.timings["render-compare"] > 0
    # and it beats `full` here, whose Torrance-Sparrow lobe is not the board's (measured: 8.5 mm at 96 x 72)
    full = estimate(cap, method="full")
    assert np.linalg.norm(est.lamp_position - truth) < 0.1 * np.linalg.norm(full.lamp_position - truth)


@pytest.mark.render
def test_gradient_matches_finite_differences():
    """Dr.Jit's gradient, through the BSDF and our Stokes rotation of the lamp's polarizer, against the loss itself."""
    from nearlight.estimator.first_stage import stage_one
    from nearlight.rendercompare.lobes import LOBES
    from nearlight.rendercompare.method import PixelModel, _mitsuba

    cap = analytic_capture(width=48, height=36, analyzer_angles_deg=None)
    init, obs = stage_one(cap, strict_t_max=False)
    use = obs.surface
    model = PixelModel(_mitsuba(), LOBES["pplastic"], obs.P[use], obs.N[use], obs.camera_position,
                       obs.specular[use], polarizer=(np.array([1.0, 0.0, 0.0]), obs.peak_point))  # fmt: skip
    lamp, alpha = np.asarray(cap.truth["lamp_position"]) + [0.01, -0.02, 0.015], 0.12
    _, g_lamp, g_alpha = model.loss_and_grad(lamp, alpha)
    h = 1e-3  # m and alpha units: the float32 loss (~1e-2) changes by ~1e-4 over 2h, 1e-3 relative rounding
    for i in range(3):
        step = np.eye(3)[i] * h
        fd = (model.loss_and_grad(lamp + step, alpha)[0] - model.loss_and_grad(lamp - step, alpha)[0]) / (2 * h)
        assert g_lamp[i] == pytest.approx(fd, rel=0.03, abs=1e-3 * np.abs(g_lamp).max())
    fd = (model.loss_and_grad(lamp, alpha + h)[0] - model.loss_and_grad(lamp, alpha - h)[0]) / (2 * h)
    assert g_alpha == pytest.approx(fd, rel=0.03)


@pytest.mark.render
def test_lamp_stokes_is_mitsubas_rotation_and_pplastic_is_beckmann():
    """Two facts rendercompare relies on, against Mitsuba itself (analytic board, true lamp, alpha 0.14)."""
    import drjit as dr

    from nearlight.estimator.first_stage import stage_one
    from nearlight.rendercompare.lobes import LOBES
    from nearlight.rendercompare.method import PixelModel, _mitsuba

    mi = _mitsuba()
    cap = analytic_capture(width=48, height=36, analyzer_angles_deg=None)
    _, obs = stage_one(cap, strict_t_max=False)
    use = obs.surface
    lamp = np.asarray(cap.truth["lamp_position"])

    def model(name, polarizer=None):
        return PixelModel(mi, LOBES[name], obs.P[use], obs.N[use], obs.camera_position, obs.specular[use],
                          polarizer=polarizer)  # fmt: skip

    m = model("beckmann", (np.array([1.0, 0.0, 0.0]), obs.peak_point))
    p = mi.Point3f(*map(float, lamp))
    forward = -m.si.sh_frame.to_local(dr.normalize(p - m.si.p))
    ours = m._lamp_stokes(p, forward)
    absorb = m.si.sh_frame.to_local(dr.cross(dr.normalize(m.polarizer[1] - p), m.polarizer[0]))
    transmit = dr.normalize(dr.cross(forward, absorb - dr.dot(absorb, forward) * forward))
    rot = mi.mueller.rotate_stokes_basis(forward, transmit, mi.mueller.stokes_basis(forward))
    for i in (1, 2):  # float32 rounding of two different formulas
        np.testing.assert_allclose(np.asarray(ours[i]), np.asarray(rot[i, 0] + rot[i, 1]), atol=2e-6)
    # pplastic's lobe has the Beckmann conductor's width (lobes.py maps its alpha as Beckmann), not GGX's
    shapes = {name: model(name).evaluate(lamp, 0.14)[0] for name in ("beckmann", "ggx", "pplastic")}
    order = np.argsort(-shapes["beckmann"])[:200]  # the lobe down to about half its peak
    rel = {name: g[order] / g[order[0]] for name, g in shapes.items()}
    assert np.max(np.abs(rel["pplastic"] - rel["beckmann"])) < 0.01  # measured here: 0.0048 (GGX: 0.19)
    assert np.max(np.abs(rel["ggx"] - rel["beckmann"])) > 0.05


@pytest.mark.render
def test_cli_estimates_with_render_compare(tmp_path, capsys):
    cap = write_capture(analytic_capture(width=48, height=36), tmp_path / "cap")
    out = tmp_path / "e.json"
    assert main(["estimate", str(cap), "--method", "render-compare", "--set", "bsdf=pplastic", "--json", str(out)]) == 0
    stdout = capsys.readouterr().out
    assert stdout.startswith("render-compare: lamp (") and stdout.splitlines()[-1] == str(out)
    assert '"bsdf": "pplastic"' in out.read_text()


@pytest.mark.render  # load_method asks for the extra before it reads the options
def test_options_are_checked_before_anything_runs():
    cap = analytic_capture(width=24, height=18)
    with pytest.raises(UserError, match=r"^option bsdf: Value error, expected one of beckmann, ggx, roughplastic, pplastic"):
        estimate(cap, method="render-compare", bsdf="phong")


def test_without_the_renderer_it_says_what_to_install(tmp_path, monkeypatch, capsys):
    cap = write_capture(analytic_capture(width=24, height=18), tmp_path / "cap")
    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name in ("mitsuba", "drjit") else find_spec(name, *a))  # fmt: skip
    assert main(["estimate", str(cap), "--method", "render-compare"]) == 2
    assert capsys.readouterr() == ("", "nearlight estimate: needs the renderer: pip install 'nearlight[render]'\n")


class _Bowl:
    """A stand-in for PixelModel: the loss is the squared distance to a lamp and an alpha, NaN on one side."""

    def __init__(self, lamp, alpha):
        self.lamp, self.alpha = np.asarray(lamp), alpha

    def loss_and_grad(self, lamp, alpha):
        if lamp[2] < 0:  # a lamp behind the surface: a dark lobe, no loss
            return np.nan, np.full(3, np.nan), np.nan
        return float(np.sum((lamp - self.lamp) ** 2) + (alpha - self.alpha) ** 2), np.zeros(3), 0.0


def test_starts_are_ranked_by_their_loss():
    from nearlight.rendercompare.method import rank_starts

    model = _Bowl([0.1, 0.2, 0.3], 0.14)
    # the first (paper-init's) is far off, one start has no loss, the fourth is nearest
    starts = [(np.array([0.5, 0.5, 0.9]), 0.3), (np.array([0.0, 0.0, -0.1]), 0.1),
              (np.array([0.1, 0.2, 0.6]), 0.14), (np.array([0.1, 0.25, 0.3]), 0.15)]  # fmt: skip
    order, losses = rank_starts(model, starts)
    assert order == [3, 2, 0, 1] and len(losses) == 4 and np.isnan(losses[1])
    assert losses[3] == pytest.approx(0.05**2 + 0.01**2)  # 5 cm and 0.01 of alpha from the bowl's bottom
    assert rank_starts(model, [starts[1], starts[1]])[0] == [0, 1]  # no finite loss: in their order


@pytest.mark.render
def test_starts_are_recorded_and_the_best_fit_is_reported():
    cap = analytic_capture(width=48, height=36)
    est = estimate(cap, method="render-compare", n_starts=3, n_fits=2)
    stage = est.stages["render-compare"]
    starts = stage["starts"]
    losses = [s["loss"] for s in starts]
    fitted = [i for i, s in enumerate(starts) if s["fit_loss"] is not None]
    assert len(starts) == 4 and sorted(fitted) == sorted(np.argsort(losses)[:2].tolist())  # paper-init's and 3 more
    np.testing.assert_allclose(starts[0]["lamp_position"], est.stages["init"]["lamp_position"])
    assert stage["start"] == min(fitted, key=lambda i: starts[i]["fit_loss"])
    assert stage["loss"] == starts[stage["start"]]["fit_loss"] and stage["loss_curve"][0] == losses[stage["start"]]
    alone = estimate(cap, method="render-compare", n_starts=0, n_fits=1).stages["render-compare"]
    assert len(alone["starts"]) == 1 and alone["start"] == 0
