"""What is done with results: statistics (``python -m heurtune.compare``), anytime measures,
exports, the HTML report and the figures."""
