"""Height (and tilt) of a board over a desk from VL53L1 time-of-flight sensors (seed 001):
the seed's constant-velocity and constant-acceleration filters on the centre sensor, its
three-sensor fusion, and the board's height, pitch and roll from the three ranges, with
invalid readings, outliers and stuck or dead sensors caught and reported."""
