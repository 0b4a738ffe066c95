"""Optimiser plugins, one module per algorithm (imported as ``heurtune.algorithms``)."""
