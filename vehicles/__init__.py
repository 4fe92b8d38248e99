"""corridor.vehicles."""
