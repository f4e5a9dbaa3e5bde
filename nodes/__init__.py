"""Simulated boards, the world they sense, and the board driver interface.

Modules (one concern each):

- :mod:`hera.nodes.driver`: the NavDriver / SonarDriver protocols a real board implements;
- :mod:`hera.nodes.world`: scenarios as pure functions of time, :func:`~hera.nodes.world.truth_at`;
- :mod:`hera.nodes.geometry`: vectors and quaternions; :mod:`hera.nodes.noise`: keyed RNG;
- :mod:`hera.nodes.imu_model`, :mod:`hera.nodes.sonar_model`: the error models;
- :mod:`hera.nodes.sim_nav`, :mod:`hera.nodes.sim_sonar`: the simulated boards;
- :mod:`hera.nodes.air`: sonar cross-talk over the bus;
- :mod:`hera.nodes.fault_model`, :mod:`hera.nodes.faults`: run-time board faults;
- :mod:`hera.nodes.boards`: the boards of a node, shared by its measures;
- :mod:`hera.nodes.calibration`, :mod:`hera.nodes.truth`;
- :mod:`hera.nodes.measures`: the board measures (nav, mag, nav3, sonar);
- :mod:`hera.nodes.app`: the simulator as an application (the `board` control verb).

The README ("Simulated boards and their error models") lists every model, default and source.
"""
