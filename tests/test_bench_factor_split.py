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


def test_the_largest_difference_covers_the_off_diagonal_blocks(monkeypatch):
    """The table's "largest difference between the two factors" compared only their diagonal
    blocks: factors that differ in ``sub`` alone reported 0. Fake programs, no compile."""
    import jax.numpy as jnp

    bench = bench_module("factor_split")
    K, n, c = 3, 4, 2

    def program(split_above, cols, diag, upper):
        sub = jnp.ones((K, c, n)).at[1, 0, 2].add(0.25 if split_above == bench.NO_SPLIT else 0.0)
        return lambda d, u: (kkt.BlockFactor(diag=d, sub=sub), jnp.asarray(True))

    monkeypatch.setattr(bench, "program", program)
    rec = bench.measure(K, n, c, rounds=1)
    # |1 - 1.25| of the one call's largest sub entry 1.25; the diagonal blocks agree
    assert rec["max_rel_diff"] == 0.2
    assert bench._relative_difference(jnp.zeros(3), jnp.zeros(3)) == 0.0
