"""The sweep engine: sweep files expanded into tasks, each task run into one result row, resumable.

``sweep.py`` reads a sweep file into tasks; ``renderers.py`` renders a task's
scene (Mitsuba or analytic); ``tasks.py`` runs one task (render, observe,
estimate, score); ``run.py`` runs and resumes a whole sweep on ``workers.py``'s
executors; ``store.py`` keeps the rows; ``environment.py`` and
``provenance.py`` record where and from which code they came; ``cli.py`` is
the verb ``sweep``.
"""
