"""Workflows built on the core: regression checks, stored-set generation, online simulation and
the fidelity study. Plugins are reached through the registries, never imported by name."""
