"""Command line: ``jtraj <command>``; ``jtraj --help`` lists the commands.

Exit status: 0 success; 2 a bad input (one line on stderr, ``jtraj CMD: FIELD: VALUE:
EXPECTED``, before anything compiles or solves; for a bad ``JTRAJ_CPU_DEVICES``, which ``import
jtraj`` reads before any command is parsed, ``jtraj: MESSAGE``); ``jtraj solve`` and ``jtraj
attitude`` also exit 3 when the solver converged to a feasible point but the motion does not do
the task (e.g. a jump instead of a flip) and 4 when it did not return a feasible solution (the
outcome ``not_converged``, which includes a convergence to a point over the feasibility
violation tolerance). 1: the work itself failed after the inputs were accepted (``jtraj render`` or a
successful solve's ``--render`` without a working OpenGL, the solution still saved; ``jtraj
compare`` with no rows; a worker process of ``jtraj compare``/``jtraj robustness`` lost, e.g.
killed when memory ran out; a sweep's output closed, e.g. by ``| head``; a failed ``jtraj
params`` check). 130: interrupted (Ctrl-C); ``jtraj
robustness`` resumes from the runs finished, ``jtraj compare``'s tables hold the cells finished.
143: terminated (SIGTERM, e.g. by a job scheduler), which stops a command as Ctrl-C does (its
worker processes too) and keeps what Ctrl-C keeps.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

#: exit status of a bad input (as argparse's own usage errors)
EXIT_BAD_INPUT = 2
#: exit status of `jtraj solve` (and `jtraj attitude`) when the solver converged to a feasible point that does not do the task
EXIT_TASK_FAILED = 3
#: exit status of `jtraj solve` (and `jtraj attitude`) when the solver returned no feasible solution (outcome not_converged)
EXIT_NOT_CONVERGED = 4
#: exit status of a command interrupted by Ctrl-C (SIGINT), as the shell gives it
EXIT_INTERRUPTED = 130
#: exit status of a command stopped by SIGTERM (128 + 15, as the shell gives a process it kills)
EXIT_TERMINATED = 143
#: `jtraj wahba`'s largest --trials and --iterations: its arrays grow with both (about 13 kB a
#: trial at 12 iterations), and counts far past them ended in JAX's errors or out of memory
WAHBA_MAX_TRIALS = 100_000
WAHBA_MAX_ITERATIONS = 100
#: `jtraj attitude`'s largest --knots, as a task file's (`jtraj.task.MAX_KNOTS`): past it numpy
#: failed to allocate the problem (163 PiB at 1e15 knots), a traceback
ATTITUDE_MAX_KNOTS = 100_000


def _cmd_params(args: argparse.Namespace) -> int:
    import jax
    import jax.numpy as jnp
    import numpy as np

    from jtraj import lie
    from jtraj.lie import SE3, SO3
    from jtraj.parameterization import PARAMETERIZATIONS

    key = jax.random.PRNGKey(args.seed)
    k1, k2, k3 = jax.random.split(key, 3)
    T = SE3.from_rotation_and_translation(SO3.sample_uniform(k1), jax.random.normal(k2, (3,)))
    V = jax.random.normal(k3, (6,))
    h = 0.05
    print(f"random pose: xyz_wxyz = {np.round(np.concatenate([T.translation(), T.rotation().wxyz]), 4)}")
    print(f"{'name':<7} {'Table I row':<20} {'nq':>3} {'ndiff':>5}  {'pose round trip':>15}  {'step error vs Exp(Vh)':>21}")
    ok = True
    for name, p in PARAMETERIZATIONS.items():
        q = p.from_pose(T)
        roundtrip = float(jnp.max(jnp.abs(p.to_pose(q).as_matrix() - T.as_matrix())))
        step = float(jnp.linalg.norm(lie.minus(p.to_pose(p.integrate(q, V, h)), lie.plus(T, V * h))))
        ok &= roundtrip < 1e-9
        print(f"{name:<7} {p.label:<20} {p.nq:>3} {p.ndiff:>5}  {roundtrip:>15.2e}  {step:>21.2e}")
    return 0 if ok else 1


def _cmd_solve(args: argparse.Namespace) -> int:
    """``jtraj solve``: the solve's folder, with the ``provenance.json`` `jtraj.solve` writes
    there (`jtraj.provenance`, as the sweeps write it: unfinished until the result is saved)
    naming this command."""
    from jtraj.provenance import holding
    from jtraj.solver import solve

    # loaded, retargeted and checked by _check_inputs
    options, task = args.ipopt_checked, args.task_checked
    out = args.out_checked
    with holding(out):  # (solve holds it too; this hold lasts until its figures are written)
        return _solve_and_draw(args, solve, task, options, out)


def _solve_and_draw(args: argparse.Namespace, solve, task, options, out) -> int:
    result = solve(
        task,
        args.param,
        solver=args.solver,
        variables=args.variables,
        exact_hessian=args.exact_hessian,
        ipopt_options=options,
        noise=args.noise,
        seed=args.seed,
        replicate=args.replicate,
        noise_chart=args.noise_chart,
        out=out,
        progress_every=args.every,
        command=["jtraj", *args.argv],
    )
    from jtraj.plots import plot_convergence, plot_result
    from jtraj.result import Outcome

    plot_result(result, f"{out}/trajectory.png")
    plot_convergence(result, f"{out}/convergence.png")
    print(f"wrote {out}/result.json, {out}/trajectory.npz, {out}/trajectory.png, {out}/convergence.png, {out}/provenance.json")
    code = 0 if result.success else EXIT_TASK_FAILED if result.status is Outcome.TASK_FAILED else EXIT_NOT_CONVERGED
    if args.render:
        from jtraj.render import render_directory

        if not _render_after_solve("solve", lambda: render_directory(out, f"{out}/motion.mp4", f"{out}/keyframes.png"), out):
            return code or 1
    return code


def _solve_out(args: argparse.Namespace) -> str:
    """``jtraj solve``'s output folder: ``--out``, else ``runs/TASK_PARAM``, and
    ``runs/TASK_PARAM_ROBOT`` when ``--robot`` put the task on another robot (the solve on the
    task's own robot keeps its folder). An empty ``--out`` is kept, for `_check_out` to refuse."""
    if args.out is not None:
        return args.out
    from jtraj import task as tasks

    task = args.task_checked
    retargeted = task.robot != tasks.load(args.task).robot
    return f"runs/{task.name}_{args.param}" + (f"_{task.robot}" if retargeted else "")


def _executor_arguments(p: argparse.ArgumentParser, workers: bool = True) -> None:
    p.add_argument("--executor", default="local", choices=["local", "ray"], help="local worker processes (default) or one Ray task per (task, parameterization) group (pip install 'jtraj[ray]')")
    p.add_argument("--ray-address", default=None, help="cluster for --executor ray, passed to ray.init (default: start a local Ray instance; 'auto': this node's cluster)")
    p.add_argument(
        "--ray-gpus", type=float, default=None, metavar="G",
        help="with --executor ray: GPUs each group's task reserves (default 0: Ray hides the GPUs from it and it computes on the CPU); a fraction such as 0.25 lets groups share one",
    )
    if workers:
        p.add_argument("--workers", type=int, default=1, help="with --executor local: solve in this many processes (default 1)")


def _variables_argument(p: argparse.ArgumentParser, default: str, help: str) -> None:
    # --layout is the option's former name, still parsed so that existing scripts run; it warns
    # (`_check_inputs`), as render's --layout is another option (how a strip's panels lie)
    p.add_argument("--variables", "--layout", dest="variables", default=default, choices=["compact", "paper", "lean"], action=_FormerName, help=help + " (--layout: its former name)")
    p.add_argument(
        "--set", dest="variable_changes", action="append", metavar="FIELD=VALUE",
        help="change a field of the variables' TranscriptionOptions, repeatable (e.g. --set force_limits=rows --set contact_height=row: the study's code's rows; contact_height=row needs --variables paper, the sweeps' default)",
    )


def _robot_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("--robot", action="append", metavar="ROBOT=OTHER", help="solve the tasks on ROBOT with the robot model OTHER instead, repeatable (e.g. --robot talos=talos_full: the study's Talos)")


class _FormerName(argparse.Action):
    """Store the value, and the option string it came with when that is a former name
    (``--layout``), in ``former_names`` for `_check_inputs` to warn of."""

    def __call__(self, parser, namespace, values, option_string=None):
        setattr(namespace, self.dest, values)
        if option_string is not None and option_string != self.option_strings[0]:
            namespace.former_names = [*getattr(namespace, "former_names", []), (option_string, self.option_strings[0])]


def _split(text: str) -> list[str]:
    return [x for x in text.split(",") if x]


def _cmd_compare(args: argparse.Namespace) -> int:
    from jtraj.experiments import compare
    from jtraj.provenance import end_run, recording

    with recording(args.out, ["jtraj", *args.argv]) as run:  # OUT held until the end (jtraj.provenance)
        args.compare_rows = None  # OUT/provenance.json is written: what an interrupt says (_kept)
        rows = compare(args.tasks_checked, _split(args.params), out=args.out, variables=args.variables, exact_hessian=args.exact_hessian, save_trajectories=not args.no_trajectories, executor=args.executor, workers=args.workers, ray_address=args.ray_address, solver=args.solver, record_run=False, ray_gpus=args.ray_gpus)
        args.compare_rows = rows
        end_run(args.out, run)
    print((__import__("pathlib").Path(args.out) / "table_iv.md").read_text())
    return 0 if rows else 1


def _cmd_robustness(args: argparse.Namespace) -> int:
    from jtraj.experiments import robustness
    from jtraj.provenance import end_run, recording

    sigmas = args.sigmas_checked
    with recording(args.out, ["jtraj", *args.argv]) as run:  # OUT held until the end (jtraj.provenance)
        args.robustness_began = True  # what an interrupt says (_kept)
        runs = Path(args.out) / "runs.jsonl"
        if args.no_resume and runs.is_file():  # the name robustness() moves it to (_kept says it)
            from jtraj.experiments import _aside_name

            args.runs_moved_to = _aside_name(runs, "previous")
        robustness(args.tasks_checked, _split(args.params), sigmas, replicates=args.replicates, seed=args.seed, out=args.out, variables=args.variables, workers=args.workers, resume=not args.no_resume, ipopt_options=args.ipopt_checked or None, executor=args.executor, ray_address=args.ray_address, solver=args.solver, noise_chart=args.noise_chart, record_run=False, ray_gpus=args.ray_gpus)
        end_run(args.out, run)
    print((__import__("pathlib").Path(args.out) / "table_iii.md").read_text())
    return 0


def _parse_value(text: str):
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return text


def _cmd_wahba(args: argparse.Namespace) -> int:
    """``jtraj wahba``, with ``OUT/provenance.json`` (`jtraj.provenance`: unfinished until its
    three files are written), as the other commands write it (it wrote none)."""
    from jtraj.attitude.wahba import main_wahba
    from jtraj.provenance import end_run, recording

    with recording(args.out, ["jtraj", *args.argv]) as record:
        main_wahba(args.out, trials=args.trials, iterations=args.iterations, seed=args.seed)
        end_run(args.out, record)
    return 0


def _cmd_attitude(args: argparse.Namespace) -> int:
    """``jtraj attitude``, with ``OUT/provenance.json`` (`jtraj.provenance`: unfinished until
    the solves' files are written), as the sweeps and ``jtraj solve`` write it."""
    from jtraj.attitude.cli import main as attitude_main
    from jtraj.provenance import end_run, recording

    with recording(args.out, ["jtraj", *args.argv]) as record:
        code = attitude_main(args.bench, args.variant or "attitude", args.out, n_knots=args.knots, solver=args.solver, render=args.render)
        end_run(args.out, record)
    return code


def _render_options(args: argparse.Namespace):
    from jtraj.render import RenderOptions

    camera = {k: getattr(args, k) for k in ("azimuth", "elevation", "distance") if getattr(args, k, None) is not None}
    return RenderOptions(width=args.width, height=args.height, fps=args.fps, speed=args.speed, shadows=not args.no_shadows, forces=not args.no_forces, **camera)


def _render_after_solve(command: str, draw, out: str) -> bool:
    """``--render`` after a solve whose files are written: prints the paths ``draw()``
    writes; where nothing can be drawn (no OpenGL here, `jtraj.render.RenderError`; NaN poses
    from a solve stopped by a numerical error, `jtraj.render.NotDrawable`), one line on stderr,
    and False (the command exits 1 unless the solve's own status is already a failure)."""
    from jtraj.render import NotDrawable, RenderError, TooManyFrames

    try:
        paths = draw()
    except (RenderError, NotDrawable, TooManyFrames) as e:
        print(f"jtraj {command}: --render: {e} (the solution is saved in {out})", file=sys.stderr)
        return False
    for path in paths:
        print(f"wrote {path}")
    return True


def _check_render_writer(command: str) -> None:
    """``--render``'s writer of ``motion.mp4`` (imageio-ffmpeg), checked before the solve: it
    was found missing after the solve, when the drawing was written. Exit status 1, as
    `jtraj render` without it."""
    from jtraj.render import RenderError, _check_video_writer

    try:
        _check_video_writer("motion.mp4")
    except RenderError as e:
        raise SystemExit(f"jtraj {command}: --render: {e}; nothing was solved") from None


def _check_render_args(args: argparse.Namespace) -> None:
    """``jtraj render``'s values, checked before anything is drawn; last, the writer of an
    .mp4 ``--out`` (imageio-ffmpeg: a `jtraj.render.RenderError`, exit status 1 as without
    OpenGL), which was found missing only after the frames were drawn."""
    if args.out is None and args.strip is None:
        raise InputError("--out, --strip", "neither given", "expected --out FILE.mp4|FILE.gif and/or --strip FILE.png", verbatim=True)
    if not (Path(args.dir) / "trajectory.npz").is_file():
        raise InputError("DIR", args.dir, "expected a folder written by `jtraj solve` or `jtraj attitude` (with trajectory.npz)")
    # the strip's options without a strip did nothing, without a word
    given = [f"--{name}" for name in ("keyframes", "layout", "spacing") if getattr(args, name) is not None]
    if args.strip is None and given:
        raise InputError(", ".join(given), ", ".join(str(getattr(args, g[2:])) for g in given), "the keyframe strip's options; they need --strip FILE.png", verbatim=True)
    args.keyframes = 6 if args.keyframes is None else args.keyframes
    args.layout = "side" if args.layout is None else args.layout
    args.spacing = "motion" if args.spacing is None else args.spacing
    from jtraj.render import _IMAGE_FORMATS, _VIDEO_SUFFIXES

    if args.out is not None and Path(args.out).suffix.lower() not in _VIDEO_SUFFIXES:
        raise InputError("--out", args.out, "expected a .mp4 or .gif file name")
    if args.strip is not None and Path(args.strip).suffix.lower() not in _IMAGE_FORMATS:
        raise InputError("--strip", args.strip, "expected a .png (or .jpg) file name")
    for field, value in (("--speed", args.speed), ("--fps", args.fps), ("--distance", args.distance)):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise InputError(field, value, "expected a positive number")
    for field, value in (("--azimuth", args.azimuth), ("--elevation", args.elevation)):
        if value is not None and not math.isfinite(value):
            raise InputError(field, value, "expected a finite number of degrees")
    for field, value in (("--width", args.width), ("--height", args.height)):
        if value < 16:
            raise InputError(field, value, "expected at least 16 pixels")
    _check_positive_int("--keyframes", args.keyframes, 2)
    # the files and their folders, before minutes of drawing
    for field, value, example in (("--out", args.out, "motion.mp4"), ("--strip", args.strip, "keyframes.png")):
        if value is not None:
            if Path(value).is_dir():
                raise InputError(field, value, f"is a folder; expected a file name, e.g. {Path(value) / example}")
            _check_out(str(Path(value).parent), field, shown=value)
    if args.out is not None:
        from jtraj.render import _check_video_writer

        _check_video_writer(args.out)


def _cmd_render(args: argparse.Namespace) -> int:
    from jtraj.io import FileFormatError
    from jtraj.render import NotDrawable, RenderError, TooManyFrames, render_directory

    try:
        _check_render_args(args)
        paths = render_directory(args.dir, args.out, args.strip, keyframes=args.keyframes, layout=args.layout, spacing=args.spacing, options=_render_options(args))
    except RenderError as e:  # no OpenGL or no .mp4 writer here: the message says what to install
        raise SystemExit(f"jtraj render: {e}") from None
    except TooManyFrames as e:  # found before drawing, from the motion's duration
        raise InputError("--speed, --fps", f"{args.speed:g}, {args.fps:g}", str(e).removeprefix("render: "), verbatim=True) from None
    except (NotDrawable, FileFormatError) as e:  # a folder that is not a whole-body solution
        raise InputError("DIR", args.dir, str(e)) from None
    for path in paths:
        print(f"wrote {path}")
    return 0


def _cmd_plot(args: argparse.Namespace) -> int:
    from jtraj.io import FileFormatError
    from jtraj.plots import plot_directory

    folder = Path(args.dir)
    solved = all((folder / name).is_file() for name in ("result.json", "trajectory.npz"))
    if not (solved or (folder / "table_iv.json").is_file()):
        raise InputError("DIR", args.dir, "expected a folder written by `jtraj solve` (result.json and trajectory.npz) or `jtraj compare` (table_iv.json)")
    _check_out(args.dir if args.out is None else args.out)
    try:
        paths = plot_directory(folder, args.out)
    except FileFormatError as e:
        raise InputError("DIR", args.dir, str(e)) from None
    for path in paths:
        print(f"wrote {path}")
    return 0


def _add_render_parsers(sub) -> None:
    p = sub.add_parser("render", help="video and/or keyframe strip of a solution folder (DIR/trajectory.npz)")
    p.add_argument("dir", help="a folder written by `jtraj solve` (a robot's motion) or `jtraj attitude` (a rigid body's)")
    p.add_argument("--out", help="video file, .mp4 or .gif")
    p.add_argument("--strip", help="keyframe strip image, .png (or .jpg)")
    # the strip's options default to None so that one given without --strip is refused
    p.add_argument("--keyframes", type=int, help="keyframes in the strip (default 6)")
    p.add_argument("--layout", choices=["side", "overlay"], help="strip: panels side by side (default) or overlaid in one scene")
    p.add_argument("--spacing", choices=["motion", "time"], help="strip: keyframes evenly along the base's motion (default) or in time")
    p.add_argument("--speed", type=float, default=1.0, help="playback speed, 1 = real time (default)")
    p.add_argument("--fps", type=float, default=30.0, help="video frames per second (default 30)")
    p.add_argument("--width", type=int, default=640, help="image width in pixels (default 640; the strip's panels at most 480)")
    p.add_argument("--height", type=int, default=480, help="image height in pixels (default 480; the strip's panels at most 480)")
    p.add_argument("--no-shadows", action="store_true", help="faster with software OpenGL")
    p.add_argument("--no-forces", action="store_true", help="no contact-force arrows (they are drawn by default)")
    p.add_argument("--azimuth", type=float, help="camera azimuth in degrees (90 looks along +y, 180 along -x; default: along a flip's axis, else from the side of the base's travel)")
    p.add_argument("--elevation", type=float, help="camera elevation in degrees (default -15: a little from above)")
    p.add_argument("--distance", type=float, help="camera distance to the base in metres (default: from the robot's height and the motion)")
    p.set_defaults(func=_cmd_render)

    p = sub.add_parser(
        "plot",
        help="figures of a solution folder: DIR/solution.png (six panels, joints and friction too: fuller than solve's trajectory.png) and DIR/convergence.png; of a `jtraj compare` folder: DIR/comparison.png",
    )
    p.add_argument("dir", help="a folder written by `jtraj solve` or `jtraj compare`")
    p.add_argument("--out", help="output folder (default DIR)")
    p.set_defaults(func=_cmd_plot)

def _solver_names() -> list[str]:
    from jtraj.solvers import SOLVERS

    return sorted(SOLVERS)


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (``jtraj solve: argument --noise: invalid float value:
    'x'``) and exit status 2, like the checks of `_check_inputs`."""

    def error(self, message: str):
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    from jtraj import __version__

    parser = _Parser(prog="jtraj", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"jtraj {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    parser.set_defaults(subcommands=sub.choices)  # for `main`'s errors of a subcommand's arguments

    p = sub.add_parser("params", help="list the floating-base parameterizations and check them on a random pose")
    p.add_argument("--seed", type=int, default=0, help="seed of the random pose and twist (default 0)")
    p.set_defaults(func=_cmd_params)

    p = sub.add_parser(
        "solve",
        help="solve a task (Ipopt by default) and write DIR/result.json, DIR/trajectory.npz, DIR/provenance.json and two figures, DIR/trajectory.png (base, forces, torques) and DIR/convergence.png",
        epilog=(
            f"exit status: 0 the task succeeded, {EXIT_BAD_INPUT} bad input, {EXIT_TASK_FAILED} converged but the motion does not do the task, {EXIT_NOT_CONVERGED} not converged, "
            f"1 the task succeeded but --render could not draw it (the solution is saved), {EXIT_INTERRUPTED} interrupted (Ctrl-C), {EXIT_TERMINATED} terminated (SIGTERM)"
        ),
    )
    p.add_argument("task", help="a built-in task (walk, hopscotch, big_jump, handstand, backflip, sideflip) or a .toml file")
    p.add_argument("--param", default="se3", choices=["se3", "quat1", "quat2", "quat3", "euler"], help="floating-base parameterization (default se3)")
    p.add_argument("--solver", default="ipopt", choices=_solver_names(), help="NLP solver backend (default ipopt)")
    p.add_argument("--out", help="output directory (default runs/TASK_PARAM, runs/TASK_PARAM_ROBOT with --robot)")
    _variables_argument(p, "compact", "variables per knot: compact (q, v, a, f; default), the study's (q, v, a, f, c) or lean (q, v, f)")
    p.add_argument("--exact-hessian", action="store_true", help="exact Hessian of the Lagrangian instead of L-BFGS")
    p.add_argument("--ipopt", action="append", metavar="NAME=VALUE", help="any solver option (Ipopt's names for ipopt), repeatable (e.g. --ipopt max_iter=50)")
    p.add_argument("--noise", type=float, default=0.0, help="std of Gaussian noise added to the warm start (default 0: none)")
    p.add_argument("--seed", type=int, default=None, help="seed of the noise (default 0; needs --noise)")
    p.add_argument("--replicate", type=int, default=None, metavar="R", help="draw the noise as `jtraj robustness` draws replicate R (same --seed and sigma --noise), to solve one run of a study again with its trajectory")
    p.add_argument("--noise-chart", default=None, choices=["se3", "quat1", "quat2", "quat3", "euler"], help="with --replicate: that run of `jtraj robustness --noise-chart`")
    p.add_argument("--every", type=int, default=1, help="print the solver's progress every N iterations (default 1; jtraj's solver, one compiled program, prints them when it returns)")
    p.add_argument("--render", action="store_true", help="also write DIR/motion.mp4 and DIR/keyframes.png")
    _robot_argument(p)
    p.set_defaults(func=_cmd_solve)

    p = sub.add_parser(
        "compare", help="Table IV: every task with every parameterization (writes OUT/table_iv.{json,md})",
        description=(
            "Table IV: solve every task of --tasks with every parameterization of --params; writes OUT/table_iv.json and OUT/table_iv.md "
            "(again as each cell finishes, so an interrupted run keeps the cells finished), OUT/provenance.json and, without "
            "--no-trajectories, each cell's solution in OUT/TASK_PARAM. A run solves every cell again: compare does not resume."
        ),
    )
    p.add_argument("--tasks", default="walk,hopscotch,big_jump,handstand,backflip,sideflip", help="comma-separated tasks or .toml files (default: the six of Table IV)")
    p.add_argument("--params", default="se3,quat1,quat2,quat3,euler", help="comma-separated parameterizations (default: all five)")
    _variables_argument(p, "paper", "variables per knot; default: the study's, for comparison with its tables")
    p.add_argument("--exact-hessian", action="store_true", help="exact Hessian of the Lagrangian instead of L-BFGS")
    p.add_argument("--out", default="runs/table_iv", help="output folder (default runs/table_iv)")
    p.add_argument("--no-trajectories", action="store_true", help="write only the tables (for results/)")
    p.add_argument("--solver", default="ipopt", choices=_solver_names(), help="NLP solver backend of every cell (default ipopt)")
    _robot_argument(p)
    _executor_arguments(p)
    p.set_defaults(func=_cmd_compare)

    p = sub.add_parser(
        "robustness", help="Table III and Fig. 2: success and iterations under warm-start noise",
        description=(
            "Table III and Fig. 2: solve every task of --tasks with every parameterization of --params from --replicates noisy warm "
            "starts per noise level of --sigmas. Each finished solve is appended at once to OUT/runs.jsonl, keyed by its settings: "
            "the same command again resumes where a stopped run ended, and a run with other settings (--seed, --ipopt, --variables, "
            "--solver, ...) solves only its own runs, keeping the others in the file and out of its tables. Writes "
            "OUT/table_iii.json, OUT/table_iii.md, OUT/fig2.png and OUT/provenance.json."
        ),
    )
    p.add_argument("--tasks", default="walk,big_jump,backflip,sideflip", help="comma-separated tasks or .toml files (default: the four of Table III)")
    p.add_argument("--params", default="euler,quat1,quat2,se3", help="comma-separated parameterizations (default: the four of Table III)")
    p.add_argument("--sigmas", default="1e-6,1e-3,0.1,0.5", help="comma-separated noise levels (default: Table III's 1e-6,1e-3,0.1,0.5)")
    p.add_argument("--replicates", type=int, default=10, help="solves per noise level (default 10)")
    p.add_argument("--seed", type=int, default=0, help="seed of the noise (default 0)")
    _variables_argument(p, "paper", "variables per knot; default: the study's, for comparison with its tables")
    p.add_argument("--out", default="runs/robustness", help="output folder (default runs/robustness)")
    p.add_argument("--workers", type=int, default=1, help="with --executor local: solve (task, parameterization) groups in this many processes (default 1)")
    p.add_argument("--no-resume", action="store_true", help="solve again the runs already in OUT/runs.jsonl (the old file is moved to runs.jsonl.previous-N, the first N not taken)")
    p.add_argument("--solver", default="ipopt", choices=_solver_names(), help="NLP solver backend (default ipopt); jtraj solves each (task, parameterization, sigma) group's replicates in one batched call (vmapped on a GPU, one per core on a CPU)")
    p.add_argument(
        "--noise-chart", default=None, choices=["se3", "quat1", "quat2", "quat3", "euler"],
        help="draw the noise in this parameterization's coordinates and give every parameterization those noisy poses (default: each its own; sigma on a quaternion's four entries turns the base further than on SE(3)'s three)",
    )
    p.add_argument("--ipopt", action="append", metavar="NAME=VALUE", help="any solver option (Ipopt's names for ipopt), repeatable, over the study's settings (e.g. --solver jtraj --ipopt constr_viol_tol=1e-6); runs keep their options, so a resumed study solves only the runs of these options")
    _robot_argument(p)
    _executor_arguments(p, workers=False)
    p.set_defaults(func=_cmd_robustness)

    p = sub.add_parser("wahba", help="Wahba's problem: projected vs multiplicative Gauss-Newton (writes OUT/wahba.{npz,json,png})")
    p.add_argument("--out", default="runs/wahba", help="output folder (default runs/wahba)")
    p.add_argument("--trials", type=int, default=100, help=f"random problems (default 100, the paper's; at most {WAHBA_MAX_TRIALS})")
    p.add_argument("--iterations", type=int, default=12, help=f"Gauss-Newton iterations per method (default 12; at most {WAHBA_MAX_ITERATIONS})")
    p.add_argument("--seed", type=int, default=0, help="seed of the problems (default 0)")
    p.set_defaults(func=_cmd_wahba)

    p = sub.add_parser("attitude", help="Planning with Attitude benchmarks, naive or attitude-aware (OUT/BENCH_VARIANT/{result.json,trajectory.npz}, and plot.png for one benchmark; 'all' writes OUT/table.{json,md})")
    p.add_argument("bench", choices=["quadflip", "barrelroll", "satellite", "all"], help="one benchmark, or all of them in both variants (OUT/table.{json,md})")
    p.add_argument("--variant", default=None, choices=["naive", "attitude"], help="naive quaternion calculus or the attitude-aware one (default attitude; not with 'all', which solves both)")
    p.add_argument("--out", default="runs/attitude", help="output folder (default runs/attitude)")
    p.add_argument("--knots", type=int, default=None, help="number of knots (default: the paper's)")
    p.add_argument("--solver", default="ipopt", choices=_solver_names(), help="NLP solver backend (default ipopt)")
    p.add_argument("--render", action="store_true", help="also write OUT/BENCH_VARIANT/motion.mp4 and OUT/BENCH_VARIANT/keyframes.png (not with 'all')")
    p.set_defaults(func=_cmd_attitude)
    _add_render_parsers(sub)
    return parser


class InputError(ValueError):
    """A command-line value that cannot work: ``str(error)`` is ``"FIELD: VALUE: EXPECTED"``."""

    def __init__(self, field: str, value: Any, expected: str, verbatim: bool = False):
        self.field, self.value, self.expected, self.verbatim = field, value, expected, verbatim
        # verbatim: the value is already words of the message (e.g. "neither given"), not a value
        super().__init__(f"{field}: {value if verbatim else repr(value)}: {expected}")

    def __reduce__(self):
        # as it was made: Exception's own pickling passes the message alone, which this
        # constructor does not take (a worker process's InputError could not come back)
        return (type(self), (self.field, self.value, self.expected, self.verbatim))


def _check_out(path: str | None, field: str = "--out", shown: str | None = None) -> None:
    """An output folder must be a folder (or not exist yet) that this user can write in
    (`jtraj.io.output_folder_problem`). ``shown``: the value the user gave, where ``path`` is
    derived from it (a file's folder)."""
    if path is None:
        return
    from jtraj.io import output_folder_problem

    problem = output_folder_problem(path)
    if problem is not None:
        raise InputError(field, path if shown is None else shown, problem)


def _check_out_files(folder: str, names: tuple[str, ...], field: str = "--out") -> None:
    """The files a command writes into ``folder`` must not be folders (one failed after the
    files before it were written)."""
    from jtraj.result import folder_in_the_way

    if (problem := folder_in_the_way(folder, names)) is not None:
        raise InputError(field, folder, problem)


def _check_names(field: str, text: str, known: list[str], what: str, allow_files: bool = False) -> list[str]:
    names = _split(text)
    if not names:
        raise InputError(field, text, f"expected a comma-separated list of {what}: {', '.join(known)}")
    for name in names:
        if name not in known and not (allow_files and name.endswith(".toml")):
            raise InputError(field, name, f"unknown {what[:-1]}; expected some of {', '.join(known)}" + (" or .toml files" if allow_files else ""))
    return names


def _check_robots(items: list[str] | None) -> dict[str, str]:
    """``--robot ROBOT=OTHER`` items as a mapping, both names robots of jtraj."""
    from jtraj import robot as robot_lib

    known = robot_lib.available()
    robots: dict[str, str] = {}
    for item in items or []:
        old, sep, new = item.partition("=")
        if not sep or not old or not new:
            raise InputError("--robot", item, "expected ROBOT=OTHER, e.g. --robot talos=talos_full")
        for name in (old, new):
            if name not in known:
                raise InputError("--robot", item, f"unknown robot {name!r}; expected one of {', '.join(known)}")
        if old in robots:  # the last one won without a word
            raise InputError("--robot", item, f"robot {old!r} already mapped by --robot {old}={robots[old]}; expected each robot once")
        robots[old] = new
    return robots


def _load_valid_task(name: str, robots: dict[str, str] | None = None, all_used: bool = False, on_robots: set[str] | None = None):
    """The task ``name`` (on the robot ``robots`` maps its robot to) with the checks that need
    its robot done; errors name its file. ``all_used`` (one task, `jtraj solve`): a mapping of
    a robot the task is not on is refused, as it would be ignored (a sweep's mapping may be for
    some of its tasks only, `_check_tasks`). ``on_robots`` collects the task's own robot."""
    from jtraj import task as tasks

    task = tasks.load(name)
    if on_robots is not None:
        on_robots.add(task.robot)
    unused = [f"{old}={new}" for old, new in (robots or {}).items() if old != task.robot]
    if all_used and unused:
        raise InputError("--robot", unused[0], f"task {task.name!r} is on robot {task.robot!r}; expected --robot {task.robot}=OTHER or no --robot")
    task = tasks.retarget(task, robots or {})
    try:
        return task.validate()
    except tasks.TaskError as e:
        raise e.with_source(_task_file(name)) from None


def _from_file(error, name: str):
    """A task's ``error`` naming the file of the task argument ``name`` where it names none
    (a task built from a file names that file already)."""
    return error if error.source else error.with_source(_task_file(name))


def _task_file(name: str) -> str:
    """The file a task argument names, for its errors: the .toml given, or the built-in's."""
    return name if name.endswith(".toml") else f"tasks/{name}.toml"


def _check_fixed_knots(name: str, task) -> None:
    """A sweep's task whose fixed first or last knot is off the terrain its phases stand on
    (`jtraj.transcription.Transcription.initial_xyz_wxyz`), refused before the sweep starts:
    `jtraj solve` finds it before compiling, a sweep found it when the task's cells began,
    after the cells before them had solved. Its forward kinematics only (no NLP)."""
    from jtraj import robot as robot_lib
    from jtraj import task as tasks
    from jtraj.parameterization import get
    from jtraj.transcription import Transcription

    try:
        _ = Transcription(robot_lib.load(task.robot), task, get("se3")).initial_xyz_wxyz
    except tasks.TaskError as e:
        raise _from_file(e, name) from None


def _check_euler_warm_start(tasks_or_names: list, variables) -> None:
    """A sweep's task whose warm-start rules the Euler angles cannot write with these variables
    (`jtraj.transcription._check_euler_warm_start`), refused before the sweep starts."""
    from jtraj import task as tasks
    from jtraj.solver import VARIABLES
    from jtraj.transcription import _check_euler_warm_start as check

    options = VARIABLES[variables] if isinstance(variables, str) else variables
    for item in tasks_or_names:
        task = tasks.load(item) if isinstance(item, str) else item
        try:
            check(task, "euler", options)
        except tasks.TaskError as e:
            raise (_from_file(e, item) if isinstance(item, str) else e) from None


def _check_tasks(field: str, text: str, robots: dict[str, str] | None = None) -> tuple[list, list[str]]:
    """Every task named loads and passes the checks that need its robot, before any solve.

    Returns what the sweep is given: the names as they are without ``robots``, else the
    checked Task objects, moved to the robot models ``robots`` names (loaded once, here); and
    the tasks' own names (a .toml file's task is named inside it), which name compare's cells."""
    from jtraj import task as tasks
    from jtraj.experiments import _refuse_repeats

    names = _check_names(field, text, tasks.available(), "tasks", allow_files=True)
    on_robots: set[str] = set()
    checked = [_load_valid_task(name, robots, on_robots=on_robots) for name in names]
    for name, task in zip(names, checked):
        _check_fixed_knots(name, task)
    for old, new in (robots or {}).items():  # a mapping no task uses would be ignored
        if old not in on_robots:
            raise InputError("--robot", f"{old}={new}", f"no task of {field} is on robot {old!r}; expected a mapping of {', '.join(sorted(on_robots))}")
    _refuse_repeats(field, names, [t.name for t in checked], "task")  # walk and a .toml of walk, too
    return (checked if robots else names), [t.name for t in checked]


def _check_params(field: str, text: str) -> list[str]:
    from jtraj.experiments import _refuse_repeats
    from jtraj.parameterization import PARAMETERIZATIONS

    names = _check_names(field, text, list(PARAMETERIZATIONS), "parameterizations")
    _refuse_repeats(field, names, names, "parameterization")
    return names


def _check_ipopt(items: list[str] | None, solver: str = "ipopt", field: str = "--ipopt") -> dict[str, Any]:
    """``--ipopt NAME=VALUE`` items as option values of ``solver``: for Ipopt checked against
    Ipopt's own option list (names, types, ranges, available linear solvers), for another
    backend against its options class. ``field`` names the flag in errors (``bench/solve.py``
    also reads ``--jtraj`` items with it)."""
    options: dict[str, Any] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise InputError(field, item, f"expected NAME=VALUE, e.g. {field} max_iter=50")
        if key in options:  # the last one won without a word (and changed which runs resume)
            raise InputError(field, item, f"option {key!r} already given; expected each option once")
        options[key] = _parse_value(value)
    if options and solver == "ipopt":
        from jtraj.solvers import InvalidOptionError, IpoptOptions
        from jtraj.solvers.ipopt_catalog import catalog, check_all

        options = check_all(options)
        # Ipopt takes its strings in any case; its own spelling (lower case) here, as the
        # options object reads them (--ipopt nlp_scaling_method=NONE passed this check, then
        # the solve refused it with a traceback) and --exact-hessian compares them
        specs = catalog()
        options = {k: v.lower() if isinstance(v, str) and specs[k].values else v for k, v in options.items()}
        # as the solve builds them: what only the options object refuses, the bad item named
        for key, value in options.items():
            try:
                IpoptOptions.from_dict({key: value})
            except InvalidOptionError as err:
                raise InputError(field, f"{key}={value}", str(err)) from None
        try:
            IpoptOptions.from_dict(options)
        except InvalidOptionError as err:  # values that only clash together
            raise InputError(field, " ".join(items or []), str(err)) from None
    elif options:
        from jtraj import solvers

        # jtraj's options take None where a feature can be off (e.g. feasibility_polish_tol=none)
        # and booleans (delta_c_mu_scaled=false); Ipopt's string options take "none", "yes" and
        # "no" as values of their own, so only here
        words = {"none": None, "true": True, "false": False}
        options = {k: words[v.lower()] if isinstance(v, str) and v.lower() in words else v for k, v in options.items()}
        backend = solvers.get(solver)
        for key, value in options.items():  # one at a time, so that the error names the bad one
            try:
                backend.options({key: value})
            except (TypeError, ValueError) as err:
                raise InputError(field, f"{key}={value}", str(err)) from None
        try:
            backend.options(options)
        except (TypeError, ValueError) as err:  # values that only clash together
            raise InputError(field, " ".join(items or []), str(err)) from None
    return options


def _check_positive_int(field: str, value: int, minimum: int = 1, maximum: int | None = None) -> None:
    if maximum is not None and not minimum <= value <= maximum:
        raise InputError(field, value, f"expected an integer in [{minimum}, {maximum}]")
    if value < minimum:
        raise InputError(field, value, f"expected an integer >= {minimum}")


def _check_seed(value: int) -> None:
    """A seed that JAX's PRNGKey takes (a 64-bit integer); a larger one raised OverflowError
    where the noise is drawn, after the compile."""
    from jtraj.numbers import is_seed

    if not is_seed(value):
        raise InputError("--seed", value, "expected a 64-bit integer (below 2**63 in magnitude)")


def _check_inputs(args: argparse.Namespace) -> None:
    """Every value of the command line that can be checked without compiling anything."""
    cmd = args.command
    for former, name in getattr(args, "former_names", []):
        print(f"jtraj {cmd}: {former} is deprecated: it is now called {name}", file=sys.stderr)
    if cmd in ("solve", "compare", "robustness"):
        args.robots_checked = _check_robots(args.robot)
        args.variables = _check_variable_changes(args.variables, args.variable_changes)
    if cmd == "params":
        _check_seed(args.seed)
    if cmd in ("solve", "attitude") and args.render:
        _check_render_writer(cmd)
    if cmd == "solve":
        args.task_checked = _load_valid_task(args.task, args.robots_checked, all_used=True)
        if args.param == "euler":
            _check_euler_warm_start([args.task_checked], args.variables)
        args.out_checked = _solve_out(args)
        _check_out(args.out_checked)
        from jtraj.result import RESULT_FOLDER_FILES

        _check_out_files(args.out_checked, RESULT_FOLDER_FILES)  # saving the result removes or writes each (after the solve)
        if not (math.isfinite(args.noise) and args.noise >= 0):
            raise InputError("--noise", args.noise, "expected a standard deviation >= 0")
        if args.seed is not None and not args.noise:  # (it was ignored, as --replicate is refused)
            raise InputError("--seed", args.seed, "needs the noise level --noise SIGMA > 0 (the seed is that noise's)")
        args.seed = 0 if args.seed is None else args.seed
        _check_seed(args.seed)
        _check_positive_int("--every", args.every)
        if args.noise and args.replicate is None and args.seed < 0:
            # without --replicate the noise is numpy's default_rng(seed), which takes seeds >= 0
            raise InputError("--seed", args.seed, "expected a seed >= 0 for --noise without --replicate (numpy draws that noise; --replicate R draws with JAX, which takes any)")
        if args.replicate is not None:
            _check_positive_int("--replicate", args.replicate, 0, 2**32 - 1)  # JAX folds 32 bits in: 2**32 drew replicate 0
            if not args.noise:
                raise InputError("--replicate", args.replicate, "needs the noise level --noise SIGMA > 0 (the study's sigma)")
        elif args.noise_chart is not None:
            raise InputError("--noise-chart", args.noise_chart, "needs --noise SIGMA --replicate R (a run of `jtraj robustness --noise-chart`)")
        if args.noise_chart is not None:
            from jtraj.experiments import check_noise_chart

            check_noise_chart([args.task_checked], [args.param], args.variables, args.noise_chart)
        args.ipopt_checked = _check_ipopt(args.ipopt, getattr(args, "solver", "ipopt"))
        if args.exact_hessian:  # as solve() refuses it, in the command line's words
            from jtraj.solver import _hessian_conflict

            if conflict := _hessian_conflict(args.ipopt_checked):
                raise InputError(f"--ipopt {conflict[0]}", conflict[1], "conflicts with --exact-hessian; expected 'exact' or no --exact-hessian")
    elif cmd in ("compare", "robustness"):
        # sweeps: every name is checked before the first solve
        args.tasks_checked, task_names = _check_tasks("--tasks", args.tasks, args.robots_checked)
        params = _check_params("--params", args.params)
        if "euler" in params:  # its cells run last in compare, after the others solved
            _check_euler_warm_start(args.tasks_checked, args.variables)
        _check_positive_int("--workers", args.workers)
        # options of the other executor would be ignored without a word
        if args.ray_address is not None and args.executor != "ray":
            raise InputError("--ray-address", args.ray_address, "needs --executor ray (the local executor does not use a cluster)")
        if args.ray_gpus is not None and not (math.isfinite(args.ray_gpus) and args.ray_gpus >= 0):
            raise InputError("--ray-gpus", args.ray_gpus, "expected a number >= 0 (the GPUs each group's Ray task reserves; a fraction shares one)")
        if args.ray_gpus is not None and args.executor != "ray":
            raise InputError("--ray-gpus", args.ray_gpus, "needs --executor ray (the local executor's processes see the machine's GPUs)")
        if args.workers > 1 and args.executor != "local":
            raise InputError("--workers", args.workers, "is for --executor local; with --executor ray each group is a Ray task and the cluster runs as many at once as it has CPUs")
        _check_out(args.out)
        from jtraj.experiments import COMPARE_OUTPUTS, ROBUSTNESS_OUTPUTS

        # (runs.jsonl: check_runs_file)
        _check_out_files(args.out, (*(COMPARE_OUTPUTS if cmd == "compare" else ROBUSTNESS_OUTPUTS), "provenance.json"))
        if cmd == "compare" and not args.no_trajectories:  # each cell's folder, before the first solve
            from jtraj.experiments import cell_folder_problem

            if (problem := cell_folder_problem(args.out, task_names, params)) is not None:
                raise InputError("--out", args.out, problem)
        if args.executor == "ray":  # Ray installed and its cluster reached, before OUT is written
            from jtraj.executors import RayExecutor

            RayExecutor(args.ray_address, num_gpus=args.ray_gpus or 0.0).connect()
    if cmd == "robustness":
        from jtraj.experiments import _refuse_repeats

        sigmas, texts = [], _split(args.sigmas) or [args.sigmas]
        for text in texts:
            try:
                sigma = float(text)
            except ValueError:
                sigma = math.nan
            if not (math.isfinite(sigma) and sigma >= 0):
                raise InputError("--sigmas", text, "expected comma-separated noise levels >= 0, e.g. 1e-6,1e-3,0.1,0.5")
            sigmas.append(sigma)
        _refuse_repeats("--sigmas", texts, sigmas, "noise level")
        args.sigmas_checked = sigmas
        _check_positive_int("--replicates", args.replicates)
        _check_seed(args.seed)
        args.ipopt_checked = _check_ipopt(args.ipopt, args.solver)
        if args.noise_chart is not None:  # before OUT/provenance.json is written, as jtraj solve checks it
            from jtraj.experiments import check_noise_chart

            check_noise_chart(args.tasks_checked, _split(args.params), args.variables, args.noise_chart)
        from jtraj.experiments import check_runs_file

        check_runs_file(args.out, resume=not args.no_resume)  # (also before provenance.json)
    elif cmd == "wahba":
        _check_positive_int("--trials", args.trials, 1, WAHBA_MAX_TRIALS)
        _check_positive_int("--iterations", args.iterations, 1, WAHBA_MAX_ITERATIONS)
        _check_positive_int("--seed", args.seed, 0)  # as run_wahba, which refuses a negative seed
        _check_seed(args.seed)
        _check_out(args.out)
        _check_out_files(args.out, ("wahba.npz", "wahba.json", "wahba.png", "provenance.json"))
    elif cmd == "attitude":
        if args.render and args.bench == "all":
            raise InputError("--render", "all", "draws one benchmark; give its name (quadflip, barrelroll or satellite)", verbatim=True)
        if args.variant is not None and args.bench == "all":  # (it was ignored: all solves both)
            raise InputError("--variant", args.variant, "is for one benchmark; 'all' solves both variants of each")
        # --knots: each benchmark has its own lower bound (one line, exit status 2, before
        # anything is written; jtraj.attitude.cli.main checks it too), the upper one is all's
        from jtraj.attitude import benchmarks

        if args.knots is not None:
            _check_positive_int("--knots", args.knots, 1, ATTITUDE_MAX_KNOTS)
        _check_out(args.out)
        for bench in benchmarks.BENCHMARKS if args.bench == "all" else (args.bench,):
            if args.knots is not None:  # before OUT/provenance.json
                try:
                    benchmarks.get(bench, args.knots)
                except ValueError as e:
                    raise InputError("--knots", args.knots, str(e)) from None
            # the folders of the solves, OUT/BENCH_VARIANT: one that is a file failed after its
            # solve, as did a folder where one of its files goes (a traceback, the provenance
            # left unfinished)
            for variant in ("naive", "attitude") if args.bench == "all" else (args.variant or "attitude",):
                folder = str(Path(args.out) / f"{bench}_{variant}")
                _check_out(folder)
                from jtraj.result import RESULT_FOLDER_FILES

                _check_out_files(folder, RESULT_FOLDER_FILES)  # Result.save refuses a folder at any of them
        _check_out_files(args.out, ("provenance.json", *(("table.json", "table.md") if args.bench == "all" else ())))


def _check_variable_changes(variables: str, items: list[str] | None):
    """``--variables`` with the ``--set FIELD=VALUE`` changes: the name itself when there are
    none, else a `TranscriptionOptions`."""
    if not items:
        return variables
    from jtraj.solver import with_changes

    changes: dict[str, str] = {}
    for item in items:
        field, sep, value = item.partition("=")
        if not sep or not field or not value:
            raise InputError("--set", item, "expected FIELD=VALUE, e.g. force_limits=rows")
        if field in changes:  # the last one won without a word
            raise InputError("--set", item, f"field {field!r} already set by --set {field}={changes[field]}; expected each field once")
        changes[field] = value
    try:
        return with_changes(variables, changes)
    except ValueError as e:
        raise InputError("--set", " ".join(items), str(e)) from None


def _input_errors() -> tuple[type[BaseException], ...]:
    from jtraj.executors import ExecutorUnavailableError
    from jtraj.io import FileFormatError
    from jtraj.provenance import FolderInUseError
    from jtraj.solvers.base import InvalidOptionError
    from jtraj.solvers.ipopt_catalog import IpoptOptionError
    from jtraj.task import TaskError

    # InvalidOptionError: an option the options object refuses past the command line's checks;
    # FolderInUseError: --out is held by another process's run (its command named)
    errors: tuple[type[BaseException], ...] = (InputError, TaskError, IpoptOptionError, InvalidOptionError, FileFormatError, ExecutorUnavailableError, FolderInUseError)
    # jtraj.experiments imports MuJoCo (and its refusal of MUJOCO_GL) with the robot models: a
    # command that has not imported it (jtraj params, wahba) cannot have raised its errors
    if experiments := sys.modules.get("jtraj.experiments"):
        errors += (experiments.NoiseChartError, experiments.RepeatedValueError)
    # a robot that cannot be loaded (JTRAJ_ROBOT_DATA not a folder, example-robot-data missing,
    # a robot file's URDF): loading one imports jtraj.robot
    if robot := sys.modules.get("jtraj.robot"):
        errors += (robot.RobotLoadError,)
    return errors


def _loads_mujoco(args: argparse.Namespace) -> bool:
    """Whether the command may import MuJoCo (a robot model, a drawing): ``jtraj params``,
    ``wahba`` and ``attitude`` without ``--render`` never do, and skip `_mujoco_gl_refused`'s
    import of it (0.1 to 0.2 s)."""
    if args.command in ("params", "wahba"):
        return False
    return args.command != "attitude" or bool(args.render)


def _mujoco_gl_refused() -> str | None:
    """MuJoCo's refusal of the ``MUJOCO_GL`` variable, or its failure to load that backend's
    library, both raised when it is imported (so every command ended in a traceback), as the
    line to print; None when MuJoCo imports."""
    import os

    setting = os.environ.get("MUJOCO_GL")
    try:
        import mujoco  # noqa: F401
    except RuntimeError as e:
        if "MUJOCO_GL" not in str(e):
            raise
        return f"{e}; expected egl, osmesa or glfw, or leave it unset (jtraj then takes egl or osmesa where there is no display and their libraries load)"
    except (AttributeError, ImportError, OSError) as e:  # PyOpenGL without the backend's library
        # only a failure in the OpenGL backend's import (another, a broken MuJoCo install, is
        # no MUJOCO_GL matter and keeps its traceback)
        if not setting or not _raised_in_opengl(e):
            raise
        return (
            f"MUJOCO_GL={setting!r}: MuJoCo could not load that OpenGL backend ({type(e).__name__}: {e}); install its library "
            "(egl: apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri libopengl0; osmesa: apt-get install libosmesa6) or leave MUJOCO_GL unset "
            "(jtraj then takes a backend whose library loads, or none: everything but drawing works)"
        )
    return None


def _raised_in_opengl(error: BaseException) -> bool:
    """Whether ``error`` came from PyOpenGL or MuJoCo's OpenGL backends (mujoco.egl,
    mujoco.osmesa, mujoco.glfw)."""
    import traceback

    where = [frame.filename.replace("\\", "/") for frame in traceback.extract_tb(error.__traceback__)]
    return any("/OpenGL/" in f or any(f"/mujoco/{b}" in f for b in ("egl", "osmesa", "glfw")) for f in where)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra:  # said by the subcommand's parser: "jtraj solve: unrecognized ...", not "jtraj: ..."
        args.subcommands[args.command].error(f"unrecognized arguments: {' '.join(extra)}")
    del args.subcommands
    args.argv = sys.argv[1:] if argv is None else list(argv)  # provenance.json's command
    if _loads_mujoco(args) and (refused := _mujoco_gl_refused()):
        _tell(f"jtraj {args.command}: {refused}")
        return EXIT_BAD_INPUT
    # one handler for every input error, wherever it is found: one line, exit status 2
    from jtraj.executors import GroupError, KeyMismatchError, WorkerLostError

    if args.command in ("compare", "robustness") and (getattr(args, "workers", 1) > 1 or getattr(args, "executor", "local") == "ray"):
        # before anything here uses a GPU (the inputs' checks, provenance.json's device): this
        # process only starts the workers, which would each find three quarters of it taken
        from jtraj.executors import share_the_accelerator

        share_the_accelerator()
    terminated: list[int] = []
    restore = _sigterm_as_interrupt(terminated)
    try:
        _check_inputs(args)
        return int(args.func(args) or 0)
    except _input_errors() as e:
        _tell(f"jtraj {args.command}: {e}")
        return EXIT_BAD_INPUT
    except (WorkerLostError, KeyMismatchError, GroupError) as e:
        # their messages say what went wrong in a worker (a lost worker's also what was kept;
        # a group's error that could not cross processes carries the worker's traceback as
        # text): a Python traceback of this process's hid them
        _tell(f"jtraj {args.command}: {e}")
        return 1
    except KeyboardInterrupt as e:
        _tell(f"jtraj {args.command}: {'terminated (SIGTERM)' if terminated else 'interrupted'}{_kept(args, e)}")
        return EXIT_TERMINATED if terminated else EXIT_INTERRUPTED
    except BrokenPipeError as e:
        # its output was closed (`| head`, a `tee` ended by Ctrl-C): one line, what was kept
        # (a traceback before; and Python's flush of stdout at exit would fail again)
        _to_devnull(sys.stdout)
        notes = getattr(e, "__notes__", [])
        _tell(f"jtraj {args.command}: stopped: its output was closed (broken pipe){_kept(args, KeyboardInterrupt(*notes[-1:]))}")
        return 1
    finally:
        restore()


def _tell(message: str) -> None:
    """``message`` on stderr, the command's last word; where stderr is a closed pipe as well
    (``2>&1 | head``) it is dropped, not raised out of `main` as a traceback."""
    try:
        print(message, file=sys.stderr, flush=True)
    except (BrokenPipeError, ValueError):  # ValueError: stderr closed
        _to_devnull(sys.stderr)


def _to_devnull(stream) -> None:
    """Point ``stream``'s file descriptor at /dev/null (Python's advice for a closed pipe: its
    flush at exit would raise again); nothing where it has no descriptor (a test's)."""
    import os

    try:
        fd = stream.fileno()
    except (AttributeError, OSError, ValueError):
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, fd)
    os.close(devnull)


def _sigterm_as_interrupt(terminated: list[int]):
    """Make SIGTERM raise KeyboardInterrupt, as Ctrl-C does, so that a command stopped by it (a
    job scheduler's, ``kill``) runs the cleanup of Ctrl-C: the sweeps' worker processes are
    stopped (Python's default ends the process at once, and ``--workers`` processes went on
    solving, then waited forever) and the message says what was kept. The first SIGTERM raises
    and is recorded in ``terminated``; later ones are ignored while that cleanup runs. Returns
    what puts the handler it replaced back, for `main` to call as it returns (outside the main
    thread, where Python takes no handler, nothing is changed)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        return lambda: None

    def handler(signum, frame):
        if not terminated:
            terminated.append(signum)
            raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, handler)
    # None: a handler not set from Python, which cannot be put back; the default then
    return lambda: signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)


def _kept(args: argparse.Namespace, interrupt: KeyboardInterrupt) -> str:
    """What an interrupted command leaves, for its message (compare says it in ``interrupt``:
    how many cells its table holds, or none, where an earlier run's table may still lie;
    an interrupt outside compare() is told by how far `_cmd_compare` got)."""
    if args.command == "robustness":
        if not getattr(args, "robustness_began", False):  # still checking its inputs
            return f"; nothing was written to {Path(args.out)}"
        if not (Path(args.out) / "runs.jsonl").is_file():  # (its first group still compiling)
            moved = ""
            if (earlier := getattr(args, "runs_moved_to", None)) is not None and earlier.is_file():
                moved = f"; the earlier runs were moved to {earlier}"
            return f"; no run was solved{moved}; {Path(args.out) / 'provenance.json'} records the run as unfinished"
        # with --no-resume the same command would move them aside again and solve every run
        again = "the same command without --no-resume resumes" if args.no_resume else "the same command again resumes"
        return f"; the runs finished are kept in {Path(args.out) / 'runs.jsonl'}, and {again} from them"
    if args.command == "compare":
        out = Path(args.out)
        if interrupt.args:
            said = f"{interrupt}"
        elif not hasattr(args, "compare_rows"):  # still checking its inputs
            said = f"nothing was written to {out}"
        elif args.compare_rows is None:  # before compare() began its cells
            said = f"no cell was solved and no table written; {out / 'provenance.json'} records the run as unfinished"
        else:
            said = f"{out / 'table_iv.json'} holds all {len(args.compare_rows)} cells"
        return f"; {said} (the same command again solves every cell)"
    return ""


if __name__ == "__main__":
    sys.exit(main())
