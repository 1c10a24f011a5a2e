"""The paper reproduction (verb ``reproduce``): the paper's experiments as sweep files, run by the engine.

``reproduce.py`` runs them and writes the JSON document; ``markdown.py`` the
report from it; ``check.py`` compares two runs (``--against``);
``fidelity.py`` the analytic tables of why the paper's first stage errs;
``cli.py`` the verb.
"""
