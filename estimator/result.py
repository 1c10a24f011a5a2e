"""The result every estimator returns."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..files.jsonable import jsonable


@dataclasses.dataclass
class Estimate:
    """A lamp position and specular reflectance estimated from one capture.

    Attributes
    ----------
    method : str
        Method name (``paper``, ``paper-init``, ``full``, ``distant`` or a
        plug-in's ``module:function``).
    lamp_position : ndarray, shape (3,)
        World position of the lamp, metres.
    ks : ndarray, shape (3,)
        Torrance–Sparrow Ks per channel, absorbing the lamp intensity reaching
        the surface (the estimators assume ``I_lamp = 1``): the true Ks times
        that intensity (half the lamp's behind an ideal polarizer).
    sigma : float
        Torrance–Sparrow roughness σ, radians.
    covariance : ndarray, shape (4, 4) or None
        1-σ covariance of ``(x, y, z, sigma)`` (m², m·rad, rad²), when the
        method provides one.
    stages : dict of str to dict
        Per-stage results (e.g. ``{"init": {...}, "am": {...}}``), JSON-ready.
    diagnostics : dict
        Curves and counts, e.g. ``t_grid`` and ``ep`` (the E_p(t) curve),
        ``energy`` (E_energy per AM iteration), ``n_pixels``.
    timings : dict of str to float
        Seconds per stage (they sum to the run time; no separate total).
    light_model : dict
        How to re-synthesise: ``{"type": "point"}``, or for the distant
        baseline ``{"type": "distant", "light_direction": [...],
        "view_direction": [...]}``.
    lamp_positions : ndarray, shape (k, 3), or None
        Optional, for a method that finds several lamps: every lamp it found,
        world positions in metres, ``k ≥ 0`` (``lamp_position`` is then
        conventionally the first of them, the one ``ks`` and ``sigma`` were
        fitted with). None (the default, and what every one-lamp method
        leaves) means the one lamp ``lamp_position``: read it through
        :meth:`found_lamps`, never this field directly. The evaluation
        matches these lamps to the capture's true ones
        (:mod:`nearlight.evaluation.scoring.matching`); ``to_dict`` writes the key only
        when it is set, so one-lamp estimates serialise as before. An
        optional last field, so that every existing ``Estimate(...)`` call and
        ``dataclasses.replace(est, lamp_position=...)`` on a one-lamp estimate
        keeps its meaning.
    status : str
        ``"ok"``, or ``"failed"``: the estimate broke a rule of
        :mod:`nearlight.estimator.sanity` (:meth:`refused`); its lamp, Ks and σ
        are then NaN, ``diagnostics["failure"]`` says which rule and why, and
        ``diagnostics["refused"]`` keeps the numbers the method gave.
    """

    method: str
    lamp_position: np.ndarray
    ks: np.ndarray
    sigma: float
    covariance: np.ndarray | None = None
    stages: dict[str, dict] = dataclasses.field(default_factory=dict)
    diagnostics: dict[str, Any] = dataclasses.field(default_factory=dict)
    timings: dict[str, float] = dataclasses.field(default_factory=dict)
    light_model: dict[str, Any] = dataclasses.field(default_factory=lambda: {"type": "point"})
    lamp_positions: np.ndarray | None = None
    status: str = "ok"

    def __post_init__(self) -> None:
        self.lamp_position = np.asarray(self.lamp_position, dtype=float).reshape(3)
        self.ks = np.asarray(self.ks, dtype=float).reshape(3)
        self.sigma = float(self.sigma)
        if self.covariance is not None:
            self.covariance = np.asarray(self.covariance, dtype=float).reshape(4, 4)
        if self.lamp_positions is not None:
            self.lamp_positions = np.asarray(self.lamp_positions, dtype=float).reshape(-1, 3)

    def found_lamps(self) -> np.ndarray:
        """Every lamp the estimate reports, shape (k, 3), metres: ``lamp_positions``, or
        ``lamp_position`` as the one row of a one-lamp estimate."""
        if self.lamp_positions is None:
            return self.lamp_position.reshape(1, 3)
        return self.lamp_positions

    @property
    def ok(self) -> bool:
        """True unless the estimate was refused (:meth:`refused`)."""
        return self.status == "ok"

    def refused(self, rule: str, reason: str) -> Estimate:
        """This estimate as a failure: ``status="failed"``, NaN numbers, the rule and reason in ``diagnostics``.

        Parameters
        ----------
        rule : str
            The broken rule's name (:mod:`nearlight.estimator.sanity`).
        reason : str
            One line with the numbers that broke it.
        """
        refused = {"lamp_position": self.lamp_position, "ks": self.ks, "sigma": self.sigma,
                   **({} if self.lamp_positions is None else {"lamp_positions": self.lamp_positions})}
        nan3 = np.full(3, np.nan)
        return dataclasses.replace(
            self, lamp_position=nan3, ks=nan3, sigma=np.nan, covariance=None,
            lamp_positions=None if self.lamp_positions is None else np.full_like(self.lamp_positions, np.nan),
            diagnostics={**self.diagnostics, "failure": {"rule": rule, "reason": reason}, "refused": refused},
            status="failed",
        )

    def without_ks(self, rule: str, reason: str) -> Estimate:
        """This estimate with Ks refused (NaN) and its lamp and σ kept: ``diagnostics["partial"]`` says which
        rule and why (``rule`` and ``reason`` as for :meth:`refused`), ``diagnostics["refused"]["ks"]`` keeps
        the method's Ks; ``status`` stays ``"ok"``."""
        return dataclasses.replace(
            self, ks=np.full(3, np.nan),
            diagnostics={**self.diagnostics, "partial": {"quantity": "ks", "rule": rule, "reason": reason},
                         "refused": {"ks": self.ks}},
        )

    def with_warning(self, warning: str | None) -> Estimate:
        """This estimate with ``warning`` appended to ``diagnostics["warnings"]`` (itself when None or already
        there)."""
        warnings = self.diagnostics.get("warnings", [])
        if warning is None or warning in warnings:
            return self
        return dataclasses.replace(self, diagnostics={**self.diagnostics, "warnings": [*warnings, warning]})

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict: lists for arrays, floats for scalars (NaN kept as None)."""
        return {
            "method": self.method,
            "status": self.status,
            "lamp_position": jsonable(self.lamp_position),
            "ks": jsonable(self.ks),
            "sigma": jsonable(self.sigma),
            "covariance": jsonable(self.covariance),
            "covariance_params": ["x", "y", "z", "sigma"],
            "light_model": jsonable(self.light_model),
            "stages": jsonable(self.stages),
            "diagnostics": jsonable(self.diagnostics),
            "timings": jsonable(self.timings),
            **({} if self.lamp_positions is None else {"lamp_positions": jsonable(self.lamp_positions)}),
        }
