"""Hera for Python: distributed, fault-tolerant sensor fusion on Eclipse Zenoh."""

__version__ = "0.1.0"
