"""The seed-000 rig (Sharp IR range sensors and type-K thermocouples under a plate).

Modules (one concern each):

- :mod:`.sharp`: the Sharp IR voltage response of the three variants and its noise;
- :mod:`.plate`: heat diffusion in the plate and the thermocouple error model;
- :mod:`.scenarios`: the world scenarios of the seed's labs 2 and 3 (registered with
  :func:`hera.nodes.world.register_scenario`);
- :mod:`.driver`: the driver protocols a real ADC or thermocouple amplifier implements;
- :mod:`.sim`: the simulated boards; :mod:`.boards`: opening them for a node;
- :mod:`.measures`: the ``sharp_ir`` and ``thermocouple`` measures; :mod:`.tables`: error
  models from a measure's ``model`` argument.

The README ("Sharp IR tracking and the plate occupancy grid") lists every model, default
and source.
"""
