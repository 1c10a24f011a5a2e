"""Global sensitivity analysis (verb ``gsa``): sampled designs run on the sweep engine, SALib's indices.

``study.py`` reads a GSA file, samples its designs and analyses the rows;
``report.py`` writes a design's report; ``cli.py`` the verb.
"""
