"""Evaluation: estimates against the truth, at scale. One folder per job (docs/architecture.md):

- ``engine/``: a sweep file expanded into tasks, each task rendered, observed,
  estimated and scored into one result row, resumable, on local workers or a
  Dask cluster (verb ``sweep``);
- ``scoring/``: one estimate against the truth of its capture: the metrics,
  the grader's own re-synthesis of the specular image, lamp matching, the
  Cramér–Rao bounds;
- ``views/``: what a finished results folder says: the report and the
  regression check (verbs ``report``, ``compare``);
- ``paper/``: the paper's experiments as sweep files, their report and its
  check (verb ``reproduce``);
- ``gsa/``: global sensitivity analysis on the engine (verb ``gsa``);
- ``suites/``: frozen benchmark suites and scorecards (verbs ``suite``, ``score``).

Beside them, ``planted.py``: a plug-in method that makes a built-in one worse
by a known amount, named in sweep files as
``nearlight.evaluation.planted:further_along_ray``.
"""
