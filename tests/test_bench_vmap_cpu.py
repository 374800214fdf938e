"""bench/vmap_cpu.py on tiny blocks: ``--out`` writes its figures with the run's provenance
(they were only printed)."""

import json

from conftest import bench_module


def test_out_writes_each_size(tmp_path):
    out = tmp_path / "out"
    bench_module("vmap_cpu").main(["--members", "2", "--knots", "3", "--sizes", "2,3", "--repeats", "1", "--out", str(out)])
    records = json.loads((out / "vmap_cpu.json").read_text())
    assert [(r["n"], r["members"], r["knots"], r["sweeps"]) for r in records] == [(2, 2, 3, 1), (3, 2, 3, 1)]
    lines = (out / "vmap_cpu.md").read_text().splitlines()
    # each row gives its record's figures, and the ratio of the two batched ones
    for r, line in zip(records, lines[2:4]):
        cells = [c.strip() for c in line.strip("|").split("|")]
        assert cells == [str(r["n"]), f"{r['one_ms']:.1f}", f"{r['mapped_ms']:.1f}", f"{r['vmapped_ms']:.1f}", f"{r['vmapped_ms'] / r['mapped_ms']:.2f}"]
    assert lines[0] == "| n | one (ms) | one after another (ms) | vmapped (ms) | vmapped / one after another |"
    assert lines[2].startswith("| 2 | ") and lines[3].startswith("| 3 | ")
    assert "2 members, 3 knots, 1 sweeps; each time the mean of 3 calls" in lines[-1]
    assert "--sizes 2,3" in json.loads((out / "provenance.json").read_text())["command"]
