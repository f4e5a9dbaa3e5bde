"""Measures that ship with the framework itself (observers for fault-tolerance runs)."""
