"""3-D position from sonars (thesis ch. 7.2): the thesis's e10 and our EKF on raw ranges,
as the ``position3d`` application."""
