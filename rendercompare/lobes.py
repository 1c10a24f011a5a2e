"""The Mitsuba BSDFs ``render-compare`` can fit, and how their roughness maps onto σ.

Each lobe is a Mitsuba BSDF dict whose specular part is scaled per colour
channel by Ks (solved in closed form, see :mod:`nearlight.rendercompare.method`)
and whose roughness ``alpha`` is a differentiable parameter (its key in
``mi.traverse``). Diffuse parts are switched off: the fit compares with a
separated specular image.

σ, the Torrance–Sparrow slope deviation of docs/physics.md, from a microfacet
``alpha`` at small roughness (tan θh ≈ θh):

- Beckmann: ``D ∝ exp(−tan²θh / α²)``, so ``exp(−θh² / 2σ²)`` with ``σ = α/√2``;
- GGX: ``D ∝ (α² + tan²θh)⁻² ≈ α⁻⁴ (1 − 2 tan²θh / α²) ≈ α⁻⁴ exp(−2θh² / α²)``
  near the peak, so ``σ = α/2``.

The project's own ``nearlight_bsdf`` (:mod:`nearlight.generator.bsdfs`) is not
in the table: it keeps its roughness and Ks as plain Python floats, which
Dr.Jit cannot differentiate, so it could give lamp gradients but no σ
gradient. The Beckmann conductor is the nearest differentiable lobe to it.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any


@dataclasses.dataclass(frozen=True)
class Lobe:
    """One Mitsuba BSDF as a specular lobe.

    Attributes
    ----------
    bsdf : dict
        The Mitsuba BSDF dict (``mi.load_dict``), without its roughness.
    alpha_key : str
        Key of the roughness ``alpha`` in ``mi.traverse`` of the loaded BSDF.
    sigma_per_alpha : float
        σ / alpha (radians per unit alpha) of the microfacet distribution.
    polarizing : bool
        Whether its Mueller matrix polarizes (then ``render-compare`` can
        model the lamp's polarizer); ``roughplastic`` returns a depolarizing
        matrix in polarized variants.
    """

    bsdf: dict[str, Any]
    alpha_key: str
    sigma_per_alpha: float
    polarizing: bool = True

    def sigma(self, alpha: float) -> float:
        """Torrance–Sparrow σ (radians) of microfacet roughness ``alpha``."""
        return alpha * self.sigma_per_alpha

    def alpha(self, sigma: float) -> float:
        """Microfacet roughness ``alpha`` of Torrance–Sparrow σ (radians)."""
        return sigma / self.sigma_per_alpha


BECKMANN = 1.0 / math.sqrt(2.0)
GGX = 0.5

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
    "beckmann": Lobe({"type": "roughconductor", "material": "none", "distribution": "beckmann"}, "alpha.value", BECKMANN),
    "ggx": Lobe({"type": "roughconductor", "material": "none", "distribution": "ggx"}, "alpha.value", GGX),
    "roughplastic": Lobe({"type": "roughplastic", "distribution": "beckmann", "diffuse_reflectance": 0.0}, "alpha",
                         BECKMANN, polarizing=False),
    "pplastic": Lobe({"type": "pplastic", "diffuse_reflectance": 0.0}, "alpha.value", BECKMANN),
}
