"""The lamp: a point source behind a linear polarizer filter (ideal unless asked).

The filter is a flat sheet right in front of the lamp, facing the object
(normal: lamp → ``object.position``), with its transmission axis
``polarizer_axis`` projected into the sheet's plane (:func:`filter_axes`). For
rays leaving the lamp obliquely through the sheet, the effective transmission
axis follows Korger et al. 2013 ("The polarization properties of a tilted
polarizer"), as Mitsuba's ``polarizer`` does: ``t_eff = k × â``, with ``â`` the
sheet's absorbing axis projected normal to the ray direction ``k``.

Two nuisances of the lamp are rendered by the emitter (both off by default,
and then the emitter computes exactly what it did without them):

- the filter's extinction ratio ε: a linear diattenuator with principal
  intensity transmittances 1 and 1/ε (``mi.mueller.diattenuator(1, 1/ε)``:
  measured, its arguments are intensity transmittances, ``M00 = (x + y)/2``,
  ``M22 = √(xy)``) instead of the ideal polarizer; the
  light after it is ``I/2 · [1 + 1/ε, (1 − 1/ε) cos 2φ, (1 − 1/ε) sin 2φ, 0]``;
- anisotropy: the radiant intensity leaving along the unit direction ``d`` is
  ``I · max(0, d·a)^k`` about the unit axis ``a`` (an LED's or a reflector
  lamp's beam; ``k = 0`` is isotropic);
- size: a sphere of radius ``a`` emitting uniformly (radiance ``I / (π a²)``,
  so its intensity is ``I`` in every direction), behind the same filter. Each
  sample picks one point of the sphere, uniformly in the solid angle it
  subtends, so ``capture.spp`` now averages over the lamp too (Monte Carlo:
  relative noise about ``Δ/√spp``, Δ the variation of the BRDF across the
  lamp's angular size); a fully visible sphere gives a Lambertian surface the
  point lamp's irradiance, and the sphere shrinks to the point lamp as
  ``a → 0`` (tested). Shadows of a sphere lamp are soft (each sample's shadow
  ray goes to its own point).

Two independent routes, which the tests compare:

- ``nearlight_lamp`` (used for rendering): a point emitter returning the
  Stokes vector of unpolarized light of intensity ``I`` after that filter,
  ``I/2 · [1, cos 2φ, sin 2φ, 0]`` in Mitsuba's Stokes basis of each ray;
  works with ``path``.
- :func:`polarizer_sheet`: Mitsuba's unpolarized ``point`` emitter with a
  geometric ``polarizer`` rectangle 1 mm in front of it; shadow rays only pass
  a sheet with the ``volpath`` integrator (docs/physics.md, "Facts measured").
"""

from __future__ import annotations

from types import ModuleType

import numpy as np

from ..physics.polarization import filter_axes

PLUGIN = "nearlight_lamp"


def register(mi: ModuleType) -> None:
    """Register ``nearlight_lamp`` with the active Mitsuba variant."""
    import drjit as dr

    from .bsdfs import zero_struct

    class PolarizedPointLamp(mi.Emitter):
        def __init__(self, props):
            super().__init__(props)
            self.position = mi.ScalarPoint3f(props.get("position"))
            self.intensity = float(props.get("intensity", 1.0))
            # absorbing axis of the filter, in its plane (normal to "facing")
            self.absorb = mi.ScalarVector3f(filter_axes(props.get("axis"), props.get("facing"))[1])
            self.extinction = float(props.get("extinction_ratio", 0.0))  # 0: ideal
            self.k = float(props.get("anisotropy_k", 0.0))
            self.beam = mi.ScalarVector3f(props.get("anisotropy_axis", [0.0, 0.0, 1.0]))
            self.radius = float(props.get("radius", 0.0))
            # Also a sphere lamp is flagged delta: its one sampled point per sample is the whole estimate (no shape
            # for BSDF-sampled rays to hit, so no MIS and nothing counted twice).
            self.m_flags = mi.EmitterFlags.DeltaPosition

        def sample_direction(self, it, sample, active=True):
            ds = zero_struct(mi, mi.DirectionSample3f)
            ds.p = mi.Point3f(self.position)
            ds.time = it.time
            ds.pdf = 1.0
            ds.delta = True
            d = ds.p - it.p
            ds.dist = dr.norm(d)
            ds.d = d / ds.dist
            if self.radius > 0:
                ds, scale = self._sample_sphere(it, sample, ds, d)
            forward = -ds.d  # propagation direction of the emitted light
            absorb = mi.Vector3f(self.absorb)
            transmit = dr.cross(forward, dr.normalize(absorb - dr.dot(absorb, forward) * forward))
            # The polarizer in its own frame (x = effective transmission axis), rotated into the ray's Stokes basis.
            if self.extinction > 0:
                filt = mi.mueller.diattenuator(1.0, 1.0 / self.extinction)
            else:
                filt = mi.mueller.linear_polarizer(1.0)
            pol = mi.mueller.rotate_mueller_basis_collinear(filt, forward, transmit, mi.mueller.stokes_basis(forward))
            if self.radius > 0:
                value = dr.select(active, self.intensity * scale, 0.0)
            else:  # the point lamp, written as before the sphere existed (same rounding, bit for bit)
                value = dr.select(active, self.intensity / dr.square(ds.dist), 0.0)
            if self.k > 0:
                value *= dr.power(dr.maximum(dr.dot(forward, mi.Vector3f(self.beam)), 0.0), self.k)
            return ds, mi.Spectrum(pol) * mi.depolarizer(mi.UnpolarizedSpectrum(value))

        def _sample_sphere(self, it, sample, ds, to_centre):
            """A point of the sphere lamp seen from ``it``, uniform in the solid angle of its visible cap.

            Radiance ``L = I / (π a²)`` (a uniform Lambertian sphere of intensity ``I``) over the cone's solid angle
            ``Ω = 2π (1 − cos θmax)``: the estimate is ``L · Ω`` times the lamp's polarizer (and beam) along the
            sampled direction; it tends to ``I / d²`` as ``a → 0``. Zero inside the sphere.
            """
            a = self.radius
            dc = dr.norm(to_centre)
            axis = to_centre / dc
            cos_max = dr.sqrt(dr.maximum(1.0 - dr.square(a / dc), 0.0))
            direction = mi.Frame3f(axis).to_world(mi.warp.square_to_uniform_cone(sample, cos_max))
            b = dr.dot(direction, to_centre)
            miss = dr.squared_norm(to_centre - b * direction)  # squared distance of the ray from the centre
            t = b - dr.sqrt(dr.maximum(a * a - miss, 0.0))
            ds.p = it.p + t * direction
            ds.dist = t
            ds.d = direction
            # L·Ω = I/(π a²) · 2π (1 − cos θmax) = I · 2 / (dc² (1 + cos θmax)),
            # by 1 − cos θmax = (a/dc)² / (1 + cos θmax): no cancellation for a small lamp (the caller applies I)
            return ds, dr.select(dc > a, 2.0 / (dr.square(dc) * (1.0 + cos_max)), 0.0)

        def pdf_direction(self, it, ds, active=True):
            return mi.Float(0.0)

        def eval_direction(self, it, ds, active=True):
            return dr.zeros(mi.Spectrum)

        def eval(self, si, active=True):
            return dr.zeros(mi.Spectrum)

        def to_string(self):
            return f"PolarizedPointLamp[position={self.position}, intensity={self.intensity}]"

    mi.register_emitter(PLUGIN, lambda props: PolarizedPointLamp(props))


def polarized_lamp(position, intensity: float, axis, facing, *, extinction_ratio: float | None = None,
                   anisotropy_k: float = 0.0, anisotropy_axis=None, radius: float = 0.0) -> dict:  # fmt: skip
    """Mitsuba dict of the lamp as a polarized point emitter (the rendering route).

    ``extinction_ratio`` None is the ideal filter; ``anisotropy_k`` 0 an
    isotropic lamp, else ``I·max(0, d·a)^k`` about ``anisotropy_axis`` (unit
    ``a``, default ``facing``); ``radius`` 0 a point, else a sphere of that
    radius (m) with the same intensity, sampled once per sample. At those off
    values the dict is v1's exactly.
    """
    out = {"type": PLUGIN, "position": list(map(float, position)), "intensity": float(intensity),
           "axis": list(map(float, axis)), "facing": list(map(float, facing))}  # fmt: skip
    if extinction_ratio is not None:
        out["extinction_ratio"] = float(extinction_ratio)
    if anisotropy_k > 0:
        a = np.asarray(facing if anisotropy_axis is None else anisotropy_axis, float)
        out["anisotropy_k"] = float(anisotropy_k)
        out["anisotropy_axis"] = (a / np.linalg.norm(a)).tolist()
    if radius > 0:
        out["radius"] = float(radius)
    return out


def polarizer_sheet(mi: ModuleType, position, intensity: float, axis, facing, *, gap: float = 1e-3,
                    half_size: float = 0.05) -> dict[str, dict]:  # fmt: skip
    """Mitsuba dicts of the lamp as an unpolarized point light behind a polarizer sheet.

    Parameters
    ----------
    mi : module
    position, axis : array_like, shape (3,)
        Lamp position (metres) and polarizer axis (world).
    intensity : float
        Radiant intensity before the polarizer, one channel.
    facing : array_like, shape (3,)
        The sheet's normal (from the lamp towards the object).
    gap, half_size : float
        Distance from the lamp to the sheet and the sheet's half width, metres:
        a 1 mm gap and 5 cm half width cover 88° around ``toward``.

    Returns
    -------
    dict
        ``{"lamp": point emitter, "lamp_sheet": polarizer rectangle}``; render with ``volpath``.
    """
    position = np.asarray(position, float)
    normal = np.asarray(facing, float) / np.linalg.norm(facing)
    x, y = filter_axes(axis, normal)  # Mitsuba's polarizer absorbs along its local y
    frame = np.eye(4)
    frame[:3, 0], frame[:3, 1], frame[:3, 2] = x * half_size, y * half_size, normal
    frame[:3, 3] = position + gap * normal
    return {
        "lamp": {"type": "point", "position": position.tolist(), "intensity": {"type": "uniform", "value": intensity}},
        "lamp_sheet": {"type": "rectangle", "to_world": mi.ScalarTransform4f(frame.tolist()),
                       "bsdf": {"type": "polarizer", "theta": 0.0}},
    }  # fmt: skip
