"""Method ``render-compare``: analysis by synthesis through Mitsuba 3 (an extra, ``nearlight[render]``).

The estimator (:mod:`nearlight.estimator`) never imports Mitsuba; this
package sits beside it and fits lamp position, Ks and roughness by gradient
descent through a Mitsuba BSDF (:mod:`nearlight.rendercompare.method`, its
lobes in :mod:`nearlight.rendercompare.lobes`). ``nearlight.estimator.estimate``
reaches it by name, ``method="render-compare"``, only when the renderer is
installed (docs/render-compare.md). Mitsuba and Dr.Jit are imported only
inside the functions that use them.
"""
