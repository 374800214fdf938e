"""The README's result tables are the files in results/, and those files are what their command wrote.

A table in README.md (or a page of docs/) that quotes a result is preceded by a marker line
``<!-- results: results/DIR/NAME.md -->``; the table under it must be that file's table, row for
row. Each results folder holds the JSON its command wrote, the Markdown rendered from it and
``provenance.json`` (command, date, machine, versions).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from conftest import bench_module

ROOT = Path(__file__).resolve().parents[1]
MARKER = re.compile(r"^\s*<!--\s*results:\s*(\S+)\s*-->")
#: The pages whose quoted tables are checked.
PAGES = ("README.md", *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("*.md")))


def _table_after(lines: list[str], start: int, page: str = "README.md") -> list[str]:
    """The Markdown table (lines starting with '|') that begins at or after ``start``."""
    i = start
    while i < len(lines) and not lines[i].lstrip().startswith("|"):
        if lines[i].strip() and not lines[i].lstrip().startswith("<!--"):
            raise AssertionError(f"{page} line {i + 1}: expected a table after the results marker, found {lines[i]!r}")
        i += 1
    table = []
    while i < len(lines) and lines[i].lstrip().startswith("|"):
        table.append(lines[i].strip())
        i += 1
    return table


def _quoted_tables(page: str = "README.md") -> list[tuple[str, list[str]]]:
    lines = (ROOT / page).read_text().splitlines()
    return [(m.group(1), _table_after(lines, i + 1, page)) for i, line in enumerate(lines) if (m := MARKER.search(line))]


def _results_dirs() -> list[Path]:
    """Every folder below results/, at any depth, that has its own provenance.json."""
    return sorted(p.parent for p in (ROOT / "results").rglob("provenance.json"))


def _folder_id(folder: Path) -> str:
    return str(folder.relative_to(ROOT / "results"))


def test_every_results_file_has_provenance():
    """A file in results/ is covered by the provenance.json of its folder or of a folder above it
    (below results/): no result without its command, date and machine."""
    base = ROOT / "results"
    files = [f for f in base.rglob("*") if f.is_file()]
    assert files
    for f in files:
        owners = [d for d in f.parents if d != base and base in d.parents and (d / "provenance.json").is_file()]
        assert owners, f"{f.relative_to(ROOT)} has no provenance.json in its folder or a folder above it"


def test_readme_quotes_results_files():
    assert _quoted_tables(), "README.md quotes no results/ table (marker <!-- results: results/DIR/NAME.md -->)"
    assert "docs/reproduction.md" in PAGES and _quoted_tables("docs/reproduction.md"), "docs/reproduction.md quotes no results/ table"
    for page in PAGES:
        for rel, table in _quoted_tables(page):
            path = ROOT / rel
            assert path.is_file(), f"{page} quotes {rel}, which does not exist"
            file_table = [line.strip() for line in path.read_text().splitlines() if line.lstrip().startswith("|")]
            assert table, f"{page}: no table under the marker for {rel}"
            assert table == file_table, f"{page}'s table for {rel} differs from the file:\n{page}:\n" + "\n".join(table) + "\nfile:\n" + "\n".join(file_table)


@pytest.mark.parametrize("folder", _results_dirs(), ids=_folder_id)
def test_results_folder_has_provenance(folder):
    prov = json.loads((folder / "provenance.json").read_text())
    assert prov["command"].strip()
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ", prov["date_utc"])
    assert int(prov["machine"]["cores"]) >= 1
    assert prov["versions"]["jtraj"]
    # no trajectories in results/: small tables only
    assert not list(folder.rglob("*.npz"))


#: (file stem in a results folder, bench script, its function that renders the Markdown)
RENDERED = [
    ("side_by_side", "side_by_side", "render"),
    ("speed", "solve", "markdown"),
    ("quaternion_noise", "quaternion_noise", "table"),
    ("compile", "compile", "table"),
    ("unit_norm", "unit_norm", "table"),
    ("quat3_norms", "quat3_norms", "table"),
    ("hessians", "hessians", "table"),
    ("factor_split", "factor_split", "table"),
    ("options", "options", "table"),
    ("fatrop", "fatrop", "markdown"),
    ("differentiate", "differentiate", "table"),
    ("params_hop", "params_hop", "render"),
    ("euler_warm_start", "euler_warm_start", "table"),
]


def _table_lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.startswith("|")]


#: results folders whose Markdown was written before the script's note under the table was
#: reworded (FATROP's status explained): their table rows are checked
NOTE_REWORDED = {"fatrop/walk_backflip"}


@pytest.mark.parametrize(("stem", "script", "function"), RENDERED, ids=[r[0] for r in RENDERED])
def test_markdown_is_rendered_from_its_json(stem, script, function):
    """Every ``results/**/STEM.md`` is what the script renders of the JSON beside it (only the
    table rows in `NOTE_REWORDED`'s folders)."""
    folders = [p for p in _results_dirs() if (p / f"{stem}.json").exists()]
    assert folders, f"results/ holds no {stem}.json"
    render = getattr(bench_module(script), function)
    for folder in folders:
        records = json.loads((folder / f"{stem}.json").read_text())
        assert records
        text, rendered = (folder / f"{stem}.md").read_text(), render(records)
        if _folder_id(folder) in NOTE_REWORDED:
            text, rendered = _table_lines(text), _table_lines(rendered)
            assert text
        assert text == rendered, f"{folder}/{stem}.md was not rendered from its JSON"


def test_revisions_tables_are_rendered_from_their_json():
    """bench/revisions.py's tables: two labelled revisions per task, in the order they ran."""
    render = bench_module("revisions").table
    files = sorted((ROOT / "results").rglob("revisions.json"))
    assert files
    for path in files:
        records = json.loads(path.read_text())
        labels = tuple(dict.fromkeys(r["label"] for r in records))
        assert len(labels) == 2, (path, labels)
        table = _table_lines(path.with_suffix(".md").read_text())
        assert table and table == _table_lines(render(records, labels)), f"{path.with_suffix('.md')} was not rendered from its JSON"


def test_table_iv_is_rendered_from_its_json(tmp_path):
    """Every Table IV in results/ is what `jtraj compare` writes of the rows in its JSON."""
    from jtraj.experiments import _write_table_iv

    files = sorted((ROOT / "results").rglob("table_iv.json"))
    assert files
    for i, path in enumerate(files):
        _write_table_iv(json.loads(path.read_text()), tmp_path / str(i))
        assert path.with_suffix(".md").read_text() == (tmp_path / str(i) / "table_iv.md").read_text(), f"{path.with_suffix('.md')} was not rendered from its JSON"


@pytest.mark.parametrize("missing", [float("nan"), float("inf"), None])
def test_table_iv_writes_a_missing_number_as_its_json_renders_it(tmp_path, missing):
    """A NaN cost or turns printed ``nan`` / ``+nan`` in table_iv.md, while table_iv.json holds
    null, from which the table did not render at all (TypeError): a missing number (None, NaN,
    infinite) is "-", and turns blank, alike from the rows and from the JSON they were written to."""
    from jtraj.experiments import _write_table_iv

    (row,) = [r for r in json.loads((ROOT / "results" / "table_iv" / "table_iv.json").read_text()) if (r["task"], r["parameterization"]) == ("backflip", "se3")]
    assert row["turns"] is not None
    rows = [row | {"cost": missing, "constraint_violation": missing, "turns": missing, "time_s": missing}]
    _write_table_iv(rows, tmp_path / "rows")
    _write_table_iv(json.loads((tmp_path / "rows" / "table_iv.json").read_text()), tmp_path / "json")
    md = (tmp_path / "rows" / "table_iv.md").read_text()
    assert md == (tmp_path / "json" / "table_iv.md").read_text()
    assert md.splitlines()[-1].endswith("| - | - |  | - | ipopt |"), md


def test_side_by_side_render_cells():
    render = bench_module("side_by_side").render
    rows = [
        dict(code="jtraj paper", task="walk", sigma=0.0, seed=0, converged=False, iterations=50),
        dict(code="paper", task="walk", sigma=0.0, seed=0, converged=True, iterations=12),
        dict(code="jtraj paper", task="backflip", sigma=0.0, seed=0, converged=True, iterations=31, status="converged_but_task_failed"),
        dict(code="paper", task="walk", sigma=0.5, seed=0, converged=True, iterations=38),
        dict(code="paper", task="walk", sigma=0.5, seed=1, converged=False, iterations=50),
    ]
    lines = render(rows).splitlines()
    assert lines[0] == "| task | sigma | paper's Table IV | paper's code | jtraj paper |"  # the paper's code first
    assert lines[2] == "| walk | 0 | 14 | 12 | 50, not conv. |"
    assert lines[3] == "| backflip | 0 | 28 |  | 31, task failed |"
    assert lines[4] == "| walk | 0.5 |  | 1/2 conv., median 38 |  |"
    # draws checked for the task (noisy flips): converged and done, among all
    flips = [
        dict(code="paper", task="backflip", sigma=0.1, seed=0, converged=True, iterations=40, task_ok=True, turns=-0.99),
        dict(code="paper", task="backflip", sigma=0.1, seed=1, converged=True, iterations=30, task_ok=False, turns=-0.8),  # twisted
        dict(code="paper", task="backflip", sigma=0.1, seed=2, converged=False, iterations=200, task_ok=True, turns=-1.0),
        dict(code="paper", task="backflip", sigma=0.1, seed=3, converged=True, iterations=50, task_ok=False, turns=-0.5),  # half a turn
    ]
    assert render(flips).splitlines()[2] == "| backflip | 0.1 |  | 3/4 conv., 1 task done (2 turned), median 40 |"
    # an even count of converged draws: the median is the mean of the middle two
    even = [dict(code="paper", task="big_jump", sigma=0.5, seed=s, converged=True, iterations=i) for s, i in enumerate([41, 55, 44, 47])]
    assert render(even).splitlines()[2] == "| big_jump | 0.5 |  | 4/4 conv., median 45.5 |"


def test_side_by_side_jtraj_task_follows_robot_and_code_costs():
    mod = bench_module("side_by_side")
    walk = mod.jtraj_task("walk", {"talos": "talos_full"}, code_costs=True)
    assert (walk.robot, walk.configuration_weight) == ("talos_full", 1e-6)
    plain = mod.jtraj_task("walk", {}, code_costs=False)
    assert (plain.robot, plain.configuration_weight) == ("talos", 0.0)
    sideflip = mod.jtraj_task("sideflip", {"talos": "talos_full"}, code_costs=True)
    assert sideflip.robot == "go2" and sideflip == mod.jtraj_task("sideflip", {}, code_costs=False)  # no code cost differs there
    assert mod.jtraj_label("paper", {"talos": "talos_full"}, True) == "jtraj paper, talos_full, code's costs"
    assert mod.jtraj_label("paper", {}, False) == "jtraj paper"


def test_speed_markdown_cells():
    markdown = bench_module("solve").markdown
    row = dict(status="solved", iterations=10, time_s=2.0, time_derivatives=0.0, time_ipopt=2.0, cost=0.5, constraint_violation=3e-9)
    records = [
        dict(task="big_jump", peer=dict(iterations=11, time_s=20.0, status=0, obj=0.0, cons=1.4e-6), variants=[dict(row, variant="jtraj", options={"constr_viol_tol": 1e-6})]),
        dict(task="walk", peer=dict(iterations=50, time_s=600.0, status=-5), variants=[dict(row, variant="compact")]),
    ]
    lines = markdown(records).splitlines()
    assert lines[0].startswith("| task | variant | status | iterations | cost | violation |")
    assert lines[2] == "| big_jump | jtraj, constr_viol_tol=1e-06 | solved | 10 | 0.5 | 3.0e-09 | 2.00 | 0.200 | 0.00 | 2.00 | 11 | 0 | 1.4e-06 | 20.00 | 10.0x |"
    # a peer stopped by its wall-time limit: its time and the ratio are lower bounds; no cost logged
    assert lines[3] == "| walk | compact | solved | 10 | 0.5 | 3.0e-09 | 2.00 | 0.200 | 0.00 | 2.00 | 50 (stopped, Ipopt status -5) |  |  | >= 600.00 | >= 300.0x |"


def test_iterates_markdown_is_rendered_from_its_json():
    folders = [p for p in _results_dirs() if (p / "iterates.json").exists()]
    assert folders, "results/ holds no iterates.json"
    render = bench_module("trace_iterates").render
    for folder in folders:
        runs = json.loads((folder / "iterates.json").read_text())["runs"]
        assert len(runs) == 2 and all(run["rows"] for run in runs)
        assert (folder / "iterates.md").read_text().strip() == render(runs).strip()


def test_trace_rows_check_each_iterate_as_the_task_check():
    """A base that somersaults once about -y at the last iterate and stands still at the first:
    the rows carry Ipopt's figures and the task check's turns and off-axis share per iterate."""
    rows_of = bench_module("trace_iterates").rows_of
    K = 41
    angles = np.linspace(0.0, -2 * np.pi, K)
    flip = np.zeros((K, 7))
    flip[:, 3], flip[:, 5] = np.cos(angles / 2), np.sin(angles / 2)  # wxyz about +y
    still = np.zeros((K, 7))
    still[:, 3] = 1.0
    stats = np.array([[0, 0.0, 3e2, 1.0, 1.0, 0.0], [1, 0.6, 1e-6, 1e-3, 1e-9, 1.0]])
    rows = rows_of(stats, np.stack([still, flip]), (0.0, 1.0, 0.0), -1)
    assert [r["iter"] for r in rows] == [0, 1] and rows[0]["inf_pr"] == 3e2 and rows[1]["objective"] == 0.6
    assert abs(rows[0]["total_turns"]) < 1e-12
    assert abs(rows[1]["turns"] + 1.0) < 1e-9 and rows[1]["off_axis_share"] < 1e-9


def _table_iii_folders() -> list[Path]:
    return sorted(p.parent for p in (ROOT / "results").rglob("table_iii.md"))


@pytest.mark.parametrize("folder", _table_iii_folders(), ids=_folder_id)
def test_table_iii_is_rendered_from_its_runs(folder):
    """Every Table III in results/ is what `jtraj.experiments` makes of the runs.jsonl beside it
    (row for row, at the table's own noise levels)."""
    from jtraj import io as jio
    from jtraj.experiments import _not_a_run, _table_iii_markdown, run_key, summarize_robustness

    # read without read_runs, which copies a damaged file aside and rewrites it without its bad
    # lines: here that rewrote the committed file and the test passed
    numbered, bad = jio.read_jsonl_lines(folder / "runs.jsonl")
    assert not bad, f"{folder}/runs.jsonl: line(s) {bad} do not parse"
    odd = [(line, why) for line, r in numbered if (why := _not_a_run(r)) is not None]
    assert not odd, f"{folder}/runs.jsonl: not runs: {odd[:3]}"
    first: dict = {}
    for _, r in numbered:
        first.setdefault(run_key(r), r)  # the first of each key, as read_runs keeps
    runs = list(first.values())
    assert runs, f"{folder}: no runs beside table_iii.md"
    lines = [line for line in (folder / "table_iii.md").read_text().splitlines() if line.startswith("|")]
    sigmas = [float(s) for s in re.findall(r"sigma=([0-9.e+-]+)", lines[0])]
    assert sigmas, f"{folder}/table_iii.md: no sigma columns"
    rendered = [line for line in _table_iii_markdown(summarize_robustness(runs), sigmas).splitlines() if line.startswith("|")]
    assert lines == rendered, f"{folder}/table_iii.md is not the table of its runs.jsonl"


STUDY_HEADER = "| run | commit | machine (2 cores) | compilation cache | wall time | compiles | batches | iterations |"


def _elapsed_s(log: Path) -> float:
    """/usr/bin/time -v's wall time in ``log`` (h:mm:ss or m:ss.ss), in seconds."""
    m = re.search(r"Elapsed \(wall clock\) time \(h:mm:ss or m:ss\): ([\d:.]+)", log.read_text())
    assert m, f"{log}: no /usr/bin/time -v wall time"
    parts = [float(p) for p in m.group(1).split(":")]
    return sum(p * 60**i for i, p in enumerate(reversed(parts)))


def test_readme_study_timings_are_their_runs_files():
    """The README's table of `jtraj robustness --solver jtraj` runs (issue 11's 10-minute goal):
    each row's commit, machine and compilation cache are its folder's provenance, its wall time is /usr/bin/time's in the folder's log, and its compiles, batches and
    iterations are the sums over the folder's runs.jsonl (`time_compile`, `time_s`: each
    member's share of its batch, `iterations`); the row of the run that filled the cache, whose
    runs file was not kept, is its ``cold_fill.log``'s (the batches' lines and /usr/bin/time)."""
    lines = (ROOT / "README.md").read_text().splitlines()
    start = [i for i, line in enumerate(lines) if line.strip() == STUDY_HEADER]
    assert len(start) == 1, "README.md: the study's timing table was not found"
    rows = _table_after(lines, start[0])[2:]
    assert len(rows) >= 2
    number = lambda cell: int(cell.split()[0].replace(",", ""))  # noqa: E731  "1,029 s (a)" -> 1029
    for row in rows:
        cells = [c.strip().strip("*") for c in row.strip("|").split("|")]
        folder = ROOT / re.search(r"`(results/[^`]+)/`", cells[0]).group(1)
        # commit, machine and cache: the folder's provenance (its command says how it was run)
        prov = json.loads((folder / "provenance.json").read_text())
        command = prov["command"]
        assert cells[1].split()[0] in command, row
        assert all(word in prov["machine"]["cpu"] for word in cells[2].split()) and int(prov["machine"]["cores"]) == 2, row
        if "cold_fill.log" in cells[0]:  # the run that filled the cache the folder's run used
            assert cells[3] == "empty" and "filled by the same command run just before it from an empty folder" in command, row
        elif cells[3] == "empty":
            assert ("empty folder" in command or "cold compilation cache" in command) and "filled" not in command, row
        else:
            assert cells[3].startswith("filled") and "filled" in command, row
        minutes, seconds = re.fullmatch(r"(\d+) min (\d+) s", cells[4]).groups()
        wall = 60 * int(minutes) + int(seconds)
        if "cold_fill.log" in cells[0]:
            log = folder / "cold_fill.log"
            batches = re.findall(r"(\d+\.\d) it mean, +([\d.]+) s for the batch of 10", log.read_text())
            assert len(batches) == 64, log
            assert number(cells[6]) == round(sum(float(s) for _, s in batches)), row
            assert number(cells[7]) == round(sum(10 * float(it) for it, _ in batches)), row
        else:
            log = folder / "robustness.log"
            runs = [json.loads(line) for line in (folder / "runs.jsonl").read_text().splitlines() if line.strip()]
            assert len(runs) == 640, folder
            assert number(cells[5]) == round(sum(r["time_compile"] for r in runs)), row
            assert number(cells[6]) == round(sum(r["time_s"] for r in runs)), row
            assert number(cells[7]) == sum(r["iterations"] for r in runs), row
        assert wall == round(_elapsed_s(log)), row


@pytest.mark.parametrize("page", PAGES)
def test_code_fences_close(page):
    """Every fenced code block closes on a line of its own: a closing fence with text after it
    is not one (CommonMark), so the rest of the page would render as code (README.md had
    such a line after the replicate benchmark's output)."""
    fence = None  # the opening fence's backticks while inside a block
    for number, line in enumerate((ROOT / page).read_text().splitlines(), 1):
        stripped = line.strip()
        ticks = len(stripped) - len(stripped.lstrip("`"))
        if fence is None:
            if ticks >= 3:
                assert "`" not in stripped[ticks:], f"{page} line {number}: a fence's info string holds a backtick: {line!r}"
                fence, opened = "`" * ticks, number
        elif ticks >= len(fence):
            assert not stripped[ticks:].strip(), f"{page} line {number}: text after a closing fence: {line!r}"
            fence = None
    assert fence is None, f"{page}: the code block opened on line {opened} does not close"


def _paragraphs(text: str) -> list[str]:
    """The page's paragraphs and list items, each as one line (blank lines, list bullets,
    headings, tables and fences separate them)."""
    out: list[list[str]] = [[]]
    for line in text.splitlines():
        s = line.strip()
        if not s or s.startswith(("- ", "* ", "#", "|", "```")):
            out.append([s] if s.startswith(("- ", "* ")) else [])
        else:
            out[-1].append(s)
    return [" ".join(p) for p in out if p]


@pytest.mark.parametrize("page", PAGES)
def test_quoted_speed_ratios_are_their_speed_files(page):
    """A ratio quoted in prose as ``Rx (A s against B s)`` (jtraj's median against the public
    code's, `bench/solve.py`) is a record of a ``speed.json`` in a results folder the same
    paragraph names: both medians to the digits quoted, and their ratio to one decimal."""
    pair = re.compile(r"(\d+(?:\.\d+)?)x\**,?\s+\(?(\d+\.\d+) s against (\d+\.\d+) s")
    checked = 0
    for paragraph in _paragraphs((ROOT / page).read_text()):
        quoted = pair.findall(paragraph)
        if not quoted:
            continue
        records = []
        for folder in sorted(set(re.findall(r"results/[A-Za-z0-9_]+", paragraph))):
            if (ROOT / folder / "speed.json").exists():
                for task in json.loads((ROOT / folder / "speed.json").read_text()):
                    peer = (task.get("peer") or {}).get("time_s")
                    records += [(v["time_s"], peer) for v in task["variants"] if peer]
        for ratio, ours, theirs in quoted:
            digits = len(ours.split(".")[1]), len(theirs.split(".")[1]), len(ratio.split(".")[1]) if "." in ratio else 0
            assert any(
                (f"{t:.{digits[0]}f}", f"{p:.{digits[1]}f}", f"{p / t:.{digits[2]}f}") == (ours, theirs, ratio) for t, p in records
            ), f"{page}: '{ratio}x ({ours} s against {theirs} s)' is no record of the speed.json files its paragraph names: {paragraph[:200]}"
            checked += 1
    # a page's quotes (a rewording or a changed pattern matched none, and nothing was checked)
    assert checked == {"README.md": 8, "docs/measurements.md": 7}.get(page, 0), (page, checked)


@pytest.mark.parametrize("page", PAGES)
def test_quoted_replicate_lines_are_their_logs(page):
    """A line of `bench/replicates.py` quoted on the page (``replicates: ... speedup Z``) is a
    line of a log in a results folder the page names, to the last digit quoted."""
    text = re.sub(r"\s*\n\s*", " ", (ROOT / page).read_text())
    logs = {}
    for folder in set(re.findall(r"results/[A-Za-z0-9_]+", text)):
        for log in (ROOT / folder).glob("*.log"):
            for line in log.read_text(errors="replace").splitlines():
                logs.setdefault(line.strip(), folder)
    quoted = re.findall(r"replicates: [^`]*?speedup [\d.]+\d(?: \([^)`]*\))?", text)
    for q in quoted:
        assert any(line == q or (line.startswith(q) and not line[len(q)].isdigit()) for line in logs), f"{page}: {q!r} is in no log of the results folders it names"
    assert len(quoted) == {"README.md": 5, "docs/measurements.md": 17}.get(page, 0), (page, len(quoted))
