"""Shipped scene files (``scenes/*.yaml``), installed with the package so that
``nearlight reproduce`` finds them from any working directory."""
