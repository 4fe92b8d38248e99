"""corridor.analysis."""
