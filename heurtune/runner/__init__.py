"""Running experiments: configs (``experiments/*.toml``), the experiment runner
(``python -m heurtune.experiment``) and the evaluate command (``python -m heurtune.evaluate``)."""
