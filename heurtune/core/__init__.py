"""The core: the optimiser and plant-family registries, plugins, the engine, the evaluator and
its execution layer, the tuning-problem contract, the config schema language, files and errors.
Nothing here knows a plant."""
