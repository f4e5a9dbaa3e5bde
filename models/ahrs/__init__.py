"""Attitude and heading (thesis ch. 7.1): the thesis's quaternion Kalman filter (e11) and our
multiplicative EKF, as the ``ahrs`` application."""
