"""An LSM6DSL-like accelerometer + gyroscope (seed 003): the driver protocol, a simulator, the
``balancing`` scenario (a self-balancing robot), the gyro-bias calibration and the
``lsm6dsl`` measure."""
