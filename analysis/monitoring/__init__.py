"""The monitors: DETECT-phase (and end-of-decide) components that measure a run from the world
snapshot, so a swapped controller is judged by the same signals.

One module per monitor: ``collisions`` (oriented-box overlap + SUMO's report), ``road`` (surrogate
safety and traffic KPIs), ``ramp_kpis``, ``ramp_meters``, ``overtaking``, ``segment_watch``,
``separation`` (UAV separation), ``air_pairs``, ``parking`` and ``stl_specs`` (the scenario's STL
specifications); ``tick_block`` is the block-of-ticks helper of the road monitors.  They are found by
name through the ``corridor.components`` entry points (``monitor.<name>``).
"""
