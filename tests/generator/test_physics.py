"""Rendered physics against closed forms and invariants (generator, Mitsuba 3).

Renders are small (96×72 or 64×48, one pixel-centre sample: exact for direct
light), so the tolerances are the generator's acceptance bounds, not loosened
for noise. Golden values: the closed forms of docs/physics.md
(nearlight.physics), evaluated at the rendered P and N; bounds: median relative
error ≤ 0.5 % and 99th percentile ≤ 3 % over pixels ≥ 2 px from an edge (what
remains is Mitsuba's float32 arithmetic and its shading normals on meshes),
Stokes-fit residual ≤ 0.5 % of the peak, DoLP of a diffuse-only object < 1 %.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from nearlight.physics import reflectance
from nearlight.generator import load_scene, render_clean
from nearlight.generator.polarimetry import fit_stokes

pytestmark = pytest.mark.render

SCENES = Path(__file__).resolve().parents[2] / "scenes"
SMALL = {"camera.resolution": [96, 72]}


def interior(mask: np.ndarray, px: int = 2) -> np.ndarray:
    """Object pixels at least ``px`` pixels from an edge of the object."""
    return ndimage.binary_erosion(mask, iterations=px, border_value=0)


def rel_stats(got: np.ndarray, ref: np.ndarray) -> tuple[float, float]:
    """Median and 99th percentile of ``|got − ref| / ref`` (all channels)."""
    rel = np.abs(got - ref) / ref
    return float(np.median(rel)), float(np.percentile(rel, 99))


#: The shipped boards, and the TS board with each microfacet lobe (same width and peak,
#: physics.reflectance.convert_bsdf): the Dr.Jit lobes of generator/bsdfs.py against physics'.
BOARDS = {
    "ts": ("ts_board.yaml", {}),
    "ward": ("ward_board.yaml", {}),
    "ggx": ("ts_board.yaml", {"material": reflectance.convert_bsdf(
        {"model": "torrance_sparrow", "ks": [0.8, 0.6, 0.5], "sigma": 0.08, "kd": [0.5, 0.5, 0.5]}, "ggx")}),
    "beckmann": ("ts_board.yaml", {"material": reflectance.convert_bsdf(
        {"model": "torrance_sparrow", "ks": [0.8, 0.6, 0.5], "sigma": 0.08, "kd": [0.5, 0.5, 0.5]}, "beckmann")}),
}


@pytest.fixture(scope="module", params=sorted(BOARDS))
def board(request):
    name, extra = BOARDS[request.param]
    scene = load_scene(SCENES / name, overrides={**SMALL, **extra})
    return scene, render_clean(scene, progress=False)


def closed_form(cap, kind: str) -> np.ndarray:
    t = cap.truth
    if "lamp_position" not in t:  # several lamps (scenes/two_lamps.yaml): their radiance adds
        return sum(closed_form(cap.replace(truth={"lamp_position": lamp["position"], "lamp_intensity": lamp["intensity"],
                                                  "bsdf": t["bsdf"]}), kind) for lamp in t["lamps"])  # fmt: skip
    half = np.asarray(t["lamp_intensity"]) / 2  # an ideal polarizer passes half of unpolarized light
    args = (cap.P, cap.N, cap.camera.position, t["lamp_position"], half)
    if kind == "specular":
        return reflectance.specular_radiance(*args, t["bsdf"])
    return reflectance.diffuse_radiance(*args, t["bsdf"]["kd"])


def test_board_geometry_is_the_papers_regime(board):
    # The shipped boards keep view and lamp incidence below 60° (the paper's model).
    _, cap = board
    m = cap.surface_mask
    g = reflectance.shading_geometry(cap.P[m], cap.N[m], cap.camera.position, cap.truth["lamp_position"])
    assert np.degrees(np.arccos(g.cos_r)).max() < 60
    assert np.degrees(np.arccos(g.cos_i)).max() < 60
    # the highlight (peak of the specular truth) is inside the image, away from the border
    peak = np.unravel_index(np.argmax(cap.extra["truth_specular"][..., 1]), m.shape)
    assert 4 <= peak[0] < m.shape[0] - 4 and 4 <= peak[1] < m.shape[1] - 4


@pytest.mark.parametrize("kind", ["specular", "diffuse"])
def test_truth_images_match_closed_form(board, kind):
    # The generator's acceptance bar against the closed form: median relative error <= 0.5 %, p99 <= 3 %
    # over object pixels >= 2 px from an edge (edge pixels mix object and background in one sample).
    _, cap = board
    m = interior(cap.surface_mask)
    med, p99 = rel_stats(cap.extra[f"truth_{kind}"][m], closed_form(cap, kind)[m])
    assert med <= 0.005 and p99 <= 0.03, (med, p99)


def test_separation_from_stack_matches_closed_form(board):
    # ideal mode: I(θ) = Id/2 + Is cos²(θ−β), so Imax − Imin = Is and 2·Imin = Id (paper §2.3).
    _, cap = board
    m = interior(cap.surface_mask)
    fit = fit_stokes(cap.stack, cap.analyzer_angles_deg)
    for got, kind in ((fit.amplitude, "specular"), (2 * fit.imin, "diffuse")):
        med, p99 = rel_stats(got[m], closed_form(cap, kind)[m])
        assert med <= 0.005 and p99 <= 0.03, (kind, med, p99)


def test_stack_fits_cos2theta_and_dolp_at_most_one(board):
    _, cap = board
    fit = fit_stokes(cap.stack, cap.analyzer_angles_deg)
    peak = cap.stack.max()
    assert np.abs(fit.residual).max() <= 0.005 * peak  # acceptance bound: residual <= 0.5 % of the peak
    S0, S1, S2 = (cap.extra[k] for k in ("S0", "S1", "S2"))
    assert np.all(np.hypot(S1, S2) <= S0 * (1 + 1e-5) + 1e-9)  # float32 rounding only


def _board_dict(**material) -> dict:
    return {
        "camera": {"position": [0, -0.35, 0.55], "look_at": [0, 0, 0], "resolution": [64, 48]},
        "object": {"type": "board", "size": [0.3, 0.3]},
        "material": {"model": "torrance_sparrow", "ks": [0.3, 0.2, 0.1], "sigma": 0.1, **material},
        "lamp": {"position": [0.1, 0.25, 0.45], "intensity": [2.0, 2.0, 2.0], "polarizer_axis": [1, 2, 0.5]},
    }


def test_diffuse_only_object_is_unpolarized():
    cap = render_clean(load_scene(_board_dict(ks=[0, 0, 0], kd=[0.5, 0.4, 0.3])), progress=False)
    m = cap.surface_mask
    S0, S1, S2 = (cap.extra[k][m] for k in ("S0", "S1", "S2"))
    assert S0.min() > 0
    assert (np.hypot(S1, S2) / S0).max() < 0.01  # acceptance bound: DoLP < 1 % (an ideal depolarizing diffuse lobe gives 0)


def test_dolp_at_most_one_in_fresnel_mode():
    cap = render_clean(load_scene(_board_dict(kd=[0.1, 0.1, 0.1], polarization="fresnel", eta=1.6)), progress=False)
    S0, S1, S2 = (cap.extra[k] for k in ("S0", "S1", "S2"))
    assert np.all(np.hypot(S1, S2) <= S0 * (1 + 1e-5) + 1e-9)


def fresnel_dolp(cos_d: np.ndarray, eta: float) -> np.ndarray:
    """``(Rs − Rp)/(Rs + Rp)`` for a dielectric of index ``eta`` (textbook Fresnel equations)."""
    cos_t = np.sqrt(1 - (1 - cos_d**2) / eta**2)
    rs = ((cos_d - eta * cos_t) / (cos_d + eta * cos_t)) ** 2
    rp = ((eta * cos_d - cos_t) / (eta * cos_d + cos_t)) ** 2
    return (rs - rp) / (rs + rp)


@pytest.fixture(scope="module")
def mi():
    from nearlight.generator.llvm import mitsuba

    return mitsuba()


def _trace(mi, scene, *, lamp: dict | None = None, part: str = "full", route: str = "emitter", extra=None):
    """Stokes ``[3, H, W]`` of channel 0, optionally with the lamp or extra shapes replaced."""
    from nearlight.generator import render

    with tempfile.TemporaryDirectory() as scratch:
        d = render.scene_dict(mi, scene, part=part, channel=0, lamp_route=route, scratch=Path(scratch))
        if lamp is not None:
            d["lamp"] = lamp
        d.update(extra or {})
        return render.trace_stokes(mi, mi.load_dict(d), spp=1), d


def test_fresnel_mode_dolp_for_unpolarized_light(mi):
    # Fresnel mode's closed form: specular DoLP = (Rs − Rp)/(Rs + Rp) at the half-vector angle, within 1 %, for
    # unpolarized light;
    # and the scalar lobe is unchanged (the Fresnel matrix is normalised to unit unpolarized reflectance).
    eta = 1.6
    scene = load_scene(_board_dict(polarization="fresnel", eta=eta))
    lamp = {"type": "point", "position": list(scene.lamp.position), "intensity": {"type": "uniform", "value": 2.0}}
    S, _ = _trace(mi, scene, lamp=lamp, part="specular")
    cap = render_clean(scene, progress=False)  # only for the exact P, N at the same pixel centres
    m = interior(cap.surface_mask)
    g = reflectance.shading_geometry(cap.P[m], cap.N[m], cap.camera.position, scene.lamp.position)
    cos_d = np.sum(g.light * reflectance.normalize(g.light + g.view), axis=-1)
    dolp = np.hypot(S[1], S[2])[m] / S[0][m]
    assert np.max(np.abs(dolp / fresnel_dolp(cos_d, eta) - 1)) <= 0.01
    ref = reflectance.specular_radiance(cap.P[m], cap.N[m], cap.camera.position, scene.lamp.position, 2.0,
                                        {"model": "torrance_sparrow", "ks": 0.3, "sigma": 0.1})[:, 0]  # fmt: skip
    med, p99 = rel_stats(S[0][m], ref)
    assert med <= 0.005 and p99 <= 0.03, (med, p99)


def test_lamp_routes_agree(mi):
    # Route 1: our polarized point emitter (path integrator). Route 2: Mitsuba's unpolarized point light behind a
    # geometric `polarizer` sheet 1 mm away, facing the object (volpath). Both model the tilted filter the same way
    # (Korger et al. 2013), so they must agree to float32 precision over the whole image.
    scene = load_scene(_board_dict(kd=[0.2, 0.2, 0.2]))
    a, _ = _trace(mi, scene)
    b, _ = _trace(mi, scene, route="sheet")
    m = a[0] > 0
    assert m.sum() > 1000
    assert np.abs(a - b)[:, m].max() <= 1e-4 * a[0].max()


def test_analyzer_stack_matches_a_polarizer_sheet_at_the_camera(mi):
    # Physical route for the analyzer: a polarizer sheet 3 cm in front of the camera (beyond Mitsuba's 1 cm near
    # clip), its axis at θ counter-clockwise from the image's horizontal, rendered with volpath. It must equal
    # ½(S0 + S1 cos 2θ + S2 sin 2θ) from the Stokes render (and fixes the sign convention of θ). Mitsuba's sheet
    # treats the up-to-20°-oblique rays as a tilted filter, our Stokes frame does not: measured max deviation
    # 0.36 % of the unfiltered peak (S0.max()); deterministic (pixel-centre rays), tolerance 0.5 %. Compared 1 px
    # inside the board's outline, where rays spawned at the sheet may hit or miss.
    from nearlight.generator import render

    scene = load_scene(_board_dict(kd=[0.3, 0.3, 0.3]))
    S, base = _trace(mi, scene)
    inside = interior(S[0] > 0, px=1)
    M = np.asarray(scene_sensor_matrix(mi, base), float)
    fwd, up = M[:3, 2], M[:3, 1]
    right = np.cross(fwd, up)
    for theta in (30.0, 60.0, 135.0):
        t = np.radians(theta)
        x = np.cos(t) * right + np.sin(t) * up
        frame = np.eye(4)
        frame[:3, 0], frame[:3, 1], frame[:3, 2] = 0.05 * x, 0.05 * np.cross(fwd, x), fwd
        frame[:3, 3] = np.asarray(scene.camera.position) + 0.03 * fwd
        sheet = {"type": "rectangle", "to_world": mi.ScalarTransform4f(frame.tolist()), "bsdf": {"type": "polarizer"}}
        volpath = {"type": "volpath", "max_depth": 3}  # the sheet is one more vertex on camera paths
        got, _ = _trace(mi, scene, extra={"analyzer": sheet, "integrator": volpath})
        want = render.analyzer_stack(S[..., None], [theta])[0, ..., 0]
        assert np.abs(got[0] - want)[inside].max() <= 0.005 * S[0].max(), theta


def scene_sensor_matrix(mi, d: dict) -> np.ndarray:
    return np.asarray(mi.load_dict(d["sensor"]).world_transform().matrix, float).reshape(4, 4)


def test_stokes_frame_matches_mitsubas_stokes_integrator(mi):
    # Our pixel-centre loop rotates path's Mueller result into the sensor frame as Mitsuba's `stokes` integrator
    # does; mi.render(stokes) averages each pixel's footprint (box filter, 256 spp) instead of its centre, so the
    # two differ by the footprint's curvature only: measured median 0.04 % of the peak.
    scene = load_scene(_board_dict(kd=[0.2, 0.2, 0.2]))
    ours, d = _trace(mi, scene)
    d["integrator"] = {"type": "stokes", "integrator": d["integrator"]}
    img = np.asarray(mi.render(mi.load_dict(d), spp=256))
    theirs = np.moveaxis(img[..., [1, 4, 7]], -1, 0)  # S0.R, S1.R, S2.R (mono: R = G = B)
    m = ours[0] > 0
    assert np.median(np.abs(ours - theirs)[:, m]) <= 2e-3 * ours[0].max()


def test_per_channel_path_equals_the_linear_path_without_interreflection():
    # max_depth 3 renders each channel (and the full image) separately and traces second bounces; a flat board
    # cannot see itself, so the result must equal the direct-light render (unit renders scaled per channel).
    base = _board_dict(kd=[0.5, 0.3, 0.1])
    a = render_clean(load_scene(base), progress=False)
    b = render_clean(load_scene(base, overrides={"capture.max_depth": 3, "capture.spp": 2}), progress=False)
    for k in ("S0", "S1", "S2", "truth_specular", "truth_diffuse"):
        assert np.allclose(a.extra[k], b.extra[k], rtol=1e-5, atol=1e-7), k


def test_interreflection_in_the_bookend_adds_light():
    # The L's two plates light each other once max_depth > 2: the full image gains light (never loses it), most
    # near the bend; direct-only S0 is exactly truth_specular + truth_diffuse.
    over = {"camera.resolution": [48, 36]}
    a = render_clean(load_scene(SCENES / "bookend.yaml", overrides=over), progress=False)
    b = render_clean(load_scene(SCENES / "bookend.yaml", overrides={**over, "capture.max_depth": 3,
                                                                     "capture.spp": 16}), progress=False)  # fmt: skip
    m = a.surface_mask
    assert np.allclose(a.extra["S0"], a.extra["truth_specular"] + a.extra["truth_diffuse"], rtol=1e-5, atol=1e-8)
    gain = b.extra["S0"][m].mean() / a.extra["S0"][m].mean()
    assert 1.01 < gain < 1.5, gain


def test_mitsuba_material_passes_through_per_channel():
    # A Mitsuba BSDF dict (model mismatch studies): rgb values are rendered per channel; no truth lobes exist.
    doc = _board_dict()
    rgb = {"type": "rgb", "value": [0.6, 0.3, 0.1]}
    doc["material"] = {"model": "mitsuba", "bsdf": {"type": "pplastic", "alpha": 0.1, "diffuse_reflectance": rgb}}
    cap = render_clean(load_scene(doc), progress=False)
    assert "truth_specular" not in cap.extra and cap.truth["bsdf"]["model"] == "mitsuba"
    S0 = cap.extra["S0"][cap.surface_mask]
    assert np.all(S0[:, 0] > S0[:, 1]) and np.all(S0[:, 1] > S0[:, 2])
    dolp = np.hypot(cap.extra["S1"], cap.extra["S2"])[cap.surface_mask] / S0
    assert dolp.max() <= 1 + 1e-5 and dolp.max() > 0.1  # pplastic's specular lobe keeps the lamp's polarization


SCALAR_SCRIPT = """
import sys, warnings
import numpy as np
from nearlight.generator import llvm, load_scene, render_clean
if sys.argv[1] == "no-llvm":
    llvm.find_libllvm = lambda: None  # as on a machine without LLVM >= 17
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    mi = llvm.mitsuba()
print(mi.variant(), [w.category.__name__ for w in caught])
scene = load_scene(sys.argv[2], overrides={"camera.resolution": [16, 12], "material.polarization": "fresnel"})
cap = render_clean(scene, progress=False)
np.save(sys.argv[3], np.stack([cap.extra[k] for k in ("S0", "S1", "S2")]))
"""


@pytest.mark.parametrize("how", ["forced", "no-llvm"])
def test_scalar_fallback_matches_llvm(tmp_path, how):
    # Without LLVM >= 17 the generator warns and renders with scalar_spectral_polarized (flat spectra: wavelength 0
    # is the exact mono value). Same physics, other code path: equal to float32 precision (measured 2e-5 abs at
    # S0 up to 2.0, i.e. 1e-5 relative).
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k not in ("DRJIT_LIBLLVM_PATH", "NEARLIGHT_MITSUBA_VARIANT")}
    if how == "forced":
        env["NEARLIGHT_MITSUBA_VARIANT"] = "scalar_spectral_polarized"
    out = tmp_path / "s.npy"
    run = subprocess.run([sys.executable, "-c", SCALAR_SCRIPT, how, str(SCENES / "ts_board.yaml"), str(out)],
                         env=env, capture_output=True, text=True, timeout=300)  # fmt: skip
    assert run.returncode == 0, run.stderr[-2000:]
    variant, _, warned = run.stdout.strip().splitlines()[0].partition(" ")
    assert variant == "scalar_spectral_polarized"
    assert ("ScalarFallbackWarning" in warned) == (how == "no-llvm")
    scene = load_scene(SCENES / "ts_board.yaml", overrides={"camera.resolution": [16, 12],
                                                             "material.polarization": "fresnel"})  # fmt: skip
    cap = render_clean(scene, progress=False)
    want = np.stack([cap.extra[k] for k in ("S0", "S1", "S2")])
    assert np.abs(np.load(out) - want).max() <= 1e-4 * want[0].max()


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(p.name for p in SCENES.glob("*.yaml")))
def test_shipped_scene_at_full_resolution_matches_closed_form(name):
    # Opt-in (--runslow): every shipped scene at its own 640x480, same bounds as the
    # small-render tests (median <= 0.5 %, p99 <= 3 % over pixels >= 2 px from an edge: see the module docstring).
    scene = load_scene(SCENES / name)
    if any(lamp.radius > 0 for lamp in scene.lamps):  # the closed form here is a point lamp's (scenes/targets.yaml:
        scene = load_scene(SCENES / name, overrides={"lamp.intersectable": False, "lamp.radius": 0.0})  # 1 cm)
    cap = render_clean(scene, progress=False)
    m = interior(cap.object_mask)  # the object's pixels (a scene with calibration targets has others)
    for kind in ("specular", "diffuse"):
        ref = closed_form(cap, kind)
        # Compare where the closed form is above 1e-6 of its peak: further out in the lobe's
        # tail Mitsuba's float32 exp() underflows to 0 while the float64 closed form does not.
        lit = m & np.all(ref > 1e-6 * ref[m].max(), axis=-1)
        med, p99 = rel_stats(cap.extra[f"truth_{kind}"][lit], ref[lit])
        assert med <= 0.005 and p99 <= 0.03, (name, kind, med, p99)
