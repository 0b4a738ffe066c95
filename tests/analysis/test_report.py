"""Tests of heurtune.report: the self-contained HTML report."""

import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from heurtune.analysis import report
from heurtune.runner.experiment import run as run_experiment

ROOT = Path(__file__).resolve().parents[2]
DATA_PNG = "data:image/png;base64,"


class _Page(HTMLParser):
    """Collects images, headings, tables and every src/href of a page."""

    def __init__(self):
        super().__init__()
        self.images, self.headings, self.links = [], [], []
        self.tables = 0
        self._heading = None

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == "img":
            self.images.append(attrs.get("src", ""))
        if tag == "table":
            self.tables += 1
        for key in ("src", "href"):
            if attrs.get(key):
                self.links.append(attrs[key])
        if tag in ("h1", "h2", "h3", "h4"):
            self._heading = [tag, ""]

    def handle_data(self, data):
        if self._heading is not None:
            self._heading[1] += data

    def handle_endtag(self, tag):
        if self._heading is not None and tag == self._heading[0]:
            self.headings.append(tuple(self._heading))
            self._heading = None


def parse(path) -> _Page:
    page = _Page()
    page.feed(Path(path).read_text(encoding="utf-8"))
    return page


@pytest.fixture(scope="module")
def smoke_report(tmp_path_factory):
    """Two smoke experiments (cs and apso on the QTP, cases min and nmp) and their report."""
    tmp = tmp_path_factory.mktemp("report")
    dirs = []
    for name in ("cs_folqi_qtp", "apso_folqi_qtp"):
        out = tmp / name
        assert run_experiment([name, "--smoke", "--out", str(out), "--no-figures"]) == 0
        dirs.append(out)
    assert report.run([*map(str, dirs), "--out", str(tmp / "html")]) == 0
    return tmp / "html" / "index.html", dirs


def test_report_is_one_self_contained_file(smoke_report):
    index, _ = smoke_report
    page = parse(index)
    assert sorted(p.name for p in index.parent.iterdir()) == ["index.html"]
    # every resource is embedded: no external link, no external style sheet or script
    assert page.links and all(link.startswith(DATA_PNG) for link in page.links)
    text = index.read_text(encoding="utf-8")
    assert "http://" not in text and "https://" not in text
    assert "<script" not in text and "<link" not in text


def test_report_sections_tables_and_figures(smoke_report):
    index, _ = smoke_report
    page = parse(index)
    titles = [t for _, t in page.headings]
    for case in ("min", "nmp"):
        assert f"Case {case}" in titles
        for part in ("best_f over successful runs", "pairwise tests", "best run of each algorithm per scenario",
                     "loop margins", "figures"):
            assert any(t.startswith(f"Case {case}: {part}") for t in titles), (case, part)
    assert "Across cases" in titles and "Experiments" in titles
    # header table + 4 tables per case (summary, pairwise, re-evaluation, margins)
    assert page.tables == 1 + 2 * 4
    # per case: convergence, ECDF, box plot and one response per algorithm (cs, apso)
    pngs = [s for s in page.images if s.startswith(DATA_PNG)]
    assert len(pngs) == len(page.images) == 2 * 5
    assert all(len(s) > 1000 for s in pngs)
    text = index.read_text(encoding="utf-8")
    assert "Kruskal-Wallis test" in text
    assert "0.1.0" in text  # heurtune version from meta.json
    # two algorithms only: the Friedman test across cases is skipped, and the page says so
    assert "Friedman test across cases skipped" in text
    # the per-scenario table names its units (the family's metric_units)
    for column in ("Mp1 (%)", "ts2 (s)", "J (V² s)", "ess1 (%)"):
        assert f"<th>{column}</th>" in text, column


def test_friedman_diagram_embedded_and_text_escaped():
    rng = np.random.default_rng(0)
    rows = []
    for case in ("a", "b", "c"):
        for k, alg in enumerate(("<b>x</b>", "y", "z")):
            for r in range(5):
                rows.append({"experiment": "e&1", "case": case, "algorithm": alg, "problem_id": f"p-{case}",
                             "run": r, "best_f": k + rng.random(), "feasible": True})
    html = report.render_html(pd.DataFrame(rows), responses=False)
    page = _Page()
    page.feed(html)
    assert "<b>x</b>" not in html and "&lt;b&gt;x&lt;/b&gt;" in html
    assert "e&amp;1" in html
    # one box plot per case plus the critical-difference diagram; no history: notes instead
    assert sum(s.startswith(DATA_PNG) for s in page.images) == 3 + 1
    assert "Critical-difference diagram" in html
    assert "Convergence figure not drawn" in html


def test_missing_dir_is_one_line_exit_2(tmp_path):
    res = subprocess.run([sys.executable, "-m", "heurtune.report", str(tmp_path / "nope"), "--out",
                          str(tmp_path / "o")], capture_output=True, text=True, cwd=ROOT)
    assert res.returncode == 2
    assert len(res.stderr.strip().splitlines()) == 1 and res.stderr.startswith("error:")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("argv", [[], ["somewhere"], ["--bogus"]])
def test_usage_errors_exit_2(argv, capsys, tmp_path):
    if argv == ["somewhere"]:
        argv = [str(tmp_path)]  # a folder but no --out
    assert report.run(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and err.startswith("error:")


def test_folder_without_runs_is_exit_2(tmp_path, capsys):
    assert report.run([str(tmp_path), "--out", str(tmp_path / "o")]) == 2
    assert "no runs.parquet" in capsys.readouterr().err


def test_labels_name_variants_of_one_experiment(smoke_report, tmp_path, capsys):
    cs = smoke_report[1][0]
    assert report.run([str(cs), str(cs), "--out", str(tmp_path / "r")]) == 2  # the same folder twice
    assert report.run([str(cs), "--out", str(tmp_path / "r"), "--label", "noequals"]) == 2
    assert "NAME=DIR" in capsys.readouterr().err


def test_the_best_run_of_a_case_says_when_it_failed(smoke_report, tmp_path):
    """A case whose runs all failed (here made so in a copy of the cs smoke folder) is drawn
    from its best run, and the caption says that run failed; a case with a feasible best does
    not say so."""
    import re
    import shutil

    _, dirs = smoke_report
    folder = tmp_path / "cs_folqi_qtp"
    shutil.copytree(dirs[0], folder)
    runs = pd.read_parquet(folder / "runs.parquet")
    nmp = runs["case"] == "nmp"
    runs.loc[nmp, "status"], runs.loc[nmp, "feasible"], runs.loc[nmp, "best_f"] = "failed", False, 1e10
    runs.to_parquet(folder / "runs.parquet")
    assert report.run([str(folder), "--out", str(tmp_path / "html")]) == 0
    text = (tmp_path / "html" / "index.html").read_text(encoding="utf-8")
    assert re.search(r"Case nmp: responses of the best cs controller \(run \d, failed: not a solution\)", text)
    assert "Case min: responses of the best cs controller (run" in text and "min: best of cs" not in text
    assert not [line for line in text.split("Case min: responses")[1:] if line.split(")")[0].endswith("solution")]
