"""Configuration: the scenario schema, its YAML reading, ``--set`` overrides and messages."""
