"""The bottom layer: errors, registries, parameter-model bases, streams, limits, files, threads."""
