"""ST VL53L1 time-of-flight range sensors (seed 001): the driver protocol, a simulator, the
``desk`` scenario (a board raised, lowered and tilted over a desk) and the ``vl53l1``
measure."""
