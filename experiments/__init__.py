"""Experiment configs (``<algorithm>_<controller>_<plant>.toml``), shipped as package data."""
