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

The filter (and beam) Mueller matrix of a propagation direction has one home,
shared by both emitters below; so has the sphere's visible cap.

Two independent routes, which the tests compare:

- ``nearlight_lamp`` (used for rendering): a point emitter returning the
  Stokes vector of unpolarized light of intensity ``I`` after that filter,
  ``I/2 · [1, cos 2φ, sin 2φ, 0]`` in Mitsuba's Stokes basis of each ray;
  works with ``path``. A sphere lamp is sampled by this emitter too, but
  flagged delta and without a shape: only shadow rays reach it, so a mirror
  (a delta BSDF, which only BSDF sampling can follow) shows no image of it.
- :func:`polarizer_sheet`: Mitsuba's unpolarized ``point`` emitter with a
  geometric ``polarizer`` rectangle 1 mm in front of it; shadow rays only pass
  a sheet with the ``volpath`` integrator (docs/physics.md, "Facts measured").

The intersectable sphere lamp (``polarized_lamp(..., intersectable=True)``) is
the sphere lamp a mirror can see: a Mitsuba ``sphere`` shape of radius ``a``
at the lamp (black diffuse BSDF: it reflects nothing) carrying the area
emitter ``nearlight_area_lamp``, a Python ``mi.Emitter`` nested in the shape's
dict as Mitsuba's own ``area`` emitter is (the shape calls its ``set_shape``
and the scene lists it among its emitters; flag ``EmitterFlags.Surface``). Its
radiance is ``L = I / (π a²)`` through the same filter and beam, along the
direction the light leaves the surface, and zero from inside the sphere.
Mitsuba's ``path`` reaches it in two ways, combined by multiple importance
sampling (power heuristic): emitter sampling (a point uniform in the solid
angle Ω of the visible cap, not delta: ``pdf = 1/Ω``, weight ``L·Ω`` times the
filter) and BSDF sampling (a ray that hits the sphere, weighted by the
emitter's ``pdf_direction``, the same ``1/Ω``). So a rough surface counts the
lamp once, and a perfect mirror (delta BSDF: no emitter sampling, MIS weight
1) shows the lamp's filtered radiance. As ``a → 0`` the emitter-sampled term
tends to the point lamp's ``I / d²`` and the BSDF-sampled one (solid angle
``π a² / d²``) vanishes from every non-delta BSDF (tested).
"""

from __future__ import annotations

import math
from types import ModuleType

import numpy as np

from ..physics.polarization import filter_axes

PLUGIN = "nearlight_lamp"
AREA_PLUGIN = "nearlight_area_lamp"


def register(mi: ModuleType) -> None:
    """Register ``nearlight_lamp`` and ``nearlight_area_lamp`` with the active Mitsuba variant."""
    import drjit as dr

    from .bsdfs import zero_struct

    scalar = mi.variant().startswith("scalar")

    class FilteredLamp(mi.Emitter):
        """What both lamps share: position, intensity, radius, filter and beam (the props of ``polarized_lamp``)."""

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

        def _emitted(self, forward, value):
            """Unpolarized ``value`` leaving along ``forward``, through the filter and the beam ``max(0, forward·a)^k``.

            Parameters
            ----------
            forward : mi.Vector3f
                Unit propagation direction of the emitted light (world).
            value : mi.Float
                What leaves the lamp before the filter: irradiance ``I/d²`` or ``L·Ω`` (W/m²) at the shaded point,
                or radiance ``L`` (W/(m² sr)).

            Returns
            -------
            mi.Spectrum
                Mueller matrix (Mitsuba's polarized spectrum) in ``mi.mueller.stokes_basis(forward)``.
            """
            absorb = mi.Vector3f(self.absorb)
            transmit = dr.cross(forward, dr.normalize(absorb - dr.dot(absorb, forward) * forward))
            # The polarizer in its own frame (x = effective transmission axis), rotated into the ray's Stokes basis.
            if self.extinction > 0:
                filt = mi.mueller.diattenuator(1.0, 1.0 / self.extinction)
            else:
                filt = mi.mueller.linear_polarizer(1.0)
            pol = mi.mueller.rotate_mueller_basis_collinear(filt, forward, transmit, mi.mueller.stokes_basis(forward))
            if self.k > 0:
                value *= dr.power(dr.maximum(dr.dot(forward, mi.Vector3f(self.beam)), 0.0), self.k)
            return mi.Spectrum(pol) * mi.depolarizer(mi.UnpolarizedSpectrum(value))

        def _cap(self, to_centre):
            """The sphere as seen from a point ``to_centre`` (m) away from its centre: the distance ``dc`` (m),
            ``cos θmax`` of its visible cap, and ``Ω / (π a²)`` (1/m², 0 inside the sphere).

            ``Ω = 2π (1 − cos θmax)`` is the cap's solid angle; ``L·Ω = I · Ω / (π a²)
            = I · 2 / (dc² (1 + cos θmax))``, by ``1 − cos θmax = (a/dc)² / (1 + cos θmax)``: no cancellation for a
            small lamp; it tends to ``I / dc²`` as ``a → 0``.
            """
            a = self.radius
            dc = dr.norm(to_centre)
            cos_max = dr.sqrt(dr.maximum(1.0 - dr.square(a / dc), 0.0))
            return dc, cos_max, dr.select(dc > a, 2.0 / (dr.square(dc) * (1.0 + cos_max)), 0.0)

        def _sample_sphere(self, it, sample, ds, to_centre):
            """A point of the sphere lamp seen from ``it``, uniform in the solid angle of its visible cap.

            Returns ``ds`` with ``p``, ``d`` and ``dist`` set, and ``Ω / (π a²)`` (:meth:`_cap`): the estimate of a
            uniform radiance ``L = I / (π a²)`` over the cone is ``L · Ω = I`` times that (the caller applies ``I``,
            the filter and the beam along the sampled direction). Zero inside the sphere.
            """
            a = self.radius
            dc, cos_max, scale = self._cap(to_centre)
            axis = to_centre / dc
            direction = mi.Frame3f(axis).to_world(mi.warp.square_to_uniform_cone(sample, cos_max))
            b = dr.dot(direction, to_centre)
            miss = dr.squared_norm(to_centre - b * direction)  # squared distance of the ray from the centre
            t = b - dr.sqrt(dr.maximum(a * a - miss, 0.0))
            ds.p = it.p + t * direction
            ds.dist = t
            ds.d = direction
            return ds, scale

        def to_string(self):
            return f"{type(self).__name__}[position={self.position}, intensity={self.intensity}, radius={self.radius}]"

    class PolarizedPointLamp(FilteredLamp):
        def __init__(self, props):
            super().__init__(props)
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
                value = dr.select(active, self.intensity * scale, 0.0)
            else:  # the point lamp, written as before the sphere existed (same rounding, bit for bit)
                value = dr.select(active, self.intensity / dr.square(ds.dist), 0.0)
            return ds, self._emitted(-ds.d, value)

        def pdf_direction(self, it, ds, active=True):
            return mi.Float(0.0)

        def eval_direction(self, it, ds, active=True):
            return dr.zeros(mi.Spectrum)

        def eval(self, si, active=True):
            return dr.zeros(mi.Spectrum)

    class AreaLamp(FilteredLamp):
        """The sphere lamp as an area emitter on a ``sphere`` shape of the same centre and radius (module doc)."""

        def __init__(self, props):
            super().__init__(props)
            if self.radius <= 0:
                raise ValueError(f"{AREA_PLUGIN}: radius must be > 0, got {self.radius}")
            self.radiance = self.intensity / (math.pi * self.radius**2)  # W/(m² sr), of a Lambertian sphere
            self.m_flags = mi.EmitterFlags.Surface

        def _pdf(self, scale):
            """Solid-angle density ``1/Ω`` (1/sr) of the cap, from :meth:`_cap`'s ``Ω / (π a²)``; 0 inside."""
            return dr.select(scale > 0, dr.rcp(math.pi * self.radius**2 * scale), 0.0)

        def sample_direction(self, it, sample, active=True):
            ds = zero_struct(mi, mi.DirectionSample3f)
            ds.time = it.time
            ds.delta = False
            centre = mi.Point3f(self.position)
            ds, scale = self._sample_sphere(it, sample, ds, centre - it.p)
            ds.n = dr.normalize(ds.p - centre)
            ds.pdf = dr.select(active, self._pdf(scale), 0.0)
            # as Mitsuba's area emitter does: scene.pdf_emitter_direction and eval_emitter_direction dispatch on it
            ds.emitter = self if scalar else mi.EmitterPtr(self)
            # weight = L · filter / pdf = I · Ω / (π a²) · filter
            return ds, self._emitted(-ds.d, dr.select(active, self.intensity * scale, 0.0))

        def pdf_direction(self, it, ds, active=True):
            _, _, scale = self._cap(mi.Point3f(self.position) - it.p)
            return dr.select(active & (dr.dot(ds.d, ds.n) < 0), self._pdf(scale), 0.0)

        def eval_direction(self, it, ds, active=True):
            return self._emitted(-ds.d, dr.select(active & (dr.dot(ds.d, ds.n) < 0), self.radiance, 0.0))

        def eval(self, si, active=True):
            outside = active & (mi.Frame3f.cos_theta(si.wi) > 0)
            return self._emitted(si.to_world(si.wi), dr.select(outside, self.radiance, 0.0))

    mi.register_emitter(PLUGIN, lambda props: PolarizedPointLamp(props))
    mi.register_emitter(AREA_PLUGIN, lambda props: AreaLamp(props))


def polarized_lamp(position, intensity: float, axis, facing, *, extinction_ratio: float | None = None,
                   anisotropy_k: float = 0.0, anisotropy_axis=None, radius: float = 0.0,
                   intersectable: bool = False) -> dict:  # fmt: skip
    """Mitsuba dict of the lamp: a polarized point emitter (the rendering route) or an intersectable sphere.

    Parameters
    ----------
    position, axis, facing : array_like, shape (3,)
        Lamp position (m), polarizer axis and the filter's normal (world).
    intensity : float
        Radiant intensity before the filter, one channel.
    extinction_ratio : float, optional
        The filter's ε; None is the ideal filter.
    anisotropy_k : float
        0 an isotropic lamp, else ``I·max(0, d·a)^k`` about ``anisotropy_axis`` (unit ``a``, default ``facing``).
    radius : float
        0 a point, else a sphere of that radius (m) with the same intensity, sampled once per sample.
    intersectable : bool
        False: the ``nearlight_lamp`` emitter (at the off values above, v1's dict exactly). True: a ``sphere``
        shape of ``radius`` at ``position`` (black BSDF) carrying the ``nearlight_area_lamp`` emitter, which
        BSDF-sampled rays (a mirror's) can hit; put it in the scene dict under the lamp's name all the same.

    Returns
    -------
    dict
        The emitter's dict, or ``{"type": "sphere", "center", "radius", "bsdf": black, "emitter": {...}}``.

    Raises
    ------
    ValueError
        ``intersectable`` with ``radius`` 0: a point has nothing to intersect.
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
    if not intersectable:
        return out
    if radius <= 0:
        raise ValueError(f"an intersectable lamp needs radius > 0, got {radius}")
    black = {"type": "diffuse", "reflectance": {"type": "uniform", "value": 0.0}}  # the lamp reflects nothing
    return {"type": "sphere", "center": out["position"], "radius": out["radius"], "bsdf": black,
            "emitter": {**out, "type": AREA_PLUGIN}}  # fmt: skip


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
