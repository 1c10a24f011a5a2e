"""Evaluation: sweeps, metrics, tables, plots, regression checks and the paper reproduction."""
