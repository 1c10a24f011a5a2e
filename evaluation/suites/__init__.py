"""Benchmark suites (verbs ``suite build``, ``suite verify``, ``score``): frozen captures and scorecards.

``suite.py`` reads suite files, builds and verifies suites (manifest,
checksums, digests); ``scorecard.py`` scores a method on a built suite;
``cli.py`` the verbs.
"""
