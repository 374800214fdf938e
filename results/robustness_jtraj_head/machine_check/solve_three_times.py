"""A/B: one task solved by jtraj's solver with the jtraj found on sys.path; prints the warm solve times."""
import sys, time
import jtraj
print(jtraj.__file__)
task, param = sys.argv[1], sys.argv[2]
for i in range(3):
    t = time.perf_counter()
    r = jtraj.solve(task, param, variables="paper", solver="jtraj", progress=None, keep_trajectory=False)
    dt = time.perf_counter() - t
    print(f"run {i}: {r.status.value} {r.iterations} it, {dt:.2f} s wall, time_s {r.time_s:.2f}, {1000*r.time_s/r.iterations:.1f} ms/it", flush=True)
