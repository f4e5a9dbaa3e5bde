"""The 6-DOF IMU (thesis ch. 7.3): position from the accelerometer turned into the world by
the AHRS, with the sonars' position when there is one, as the ``imu6dof`` application."""
