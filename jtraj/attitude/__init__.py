"""Planning with Attitude (Jackson, Tracy and Manchester, RA-L 2021) in pure JAX: Wahba's
problem (`wahba`), rigid-body models with RK4 (`models`), the two ways the quaternion enters a
transcription (`formulations`), the trajectory-optimization benchmarks with their checks and
figures (`benchmarks`), their NLP (`transcription`), their solve and comparison table (`solve`)
and the ``jtraj attitude`` command (`cli`). The quaternion calculus itself is
`jtraj.quaternion`. Nothing here imports MuJoCo, MJX or the legged-robot code.
"""

from jtraj.attitude import benchmarks, formulations, models, solve, transcription, wahba
from jtraj.attitude.benchmarks import BENCHMARKS, PAPER_ITERATIONS, barrel_roll, plot_benchmark, quadrotor_flip, satellite_slew
from jtraj.attitude.formulations import FORMULATIONS
from jtraj.attitude.solve import IPOPT_OPTIONS, compare_benchmarks, solve_benchmark
from jtraj.attitude.transcription import build_nlp

__all__ = [
    "benchmarks",
    "formulations",
    "models",
    "solve",
    "transcription",
    "wahba",
    "BENCHMARKS",
    "FORMULATIONS",
    "IPOPT_OPTIONS",
    "PAPER_ITERATIONS",
    "barrel_roll",
    "build_nlp",
    "compare_benchmarks",
    "plot_benchmark",
    "quadrotor_flip",
    "satellite_slew",
    "solve_benchmark",
]
