"""Every shipped LaTeX table fits the page and can be input beside the others (issue 53).

The chapter and paper tables are written from folders without results (their printed columns
full, heurtune's empty: the widths are the headers' and the printed digits'), then checked
as text: the package line, one caption and one label per table, labels unique across all of
them, no "Table 5.2:" in a caption (LaTeX numbers tables itself). Where pdflatex is installed
(the README's optional tools) each file is compiled in a plain portrait ``article`` (US letter,
the narrower text width of the two usual ones) and no box may be overfull by more than 1 pt;
two ``compare --format latex`` reports input in one document define no label twice.
"""

from __future__ import annotations

import re
import shutil
import subprocess

import numpy as np
import pandas as pd
import pytest

import heurtune
from heurtune.analysis.render import report
from heurtune.objectives.qtp.thesis import tables as thesis_tables
from heurtune.objectives.tito.papers import tables as paper_tables

# writing every chapter's and paper's tables takes 25 s on the EPYC (the printed gains' margins):
# `make test-long`; `make test` checks the tables of test_thesis_tables and test_printed_papers
pytestmark = pytest.mark.long

PDFLATEX = shutil.which("pdflatex")
needs_pdflatex = pytest.mark.skipif(PDFLATEX is None, reason="pdflatex is not installed (an optional tool)")


@pytest.fixture(scope="module")
def shipped_tables(tmp_path_factory):
    out = tmp_path_factory.mktemp("tables")
    for chapter in (4, 5, 6):
        thesis_tables.write_chapter(chapter, heurtune.load_experiment(f"thesis_ch{chapter}"), out / f"ch{chapter}",
                                    figures=False)
    for paper in ("000", "001", "002"):
        paper_tables.write_paper(paper, heurtune.load_experiment(f"paper_{paper}"), out / f"p{paper}", figures=False)
    return sorted(out.glob("*/tables/*.tex"))


def _environments(text):
    return re.findall(r"\\begin\{table\}.*?\\end\{table\}", text, flags=re.S)


def test_every_table_has_its_package_line_one_caption_and_a_unique_label(shipped_tables):
    assert len(shipped_tables) >= 30
    labels = []
    for path in shipped_tables:
        text = path.read_text()
        assert text.startswith("% needs \\usepackage{booktabs}"), path.name
        for env in _environments(text):
            assert env.count("\\caption{") == 1 and env.count("\\label{") == 1, path.name
            caption = re.search(r"\\caption\{(.*)\}", env).group(1)
            assert not caption.startswith("Table"), caption
            labels += re.findall(r"\\label\{([^}]*)\}", env)
    assert len(labels) == len(set(labels)), [k for k in labels if labels.count(k) > 1][:5]
    # the experiment is in the label: thesis_ch5's Table 5.2 is tab:thesis-ch5-table-5-2...
    assert any(k.startswith("tab:thesis-ch5-table-5-2") for k in labels)


def test_a_split_table_repeats_its_keys_and_keeps_a_quantity_together(shipped_tables):
    text = next(p for p in shipped_tables if p.name == "table_5_2.tex").read_text()
    envs = _environments(text)
    assert len(envs) > 1
    for env in envs:
        header = env.split("\\midrule")[0]
        assert "algorithm" in header or "controller" in header
        for quantity in re.findall(r"\\multicolumn\{(\d)\}\{c\}", header):
            assert int(quantity) >= 3  # printed, heurtune, diff (and diff %) under one name


def _compile(tmp_path, body: str) -> str:
    (tmp_path / "doc.tex").write_text("\\documentclass{article}\n\\usepackage{booktabs}\n\\begin{document}\n"
                                      + body + "\n\\end{document}\n")
    subprocess.run([PDFLATEX, "-interaction=nonstopmode", "-halt-on-error", "doc.tex"], cwd=tmp_path,
                   capture_output=True, timeout=120, check=False)
    return (tmp_path / "doc.log").read_text(errors="replace")


@needs_pdflatex
def test_every_shipped_table_fits_a_portrait_page(shipped_tables, tmp_path):
    widest = {}
    for path in shipped_tables:
        log = _compile(tmp_path, f"\\input{{{path}}}")
        assert "! " not in log, (path, log[log.find("! "):][:300])
        over = [float(v) for v in re.findall(r"Overfull \\hbox \(([0-9.]+)pt too wide", log)]
        widest[f"{path.parent.parent.name}/{path.name}"] = max(over, default=0.0)
    assert max(widest.values()) <= 1.0, {k: v for k, v in widest.items() if v > 1.0}


def _runs(experiment):
    rng = np.random.default_rng(1)
    rows = [dict(experiment=experiment, case="min", algorithm=alg, run=r, best_f=float(rng.normal(mu, 0.1)),
                 feasible=True, status="feasible", problem_id="p", n_evals=100, convergence_epoch=3)
            for alg, mu in (("cs", 1.0), ("pso", 1.5)) for r in range(6)]
    return pd.DataFrame(rows)


def test_two_compare_reports_have_distinct_labels(tmp_path):
    a, b = report(_runs("cs_folqi_qtp"), fmt="latex"), report(_runs("pso_folqi_qtp"), fmt="latex")
    la, lb = (set(re.findall(r"\\label\{([^}]*)\}", t)) for t in (a, b))
    assert la and lb and not la & lb
    if PDFLATEX:
        log = _compile(tmp_path, a + "\n" + b)
        assert "multiply defined" not in log
