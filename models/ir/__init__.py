"""The seed-000 systems as an application: Sharp IR tracking and the plate occupancy grid.

- :mod:`.calibration`: the lab-1 power-law fits the models use (V = a d^b + c);
- :mod:`.tracker`: the lab-2 EKF on [d, d_dot] with raw voltages as measurements;
- :mod:`.thermal`: the thermal inverse model (where the hot block is, from the
  thermocouples); :mod:`.grid`: the lab-3 log-odds occupancy grid fusing IR and thermal;
- :mod:`.tiles`: the map as rows of at most 256 values on the bus;
- :mod:`.measures`: the models as fusion measures; :mod:`.app`: the application (truth,
  scores, plots, live panel; entry point ``ir``).
"""
