"""The report's luck section: spread over per-shot seeds against what the axes do (synthetic rows)."""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd
import pytest

from nearlight.evaluation.views.luck import luck_table, plot_luck

AXES = ["lamp_distance", "noise", "object"]


def _rows() -> pd.DataFrame:
    # "lucky": error = 10 * distance + seed (luck spread 4 over seeds 0..4; distance effect 10 * (0.7 - 0.25) = 4.5);
    # "steady": error = 10 * distance, the same every seed (no luck). Noisy rows (noise=low) add 100 and must
    # not count as luck.
    out = []
    for d, noise, obj, seed, m in itertools.product([0.25, 0.7], ["none", "low"], ["board", "sphere"], range(5),
                                                    ["lucky", "steady"]):
        err = 10 * d + (seed if m == "lucky" else 0) + (100 * seed if noise == "low" else 0)
        out.append({"lamp_distance": d, "noise": noise, "object": obj, "seed": seed, "method": m, "noisy": True,
                    "status": "ok", "lamp_position_error_pct": err})
    out.append({**out[0], "status": "error", "lamp_position_error_pct": np.nan})  # a failure is not a spread
    return pd.DataFrame(out)


def test_luck_is_the_spread_over_noise_free_seeds_and_the_axis_effect_the_spread_of_medians():
    t = luck_table(_rows(), AXES).set_index("method")
    assert t.loc["lucky", "luck median"] == pytest.approx(4.0)
    assert t.loc["steady", "luck median"] == 0.0
    assert t.loc["lucky", "configurations"] == 4 and t.loc["lucky", "seeds"] == 5
    # medians over seeds: 10 d + 2 (lucky), 10 d (steady): the distance moves both by 4.5, the object by 0
    assert t.loc["lucky", "lamp_distance effect"] == pytest.approx(4.5)
    assert t.loc["steady", "lamp_distance effect"] == pytest.approx(4.5)
    assert t.loc["lucky", "object effect"] == 0.0


def test_no_noise_free_seeds_no_luck_section():
    df = _rows()
    assert luck_table(df[df["noise"] == "low"], AXES).empty
    assert luck_table(df.assign(noisy=False), AXES).empty


def test_the_luck_figure_is_written(tmp_path):
    plot_luck(_rows(), AXES, tmp_path / "luck.png")
    assert (tmp_path / "luck.png").stat().st_size > 10_000


@pytest.mark.render
def test_a_jittered_sweep_report_has_the_luck_section(tmp_path):
    """End to end: a tiny Mitsuba sweep whose camera jitters; the report writes the table and the figure,
    and a sweep without jitter writes neither."""
    from pathlib import Path

    import yaml

    from nearlight.evaluation.engine.run import run_sweep
    from nearlight.evaluation.views.report import write_report
    from nearlight.evaluation.engine.sweep import load_sweep

    doc = yaml.safe_load((Path(__file__).resolve().parents[3] / "sweeps" / "smoke.yaml").read_text())
    doc.update(seeds=3, methods=["paper-init"], axes={"lamp_distance": [0.3, 0.6]})  # distant: refused on a board
    doc["set"] = {**doc.get("set", {}), "camera.resolution": [40, 30]}
    for jitter, expect in ((0.5, True), (0.0, False)):
        doc["set"]["camera.jitter_px"] = jitter
        out = tmp_path / f"j{jitter}"
        run_sweep(load_sweep(doc), out, workers=1, progress=False)
        folder = write_report(out)
        assert (folder / "luck.csv").is_file() == expect and (folder / "luck_vs_axes.png").is_file() == expect
        assert ("## Luck" in (folder / "summary.md").read_text()) == expect
    luck = pd.read_csv(tmp_path / "j0.5" / "report" / "luck.csv")
    assert list(luck["configurations"]) == [2] and list(luck["seeds"]) == [3]
