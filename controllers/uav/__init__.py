"""UAV avoidance: shared models (``models``), potential fields (``potential_field``), time-varying control
tubes (``control_tube``); the engine components (``components``)."""
