"""2-D tilt of a self-balancing robot from an accelerometer and a gyroscope (seed 003): the
seed's split filter, a full EKF and a UKF on the same equations (eqs. 25-26), and the
seed's future work, a filter that estimates the gyroscope bias as a third state."""
