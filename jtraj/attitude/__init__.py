"""Planning with Attitude (Jackson, Tracy and Manchester, RA-L 2021): Wahba's problem
(`wahba`), rigid-body models with RK4 (`models`) and the trajectory-optimization benchmarks
solved naive vs attitude-aware with Ipopt (`benchmarks`). The quaternion calculus itself is
`jtraj.quaternion`."""

from jtraj.attitude import benchmarks, models, wahba

__all__ = ["benchmarks", "models", "wahba"]
