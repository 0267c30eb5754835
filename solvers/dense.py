"""Solver family module (being written)."""
