"""Files people and tools see, for every stage: output places (what may be created or
replaced), atomic writes of files and folders, content digests, YAML input, validated
documents, JSON-ready values, dotted keys into YAML documents, Markdown tables, PNG figures.

Imports no pipeline stage.
"""
