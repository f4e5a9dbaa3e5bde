"""Fault-injection campaigns: ``hera campaign SPEC CAMPAIGN`` (README "Fault campaigns").

A campaign starts a cluster (or attaches to one), strikes a schedule of faults at it,
records what happened and judges the record with checkers, the way Jepsen does. One concern
per module:

- :mod:`~hera.campaign.schema`: the campaign file (declared settings);
- :mod:`~hera.campaign.plan`: the schedule, scripted or drawn by a nemesis from the seed;
- :mod:`~hera.campaign.targets`: who a fault hits (names and roles: the sync leader ...);
- :mod:`~hera.campaign.actuators`: how each fault is done and undone;
- :mod:`~hera.campaign.linkproxy`, :mod:`~hera.campaign.links`: the link proxy between
  nodes (partitions, loss, delay, resets) and its plan;
- :mod:`~hera.campaign.recorder`, :mod:`~hera.campaign.journal`: what the campaign records;
- :mod:`~hera.campaign.history`: every record read back;
- :mod:`~hera.campaign.analysis`, :mod:`~hera.campaign.estimates`: figures per stream and
  fault, estimate errors through the applications;
- :mod:`~hera.campaign.checkers`: the verdicts; :mod:`~hera.campaign.report`: the report;
- :mod:`~hera.campaign.runner`: the command; :mod:`~hera.campaign.manual`: ``hera inject``'s
  board, clock and network faults.

The campaign names no application: it asks the spec which measures audit their firings
(a ``fire_log`` argument) and which are fusion models, and the applications for truth and
scores.
"""
