"""corridor: mixed road traffic and UAV scenario simulation.

The kernel (this package) holds the scenario schema and loader, the engine (clock, multi-rate
scheduler, hybrid-automaton modes), the world snapshot, the batch runner, the results store and the
CLI.  Domain code lives in ``corridor.traffic``, ``corridor.vehicles``, ``corridor.controllers`` and
``corridor.analysis``.
"""

from __future__ import annotations

__version__ = "0.1.0"
