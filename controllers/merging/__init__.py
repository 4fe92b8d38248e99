"""V2X-cooperative on-ramp merging: the RSU crossing-order coordinator (``coordinator``), energy-optimal
ramp trajectories (``trajectory``), the virtual-vehicle safety layer (``safety_layer``); the engine
component (``components``)."""
