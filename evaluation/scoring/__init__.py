"""Scoring one estimate against the truth of its capture: no estimator owns it.

``metrics.py``: the metrics, their column registry and :func:`score`;
``independent_resynthesis.py``: the specular image an estimate predicts,
written a second time on purpose (never shared with the estimator's own
re-synthesis); ``matching.py``: which estimated lamp is about which true one;
``crlb.py``: the Cramér–Rao bounds beside the errors.
"""
