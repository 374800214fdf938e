"""bench/factor_split.py on tiny blocks: both programs factor the same matrix, and the table
says which shapes were split."""

from conftest import bench_module

from jtraj.solvers import kkt


def test_factor_split_bench_compares_the_two_factors(monkeypatch):
    bench = bench_module("factor_split")
    monkeypatch.setattr(kkt, "SPLIT_ABOVE", 4)
    decisions: list[tuple[int, bool]] = []  # `kkt._split`'s decisions, read while tracing
    real = kkt._split

    def spy(n):
        decisions.append((n, real(n)))
        return decisions[-1][1]

    monkeypatch.setattr(kkt, "_split", spy)
    small = bench.measure(3, 4, 2, rounds=1)
    # 4-wide blocks are not split by either program (SPLIT_ABOVE 4 and the bench's NO_SPLIT)
    assert decisions and not any(took for _, took in decisions)
    decisions.clear()
    split = bench.measure(3, 9, 5, rounds=2)
    # the "halves" program halved the 9-wide blocks, the "one call" program did not
    assert (9, True) in decisions and (9, False) in decisions
    for rec in (small, split):
        assert rec["max_rel_diff"] < 1e-12
        assert set(rec["stats"]) == {"one call", "halves"}
    lines = bench.table([small, split]).splitlines()
    assert lines[2].startswith("| 3 x 4 (2) | no (n <= 4) |")
    assert lines[3].startswith("| 3 x 9 (5) | yes |")
