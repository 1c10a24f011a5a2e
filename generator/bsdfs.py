"""Polarized BSDF plugins: Torrance–Sparrow (paper eq. 6), Ward (eq. 19), GGX and Beckmann microfacet lobes.

``nearlight_bsdf`` is one Mitsuba BSDF returning Mueller matrices in polarized
variants: a specular lobe (``model`` ``torrance_sparrow``, ``ward``, ``ggx`` or
``beckmann``, the BRDFs of :mod:`nearlight.physics.reflectance`, written again
in Dr.Jit; ``tests/generator/test_physics.py`` holds the two together) plus a Lambertian, fully depolarizing
diffuse lobe ``kd / π``. Every parameter is a plain number (one colour
channel: the generator renders once per channel).

Polarization of the specular lobe (``polarization``):

- ``ideal``: the non-depolarizing mirror ``diag(1, 1, -1, -1)`` in the
  microfacet's s/p frame (a perfect conductor; the paper's assumption, so that
  ``Imax - Imin = Is``);
- ``fresnel``: Mitsuba's dielectric Fresnel Mueller matrix for index ``eta``
  at the microfacet (half-vector) angle, divided by its ``M00`` so that the
  unpolarized reflectance is 1 and the scalar lobe is unchanged.

The s/p frame is rotated into Mitsuba's implicit Stokes bases of the incident
and outgoing directions exactly as Mitsuba's ``roughconductor`` does.

Sampling draws cosine-weighted directions (valid for any BRDF; only paths
with more than one bounce use it, since the lamp is a delta light).
"""

from __future__ import annotations

import math
from types import ModuleType

PLUGIN = "nearlight_bsdf"
MODELS = ("torrance_sparrow", "ward", "ggx", "beckmann")
POLARIZATIONS = ("ideal", "fresnel")


def zero_struct(mi: ModuleType, cls: type):
    """A zero-initialised Mitsuba record: ``dr.zeros`` in JIT variants, the constructor in scalar ones."""
    import drjit as dr

    return cls() if mi.variant().startswith("scalar") else dr.zeros(cls)


def register(mi: ModuleType) -> None:
    """Register ``nearlight_bsdf`` with the active Mitsuba variant."""
    import drjit as dr

    complex_type = dr.scalar.Complex2f if mi.variant().startswith("scalar") else dr.llvm.ad.Complex2f

    def smith_g1(cos_t, a: float, distribution: str):
        """Smith's masking (:func:`nearlight.physics.reflectance.smith_g1`)."""
        tan2 = dr.maximum(1.0 - dr.square(cos_t), 0.0) / dr.square(cos_t)
        if distribution == "ggx":
            return 2.0 / (1.0 + dr.sqrt(1.0 + a * a * tan2))
        x = dr.rsqrt(a * a * tan2)
        return dr.select(x >= 1.6, 1.0, (3.535 * x + 2.181 * x * x) / (1.0 + 2.276 * x + 2.577 * x * x))

    def specular_lobe(model: str, rough: float, ks: float, cos_i, cos_r, cos_h):
        """``f · cos θi`` of the specular BRDF (paper eq. 6 or 19, or a microfacet lobe), per channel."""
        if model == "torrance_sparrow":
            alpha = dr.acos(dr.clip(cos_h, -1.0, 1.0))
            return ks * dr.exp(-dr.square(alpha) / (2.0 * rough * rough)) / cos_r
        c2 = dr.square(cos_h)
        tan2 = (1.0 - c2) / c2
        if model == "ward":
            return ks * dr.exp(-tan2 / (rough * rough)) / (4.0 * math.pi * rough * rough) * dr.sqrt(cos_i / cos_r)
        if model == "ggx":
            d = rough * rough / (math.pi * dr.square((rough * rough - 1.0) * c2 + 1.0))
        else:
            d = dr.exp(-tan2 / (rough * rough)) / (math.pi * rough * rough * c2 * c2)
        return ks * d * smith_g1(cos_i, rough, model) * smith_g1(cos_r, rough, model) / (4.0 * cos_r)

    class NearlightBSDF(mi.BSDF):
        def __init__(self, props):
            super().__init__(props)
            self.model = props.get("model", "torrance_sparrow")
            self.polarization = props.get("polarization", "ideal")
            if self.model not in MODELS or self.polarization not in POLARIZATIONS:
                raise ValueError(f"{PLUGIN}: bad model {self.model!r} or polarization {self.polarization!r}")
            self.ks = float(props.get("ks", 0.0))
            self.rough = float(props.get("roughness", 0.1))
            self.kd = float(props.get("kd", 0.0))
            self.eta = float(props.get("eta", 1.5))
            # The checker texture of nearlight.physics.texture (its numpy twin; a test holds them together).
            self.period = float(props.get("texture_period", 0.0))  # 0: untextured
            if self.period > 0:
                self.kd_contrast = float(props.get("kd_contrast", 0.0))
                self.rough_contrast = float(props.get("roughness_contrast", 0.0))
                self.tex_origin = mi.ScalarPoint3f(props.get("texture_origin"))
                self.tex_axes = [mi.ScalarVector3f(props.get(f"texture_{a}")) for a in "xyz"]
            flags = mi.BSDFFlags.FrontSide
            if self.ks > 0:
                flags |= mi.BSDFFlags.GlossyReflection
            if self.kd > 0:
                flags |= mi.BSDFFlags.DiffuseReflection
            self.m_flags = flags
            self.m_components = [flags]

        def _mueller(self, wo_hat, wi_hat, h):
            """Specular Mueller matrix, light arriving along ``-wo_hat`` and leaving along ``wi_hat``."""
            if self.polarization == "ideal":
                m = mi.Matrix4f(1.0)
                m[2, 2] = -1.0
                m[3, 3] = -1.0
            else:
                m = mi.mueller.specular_reflection(dr.abs(dr.dot(wo_hat, h)), complex_type(self.eta, 0.0))
                m = m * dr.rcp(m[0, 0])
            s_in = dr.cross(h, -wo_hat)
            s_out = dr.cross(h, wi_hat)
            collinear = dr.all(s_in == mi.Vector3f(0.0))
            s_in = dr.select(collinear, mi.Vector3f(1, 0, 0), dr.normalize(s_in))
            s_out = dr.select(collinear, mi.Vector3f(1, 0, 0), dr.normalize(s_out))
            return mi.mueller.rotate_mueller_basis(
                m,
                -wo_hat, s_in, mi.mueller.stokes_basis(-wo_hat),
                wi_hat, s_out, mi.mueller.stokes_basis(wi_hat),
            )  # fmt: skip

        def _sign(self, p):
            """The checker's sign (±1) at world point ``p``."""
            q = p - mi.Point3f(self.tex_origin)
            k = sum(dr.floor(dr.dot(q, mi.Vector3f(a)) / self.period + 0.25) for a in self.tex_axes)
            return 1.0 - 2.0 * (k - 2.0 * dr.floor(k / 2.0))

        def eval(self, ctx, si, wo, active=True):
            cos_i = mi.Frame3f.cos_theta(wo)
            cos_r = mi.Frame3f.cos_theta(si.wi)
            active = active & (cos_i > 0.0) & (cos_r > 0.0)
            value = dr.zeros(mi.Spectrum)
            kd, rough = self.kd, self.rough
            if self.period > 0:
                s = self._sign(si.p)
                kd, rough = kd * (1.0 + self.kd_contrast * s), rough * (1.0 + self.rough_contrast * s)
            if self.ks > 0:
                h = dr.normalize(wo + si.wi)
                lobe = specular_lobe(self.model, rough, self.ks, cos_i, cos_r, h.z)
                radiance = ctx.mode == mi.TransportMode.Radiance
                wo_hat = wo if radiance else si.wi
                wi_hat = si.wi if radiance else wo
                value += mi.Spectrum(self._mueller(wo_hat, wi_hat, h) * dr.select(active, lobe, 0.0))
            if self.kd > 0:
                value += mi.depolarizer(mi.UnpolarizedSpectrum(dr.select(active, kd / math.pi * cos_i, 0.0)))
            return value

        def pdf(self, ctx, si, wo, active=True):
            ok = active & (mi.Frame3f.cos_theta(si.wi) > 0.0)
            return dr.select(ok, mi.warp.square_to_cosine_hemisphere_pdf(wo), 0.0)

        def eval_pdf(self, ctx, si, wo, active=True):
            return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

        def sample(self, ctx, si, sample1, sample2, active=True):
            bs = zero_struct(mi, mi.BSDFSample3f)
            bs.wo = mi.warp.square_to_cosine_hemisphere(sample2)
            bs.pdf = mi.warp.square_to_cosine_hemisphere_pdf(bs.wo)
            bs.eta = 1.0
            bs.sampled_type = mi.UInt32(+mi.BSDFFlags.GlossyReflection)
            bs.sampled_component = mi.UInt32(0)
            active = active & (mi.Frame3f.cos_theta(si.wi) > 0.0) & (bs.pdf > 0.0)
            weight = self.eval(ctx, si, bs.wo, active) * dr.select(active, dr.rcp(bs.pdf), 0.0)
            return bs, weight

        def to_string(self):
            return f"NearlightBSDF[model={self.model}, ks={self.ks}, roughness={self.rough}, kd={self.kd}]"

    mi.register_bsdf(PLUGIN, lambda props: NearlightBSDF(props))
