"""Several point lamps over one surface: their summed specular, each lamp weighted by its polarization angle.

Radiance is linear in the lamps (docs/physics.md, "lamps add"), so the
specular image of K lamps over one surface is the sum of K single-lamp
images: ``I_s = Σₖ colourₖ · F(lₖ; a) / rₖ²``, each lamp its own position
and colour (the colour absorbs its intensity and Ks), one roughness ``a`` and
one lobe family (the surface is one). :class:`SeveralLampModel` composes
:class:`~nearlight.estimator.pointlamp.PointLampModel` (its residuals and
analytic Jacobian, one per lamp) rather than restating its formulas.

The sum assumes the separated specular of several lamps is the sum of theirs:
true where their highlights do not overlap or their light is polarized alike
(docs/capture-format.md, "Several lamps": Stokes vectors add, so where
differently polarized highlights overlap ``Imax − Imin`` is less than the sum).
With the lamps' filter in the capture, each lamp is weighted by how much of
its polarized light the separation measured (:class:`LampPhases`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.optimize import nnls

from ..capture import Capture
from ..physics.polarization import specular_aolp
from .pixels import FitPixels
from .pointlamp import PointLampModel
from .separation import specular_phase


class LampPhases(NamedTuple):
    """What weighs each lamp of a several-lamp model by its polarization angle (:class:`SeveralLampModel`).

    Attributes
    ----------
    measured : ndarray, shape (n,)
        β̂ per pixel, radians: the phase the separation measured the specular
        along (:func:`~nearlight.estimator.separation.specular_phase`).
    camera_up : ndarray, shape (3,)
        The camera's up vector (``camera.to_world``'s second column).
    axis, aim : ndarray, shape (3,)
        Every lamp's filter (``rig.lamp_filter``).
    """

    measured: np.ndarray
    camera_up: np.ndarray
    axis: np.ndarray
    aim: np.ndarray

    def subset(self, rows: slice | np.ndarray) -> LampPhases:
        return self._replace(measured=np.ascontiguousarray(self.measured[rows]))


def lamp_phases(capture: Capture, use: np.ndarray, separation: str,
                fit_px: FitPixels | None = None) -> LampPhases | None:
    """:class:`LampPhases` of the fitted pixels ``use``, or None where the capture cannot give them.

    Needs the lamps' filter (``rig.lamp_filter``), the camera's orientation
    (``camera.to_world``) and a separation that measures a phase (``fit``,
    ``projected``) of an analyzer stack. The dark pixels measured from their
    readings (``fit_px.measured``, :func:`~nearlight.estimator.pixels.weighted_fit_pixels`) take the phase
    they were measured along.
    """
    filt, to_world = capture.rig.lamp_filter, capture.camera.to_world
    phase = None if filt is None or to_world is None else specular_phase(capture, method=separation)
    if phase is None:
        return None
    if fit_px is not None:
        phase[fit_px.measured] = fit_px.measured_phase
    return LampPhases(np.ascontiguousarray(phase[use]), np.asarray(to_world, float)[:3, 1],
                      np.asarray(filt.axis, float), np.asarray(filt.aim, float))


class SeveralLampModel:
    """Specular radiance of K point lamps over one surface, with its Jacobian.

    Parameters ``x = (l₁, c₁, …, l_K, c_K, a)``, shape ``(6K + 1,)``: each
    lamp's position (m) and colour (its intensity times Ks per channel), then
    the lobe family's roughness, shared. Residuals are
    ``(Σₖ w_k model_k − observed) / std``, flattened pixel-major ``[n · 3]``,
    ``model_k`` :class:`~nearlight.estimator.pointlamp.PointLampModel`'s for lamp
    k and ``w_k = 1``, or, with ``phases``, ``w_k = cos 2(β_k − β̂)``: the
    separated specular of lamps polarized at different angles ``β_k``
    (:func:`~nearlight.physics.polarization.specular_aolp`) is the sum of
    their polarized parts measured along β̂, not the sum of their radiances
    (how much that matters: docs/measurements/estimator-choices.md, "Several lamps").

    Parameters
    ----------
    lamp : PointLampModel
        The pixels, observed specular, lobe family and weights.
    k : int
        Number of lamps.
    phases : LampPhases, optional
        The pixels' β̂ and the lamps' filter; None: ``w_k = 1``.
    """

    def __init__(self, lamp: PointLampModel, k: int, phases: LampPhases | None = None):
        self.lamp, self.k, self.phases = lamp, k, phases
        # the same model with nothing observed: its residuals are one lamp's weighted radiance
        self._one = type(lamp)(lamp.P, lamp.N, lamp.camera, np.zeros_like(lamp.observed), lobe=lamp.lobe, std=lamp.std)
        self._observed = self._one._weigh(lamp.observed).ravel()
        self._phases_at: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}

    @property
    def n_params(self) -> int:
        return 6 * self.k + 1

    def subset(self, rows: slice | np.ndarray) -> SeveralLampModel:
        """The same model on some of its pixels."""
        return SeveralLampModel(self.lamp.subset(rows), self.k, None if self.phases is None else self.phases.subset(rows))

    def with_lobe(self, lobe: str) -> SeveralLampModel:
        """The same pixels and weights with another lobe family."""
        return SeveralLampModel(self.lamp.with_lobe(lobe), self.k, self.phases)

    def with_geometry(self, P: np.ndarray, N: np.ndarray) -> SeveralLampModel:
        """The same on other surface points and normals (:meth:`PointLampModel.with_geometry`); the pixels' measured
        polarization angles stay, each lamp's is the new geometry's."""
        return SeveralLampModel(self.lamp.with_geometry(P, N), self.k, self.phases)

    @property
    def P(self) -> np.ndarray:
        """The pixels' surface points (n, 3), metres."""
        return self.lamp.P

    @property
    def N(self) -> np.ndarray:
        """The pixels' unit normals (n, 3)."""
        return self.lamp.N

    @property
    def camera(self) -> np.ndarray:
        return self.lamp.camera

    def lamp_params(self, x: np.ndarray, i: int) -> np.ndarray:
        """Lamp ``i``'s single-lamp parameters ``(x, y, z, c_R, c_G, c_B, a)``, shape (7,)."""
        return np.concatenate([x[6 * i : 6 * i + 6], x[-1:]])

    def _beta(self, position: np.ndarray) -> np.ndarray:
        ph = self.phases
        return specular_aolp(self.lamp.P, self.lamp.camera, ph.camera_up, position, ph.axis, ph.aim)

    def _phase_at(self, position: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """β and ``w = cos 2(β − β̂)`` of a lamp at ``position``, shape (n,) each, kept for the solver's
        last few points (the residuals, the Jacobian and the solved colours at one point share them)."""
        key = np.asarray(position, float).tobytes()
        if key not in self._phases_at:
            if len(self._phases_at) > 4 * self.k:
                self._phases_at.clear()
            beta = self._beta(position)
            self._phases_at[key] = (beta, np.cos(2.0 * (beta - self.phases.measured)))
        return self._phases_at[key]

    def weight(self, position: np.ndarray) -> np.ndarray:
        """``w = cos 2(β − β̂)`` of a lamp at ``position``, shape (n,) (ones without ``phases``)."""
        if self.phases is None:
            return np.ones(len(self.lamp.P))
        return self._phase_at(position)[1]

    def _weight_gradient(self, position: np.ndarray) -> np.ndarray:
        """``∂w/∂l``, shape (n, 3): central differences of β (steps 1e-6 of the lamp's distance)."""
        beta = self._phase_at(position)[0]
        step = 1e-6 * float(np.linalg.norm(position - self.lamp.P[0]))
        out = np.empty((len(beta), 3))
        for j in range(3):
            e = np.zeros(3)
            e[j] = step
            d = self._beta(position + e) - self._beta(position - e)
            d = (d + np.pi / 2) % np.pi - np.pi / 2  # β is an axis: modulo π
            out[:, j] = d / (2 * step)
        return -2.0 * np.sin(2.0 * (beta - self.phases.measured))[:, None] * out

    def residuals(self, x: np.ndarray) -> np.ndarray:
        if self.phases is None:
            return sum(self._one.residuals(self.lamp_params(x, i)) for i in range(self.k)) - self._observed
        return sum((self._one.residuals(self.lamp_params(x, i)).reshape(-1, 3)
                    * self.weight(x[6 * i : 6 * i + 3])[:, None]).ravel() for i in range(self.k)) - self._observed

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """Analytic ``∂ residuals / ∂ x``, shape ``(n · 3, 6K + 1)``: each lamp's block, roughness columns summed.

        With ``phases``, lamp k's block is ``w_k J_k`` plus, in its position
        columns, its weighted radiance times ``∂w_k/∂l_k``.
        """
        J = np.zeros((len(self._observed), self.n_params))
        for i in range(self.k):
            p = self.lamp_params(x, i)
            Ji = self._one.jacobian(p)
            if self.phases is not None:
                Ji = Ji * np.repeat(self.weight(p[:3]), 3)[:, None]
                radiance = self._one.residuals(p).reshape(-1, 3)
                Ji[:, :3] += (radiance[:, :, None] * self._weight_gradient(p[:3])[:, None, :]).reshape(-1, 3)
            J[:, 6 * i : 6 * i + 6] = Ji[:, :6]
            J[:, -1] += Ji[:, 6]
        return J

    def linear_colours(self, x: np.ndarray) -> np.ndarray:
        """``x`` with the non-negative least-squares colours for its lamps and roughness (per channel, NNLS)."""
        ones = np.ones(3)
        D = np.stack([self._one.residuals(np.concatenate([x[6 * i : 6 * i + 3], ones, x[-1:]])).reshape(-1, 3)
                      * self.weight(x[6 * i : 6 * i + 3])[:, None]
                      for i in range(self.k)], axis=-1)  # (n, 3, K): weighted radiance per unit colour
        obs = self._observed.reshape(-1, 3)
        out = x.copy()
        for m in range(3):
            colour, _ = nnls(D[:, m, :], obs[:, m])
            out[[6 * i + 3 + m for i in range(self.k)]] = colour
        return out

    def lamp_peaks(self, x: np.ndarray) -> np.ndarray:
        """Each lamp's largest radiance over the pixels (weighted, if the model is), mean over channels, shape (K,)."""
        return np.array([np.max(self._one.residuals(self.lamp_params(x, i)).reshape(-1, 3).mean(axis=-1))
                         for i in range(self.k)])

    def chi2(self, x: np.ndarray) -> float:
        """Sum of squared (weighted) residuals at ``x``."""
        return float(np.sum(np.square(self.residuals(x))))
