"""Estimator: lamp position and specular reflectance from one capture (numpy/scipy only)."""
