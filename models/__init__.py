"""Fusion models (thesis e4..e13 and the models of the other seed documents)."""
