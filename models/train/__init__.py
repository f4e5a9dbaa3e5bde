"""The toy train of thesis ch. 6, as an application: the model ladder e4 .. e9.

- :mod:`.tracker`: the EKF of each rung (:class:`~.tracker.TrainTracker`);
- :mod:`.bilateration`: a position from two sonar circles; :mod:`.beams`: sonar cones;
- :mod:`.measures`: the models as fusion measures (entry points ``omega_acc`` .. ``track_mag``,
  aliases ``e4`` .. ``e9``);
- :mod:`.app`: the application (truth, scores, plots, live panel; entry point ``train``).
"""
