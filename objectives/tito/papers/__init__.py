"""Papers 000, 001 and 002 of the seeds table by table: printed values (printed.py) beside heurtune's
(other modules, written by someone else). The printed values are transcribed into
``experiments/printed/paper_<nnn>/*.csv`` (installed as ``heurtune.experiments/printed/...``), one file
per printed table or group of printed equations, each folder with a README.md that gives the format,
the seed line of every table and the remarks made while transcribing."""
