"""The recall ladders of a scorecard: per metric, its thresholds and how they read (one home, data only).

:mod:`nearlight.evaluation.suites.scorecard` scores against them; the results site
(:mod:`nearlight.evaluation.site.leaderboard`) shows them in the same units.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Ladder:
    """The thresholds of one metric's recall ladder and how they read.

    Attributes
    ----------
    thresholds : tuple of float
        In the metric's own units.
    label : str
        Short name in tables and the figure.
    unit : str
        What a shown number is (``%``, ``mm``, ``°``).
    scale : float
        Shown number = metric value × scale.
    meaning : str
        The unit's meaning in a table's heading.
    """

    thresholds: tuple[float, ...]
    label: str
    unit: str
    scale: float
    meaning: str


#: Metric -> its ladder. The lamp: % of the distance from the highlight point, and millimetres (1, 2, 5, 10, 20
#: mm: what labs quote, BOP's 2025 absolute thresholds); the direction to it from the highlight point, degrees
#: (0.5° is about 1 % of the distance); σ and Ks: relative errors 0.5 %, 1 %, 2 %, 5 %, 10 %.
LADDERS: dict[str, Ladder] = {
    "lamp_position_error_pct": Ladder((0.5, 1.0, 2.0, 5.0, 10.0), "lamp", "%", 1.0, "% of the distance"),
    "lamp_position_error_m": Ladder((0.001, 0.002, 0.005, 0.01, 0.02), "lamp (mm)", "mm", 1000.0, "absolute"),
    "direction_error_deg": Ladder((0.5, 1.0, 2.0, 5.0, 10.0), "direction", "°", 1.0,
                                  "degrees, seen from the highlight point"),
    "sigma_rel_error": Ladder((0.005, 0.01, 0.02, 0.05, 0.1), "σ", "%", 100.0, "relative"),
    "ks_rel_error": Ladder((0.005, 0.01, 0.02, 0.05, 0.1), "Ks", "%", 100.0, "relative"),
}
