"""Road sensing: the beltway's loop detectors and ramp queues (``detectors``, SENSE phase) and loop
faults as a scenario input (``loop_faults``).
"""
