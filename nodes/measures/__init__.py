"""The board measures: ``nav``, ``mag``, ``nav3`` (:mod:`.nav`) and ``sonar`` (:mod:`.sonar`).

They reach boards only through the driver protocols of :mod:`hera.nodes.driver`, so a real
driver can take the simulator's place (the measure arg ``driver``, see
:mod:`hera.nodes.boards`).
"""
