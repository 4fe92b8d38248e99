"""corridor.controllers."""
