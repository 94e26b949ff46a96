"""Measured and simulated records: one validated xarray schema (see schema.py)."""
