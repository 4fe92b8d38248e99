"""corridor.traffic: the road, first in the tick (the bottom domain: imports only the kernel).

``sumo/`` the SUMO backend and what it applies or writes; ``networks/`` the generated road networks;
``macro/`` the METANET model and the traffic centre's per-segment picture; ``sensing/`` loop
detectors and their faults; ``v2x`` cooperative-awareness messages.
"""
