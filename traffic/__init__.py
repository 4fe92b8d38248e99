"""corridor.traffic."""
