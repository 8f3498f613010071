"""Numba-jitted physics core: one module per sub-model, composed by ``kernel``."""
