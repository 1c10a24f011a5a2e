"""The physics every stage shares, each formula written once (numpy only; imports no stage).

- :mod:`nearlight.physics.reflectance`: shading geometry, the Torrance–Sparrow
  (paper eq. 6) and Ward (eq. 19) BRDFs and their lobe-width conversion,
  Lambertian diffuse, specular and diffuse radiance of a point lamp, the mirror
  direction (eq. 8).
- :mod:`nearlight.physics.polarization`: the analyzer model in its two forms,
  the Stokes fit, separation into specular and diffuse, DoLP/AoLP, the lamp
  polarizer's halving.
- :mod:`nearlight.physics.camera`: pinhole rays and their projection, the
  ``saturation: auto`` exposure, vignetting and the response curve (and its inverse).
- :mod:`nearlight.physics.texture`: the checker texture of albedo and roughness.

Conventions: ``docs/physics.md``.
"""
