"""Core: conventions, errors, parameters, protocols, registry, specs, I/O, cache, pipeline."""
