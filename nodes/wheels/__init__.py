"""Wheel encoders of the balancing robot: driver protocol, simulator, ``wheel_encoder`` measure."""
