"""Which method wins where (nearlight.evaluation.views.winners) on rows whose answer is known by construction.

Two configurations × three methods × 40 seeds of lamp errors drawn from known distributions (seeded): where one
method's errors are 1 mm and the others' 10 mm and more, its bootstrap interval of the median (40 seeds: a few
tenths of a millimetre wide) lies wholly below theirs and it wins; where two methods draw from the same
distribution their intervals overlap and the cell names both. Coverage: Mahalanobis distances² drawn from χ²(3)
cover 95 % within the binomial interval; distances 100× too large cover nothing.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from nearlight.evaluation.scoring.calibration import MAHALANOBIS_COLUMN
from nearlight.evaluation.views.winners import MIN_SEEDS, plot_winners, winners_table, winners_wide


def _rows(seeds: int = 40) -> pd.DataFrame:
    rng = np.random.default_rng(7)
    rows = []
    spec = {"near": {"balls": 0.001, "highlight": 0.010, "card": 0.030},
            "far": {"balls": 0.004, "highlight": 0.004, "card": 0.050}}
    for cell, methods in spec.items():
        for method, scale in methods.items():
            for seed in range(seeds):
                err = abs(rng.normal(scale, 0.1 * scale))
                d2 = rng.chisquare(3) * (1.0 if method != "card" else 100.0)
                rows.append({"distance": cell, "method": method, "seed": seed, "status": "ok",
                             "lamp_position_error_m": err, MAHALANOBIS_COLUMN: d2})
    rows[5]["status"] = "error"  # a failure is a miss, not a number
    return pd.DataFrame(rows)


def test_the_winner_is_the_method_whose_interval_lies_below_the_others(tmp_path):
    table = winners_table(_rows(), ["distance"])
    wide = winners_wide(table, ["distance"]).set_index("distance")
    assert wide.loc["near", "winner"] == "balls"
    far = wide.loc["far", "winner"]
    assert far.startswith("none: ") and far.endswith(" overlap") and set(far[6:-8].split(", ")) == {"balls", "highlight"}
    near = table[(table["distance"] == "near") & (table["method"] == "balls")].iloc[0]
    assert near["failed"] == 1 and near["lo"] <= near["median"] <= near["hi"] < 2.0  # mm
    card = table[table["method"] == "card"]
    assert (card["inside_95"] < 0.2).all()  # a covariance 10× too small covers almost nothing
    honest = table[table["method"] != "card"]
    assert ((honest["inside_lo"] <= 0.95) & (0.95 <= honest["inside_hi"])).all()
    assert plot_winners(table, ["distance"], tmp_path / "w.png").read_bytes()[:4] == b"\x89PNG"


def test_too_few_seeds_or_one_method_writes_nothing():
    assert winners_table(_rows(MIN_SEEDS - 1), ["distance"]).empty
    one = _rows()
    assert winners_table(one[one["method"] == "balls"], ["distance"]).empty


FAKES = '''
import numpy as np
from nearlight.estimator import Estimate

def _off(capture, mm):
    t = capture.truth
    ks = np.asarray(t["bsdf"]["ks"]) * np.asarray(t["lamp_intensity"]) / 2
    return Estimate(method="off", lamp_position=np.asarray(t["lamp_position"]) + mm / 1000, ks=ks,
                    sigma=t["bsdf"]["sigma"])

def near(capture):
    return _off(capture, 1.0)

def far(capture):
    return _off(capture, 10.0)
'''


def test_a_sweep_report_with_ten_seeds_says_which_method_wins(tmp_path, monkeypatch):
    """End to end on an analytic sweep: two fake methods off by (1, 1, 1) mm and (10, 10, 10) mm (√3 and 10√3 mm
    every seed), 10 noisy seeds of the board with the lamp at two distances: the report writes the section, `winners.csv` and its figure, and
    names the near one in both rows."""
    import textwrap

    import yaml

    from nearlight.evaluation.engine.run import run_sweep
    from nearlight.evaluation.engine.sweep import load_sweep
    from nearlight.evaluation.views.report import write_report

    (tmp_path / "nl_fakes_winners.py").write_text(textwrap.dedent(FAKES))
    monkeypatch.syspath_prepend(str(tmp_path))
    doc = {"name": "winners", "renderer": "analytic",
           "scene": {"width": 32, "height": 24, "lamp_position": [0.05, 0.15, 0.35]},
           "axes": {"lamp_distance": [0.3, 0.45], "noise": {"sensor": {"full_well": 20000, "read_noise": 5.0,
                                                                         "bits": 12}}},
           "seeds": MIN_SEEDS, "methods": ["nl_fakes_winners:near", "nl_fakes_winners:far"]}  # fmt: skip
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    run_sweep(load_sweep(path), tmp_path / "run", workers=1, progress=False)
    folder = write_report(tmp_path / "run")
    wins = pd.read_csv(folder / "winners.csv")
    assert set(wins["winner"]) == {"nl_fakes_winners:near"}
    near = wins[wins["method"] == "nl_fakes_winners:near"]
    assert np.allclose(near["median"], np.sqrt(3.0), rtol=1e-6)  # mm
    assert "## Which method wins where" in (folder / "summary.md").read_text()
    assert (folder / "winners.png").read_bytes()[:4] == b"\x89PNG"
