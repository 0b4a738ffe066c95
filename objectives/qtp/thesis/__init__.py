"""The thesis' printed tables and heurtune's reproduction of them (Chapters 4-6).

* :mod:`heurtune.objectives.qtp.thesis.printed`: the printed values as data (``printed_table("4.3")``).
* :mod:`heurtune.objectives.qtp.thesis.tables`: ``write_chapter(chapter, exp, out_dir)`` writes each of a
  chapter's tables with the printed values, heurtune's and their differences.
* :mod:`heurtune.objectives.qtp.thesis.figures`: the chapter's response overlays, convergence curves and Bode
  plots.
"""

from heurtune.objectives.qtp.thesis.printed import available_tables, printed_row, printed_table

__all__ = ["available_tables", "printed_row", "printed_table"]
