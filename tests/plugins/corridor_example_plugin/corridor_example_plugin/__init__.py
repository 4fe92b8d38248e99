"""An example corridor plug-in (see its pyproject.toml)."""
