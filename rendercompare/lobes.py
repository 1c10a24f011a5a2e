"""The Mitsuba BSDFs ``render-compare`` can fit, and how their roughness maps onto σ.

Each lobe is a Mitsuba BSDF dict whose specular part is scaled per colour
channel by Ks (solved in closed form, see :mod:`nearlight.rendercompare.method`)
and whose roughness ``alpha`` is a differentiable parameter (its key in
``mi.traverse``). Diffuse parts are switched off: the fit compares with a
separated specular image.

σ, the Torrance–Sparrow slope deviation of docs/physics.md, from a microfacet
``alpha`` is :func:`nearlight.physics.reflectance.mitsuba_ts_sigma` of the
lobe's dict (Beckmann ``α/√2``, GGX ``α/2``, the small-angle widths of
:data:`nearlight.physics.reflectance.LOBES`), the σ the evaluation compares
with for a capture rendered in that Mitsuba material.

The project's own ``nearlight_bsdf`` (:mod:`nearlight.generator.bsdfs`) is not
in the table: it keeps its roughness and Ks as plain Python floats, which
Dr.Jit cannot differentiate, so it could give lamp gradients but no σ
gradient. The Beckmann conductor is the nearest differentiable lobe to it.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from ..physics.reflectance import mitsuba_ts_sigma


@dataclasses.dataclass(frozen=True)
class Lobe:
    """One Mitsuba BSDF as a specular lobe.

    Attributes
    ----------
    bsdf : dict
        The Mitsuba BSDF dict (``mi.load_dict``), without its roughness.
    alpha_key : str
        Key of the roughness ``alpha`` in ``mi.traverse`` of the loaded BSDF.
    polarizing : bool
        Whether its Mueller matrix polarizes (then ``render-compare`` can
        model the lamp's polarizer); ``roughplastic`` returns a depolarizing
        matrix in polarized variants.
    """

    bsdf: dict[str, Any]
    alpha_key: str
    polarizing: bool = True

    @property
    def sigma_per_alpha(self) -> float:
        """σ / alpha (radians per unit alpha) of the microfacet distribution (σ is linear in alpha)."""
        return mitsuba_ts_sigma({**self.bsdf, "alpha": 1.0})

    def sigma(self, alpha: float) -> float:
        """Torrance–Sparrow σ (radians) of microfacet roughness ``alpha``."""
        return alpha * self.sigma_per_alpha

    def alpha(self, sigma: float) -> float:
        """Microfacet roughness ``alpha`` of Torrance–Sparrow σ (radians)."""
        return sigma / self.sigma_per_alpha


#: The lobes by name (option ``bsdf`` of ``render-compare``). Conductors with
#: ``material: none`` reflect everything (Fresnel factor 1); the plastics keep
#: their dielectric Fresnel factor (index 1.49 in Mitsuba), so their lobe
#: tilts with the angle of incidence as a real dielectric's does. Measured
#: (Mitsuba 3.9.1, the §4.1 board at alpha = 0.14): ``pplastic``'s lobe (M00)
#: is the Beckmann conductor's to 0.2 % down to 45 % of its peak, where the
#: GGX conductor's is at 31 %: so ``pplastic`` maps as Beckmann. ``roughplastic``
#: predicts no polarized light (its Mueller matrix depolarizes: the fit with
#: the lamp's polarizer saw a zero lobe), so it is fitted unpolarized.
LOBES: dict[str, Lobe] = {
    "beckmann": Lobe({"type": "roughconductor", "material": "none", "distribution": "beckmann"}, "alpha.value"),
    "ggx": Lobe({"type": "roughconductor", "material": "none", "distribution": "ggx"}, "alpha.value"),
    "roughplastic": Lobe({"type": "roughplastic", "distribution": "beckmann", "diffuse_reflectance": 0.0}, "alpha",
                         polarizing=False),
    "pplastic": Lobe({"type": "pplastic", "diffuse_reflectance": 0.0}, "alpha.value"),
}
