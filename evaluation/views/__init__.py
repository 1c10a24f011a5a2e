"""Views of finished results folders: the report and the regression check.

``report.py`` (verb ``report``) with its sections ``one_at_a_time.py`` and
``luck.py``; ``compare.py`` (verb ``compare``); ``cli.py`` the two verbs.
"""
