"""Files people and tools see, for every stage: output places (what may be created or
replaced), YAML input, JSON-ready values, dotted keys into YAML documents, PNG figures.

Imports no pipeline stage.
"""
