"""`jtraj.result.Result`: every field survives save/load for both kinds of trajectory, a
result without a trajectory removes an older trajectory file, and a bad folder fails with
one message naming the file."""

import dataclasses

import numpy as np
import pytest

from jtraj.attitude.transcription import StateTrajectory
from jtraj.io import FileFormatError
from jtraj.result import Outcome, Result
from jtraj.solvers import Stats, Status


def make_result(trajectory, **changes):
    fields = dict(
        problem="quadflip",
        variant="attitude",
        model="Quadrotor",
        solver="ipopt",
        status=Outcome.TASK_FAILED,
        solver_status=Status.ACCEPTABLE,
        status_msg="Solved To Acceptable Level.",
        stats=Stats(iterations=12, obj_evals=13, grad_evals=13, con_evals=14, jac_evals=13, hess_evals=12, time_total=0.75, time_evaluations=0.25),
        time_compile=3.5,
        cost=1.25,
        constraint_violation=2e-9,
        violation_by_group={"dynamics": 2e-9, "bounds": 0.0},
        metrics={"roll_turns": 0.5, "target_errors_deg": {"goal@20": 1e-7}, "task_check": "half a turn"},
        n_variables=357,
        n_constraints=300,
        nnz_jacobian=4000,
        options={"solver": "ipopt", "tol": 1e-6, "extra": {}},
        history=[{"iter": 0, "objective": 2.0, "inf_pr": 1.0, "inf_du": 0.5, "mu": 0.1, "alpha_pr": 0.0}],
        trajectory=trajectory,
    )
    fields.update(changes)
    return Result(**fields)


def state_trajectory():
    rng = np.random.default_rng(0)
    return StateTrajectory(t=np.linspace(0, 1, 5), X=rng.normal(size=(5, 13)), U=rng.normal(size=(4, 4)))


def assert_same(a: Result, b: Result):
    for f in dataclasses.fields(Result):
        if f.name == "trajectory":
            continue
        assert getattr(a, f.name) == getattr(b, f.name), f.name
    assert (a.trajectory is None) == (b.trajectory is None)
    if a.trajectory is not None:
        assert type(a.trajectory) is type(b.trajectory)
        for f in dataclasses.fields(a.trajectory):
            x, y = getattr(a.trajectory, f.name), getattr(b.trajectory, f.name)
            if isinstance(x, tuple):
                assert x == y, f.name
            else:  # assert_array_equal alone takes 1.0 for True and float64 for float32
                np.testing.assert_array_equal(x, y, err_msg=f.name, strict=True)


def test_round_trip_of_every_field(tmp_path):
    r = make_result(state_trajectory())
    back = Result.load(r.save(tmp_path / "r"))
    assert_same(r, back)
    assert back.converged and not back.success and back.iterations == 12 and back.time_solver == 0.5


def test_round_trip_of_a_whole_body_trajectory(tmp_path):
    from jtraj.transcription import Trajectory

    K, P = 4, 2
    rng = np.random.default_rng(1)
    traj = Trajectory(
        t=(np.arange(K) * 0.05).astype(np.float32),  # a float32 array stays float32
        base_xyz_wxyz=rng.normal(size=(K, 7)),
        q_base=rng.normal(size=(K, 6)),
        q_joints=rng.normal(size=(K, 3)),
        v=rng.normal(size=(K, 9)),
        a=rng.normal(size=(K, 9)),
        tau=rng.normal(size=(K, 9)),
        forces=rng.normal(size=(K, P, 3)),
        contact_positions=rng.normal(size=(K, P, 3)),
        in_contact=rng.random((K, P)) > 0.5,
        contact_names=("FL_foot", "FR_foot"),
    )
    r = make_result(traj, problem="hop", variant="se3", model="go2", metrics={"turns": None, "final_position_error": 0.0})
    back = Result.load(r.save(tmp_path / "wb"))
    assert_same(r, back)
    assert back.task == "hop" and back.parameterization == "se3" and back.robot == "go2" and back.turns is None


def test_saving_without_trajectory_removes_the_old_one(tmp_path):
    make_result(state_trajectory()).save(tmp_path)
    assert (tmp_path / "trajectory.npz").exists()
    make_result(None).save(tmp_path)
    assert not (tmp_path / "trajectory.npz").exists()
    assert Result.load(tmp_path).trajectory is None


def test_non_finite_numbers_are_written_as_strict_json(tmp_path):
    r = make_result(None, cost=float("nan"), constraint_violation=float("inf"))
    text = (r.save(tmp_path) / "result.json").read_text()
    assert "NaN" not in text and "Infinity" not in text
    back = Result.load(tmp_path)
    # strict JSON keeps no NaN or inf: the file lists where they were, and they come back
    assert np.isnan(back.cost) and back.constraint_violation == float("inf")
    assert "cost nan, violation inf" in back.summary()


def test_non_finite_numbers_in_the_float_tables_come_back_as_nan(tmp_path):
    """The per-group violations and the history's numbers are floats too: strict JSON writes
    NaN and inf as null, and they came back as None where the top-level floats came back NaN."""
    row = {"iter": 3, "objective": float("nan"), "inf_pr": float("inf"), "inf_du": 0.5, "mu": 0.1, "alpha_pr": 0.0}
    r = make_result(None, violation_by_group={"dynamics": float("nan"), "bounds": 0.0}, history=[row])
    back = Result.load(r.save(tmp_path))
    assert np.isnan(back.violation_by_group["dynamics"]) and back.violation_by_group["bounds"] == 0.0
    (loaded,) = back.history
    assert loaded.keys() == row.keys() and np.isnan(loaded["objective"]) and loaded["inf_pr"] == float("inf")
    assert {k: loaded[k] for k in ("iter", "inf_du", "mu", "alpha_pr")} == {"iter": 3, "inf_du": 0.5, "mu": 0.1, "alpha_pr": 0.0}


def test_nan_metrics_come_back_as_nan_and_none_stays_none(tmp_path):
    """A flip's NaN turns was written as null and read back as None, the value of a task
    without a flip, and the summary dropped it; a None metric stays None."""
    r = make_result(None, metrics={"turns": float("nan"), "final_position_error": float("inf"), "target_errors_deg": {"goal@20": float("nan"), "top@10": 1.0}, "sun_angle_deg": np.array([1.0, np.nan]), "keep_out_deg": None, "task_check": "NaN poses"})
    back = Result.load(r.save(tmp_path))
    m = back.metrics
    assert np.isnan(back.turns) and m["final_position_error"] == float("inf") and "turns +nan" in back.summary()
    assert np.isnan(m["target_errors_deg"]["goal@20"]) and m["target_errors_deg"]["top@10"] == 1.0
    assert m["sun_angle_deg"][0] == 1.0 and np.isnan(m["sun_angle_deg"][1])
    assert m["keep_out_deg"] is None and m["task_check"] == "NaN poses"
    no_flip = Result.load(make_result(None, metrics={"turns": None, "final_position_error": 0.0}).save(tmp_path))
    assert no_flip.turns is None and "turns" not in no_flip.summary()


def test_infinities_in_the_options_and_metrics_come_back_as_they_were(tmp_path):
    """A theta's infinite max_delta_force (walk, hopscotch, side-flip) was read back as None,
    not a float, and an infinite metric as NaN."""
    theta = {"friction": [0.7], "max_delta_force": [float("inf")], "bounds": [[-float("inf"), 1.0], [float("nan"), 2.0]]}
    r = make_result(None, options={"tol": 1e-3, "theta": theta}, metrics={"turns": None, "margin": -float("inf"), "gap": np.array([0.5, np.inf])})
    back = Result.load(r.save(tmp_path))
    th = back.options["theta"]
    assert th["max_delta_force"] == [float("inf")] and th["friction"] == [0.7] and back.options["tol"] == 1e-3
    assert th["bounds"][0] == [-float("inf"), 1.0] and np.isnan(th["bounds"][1][0]) and th["bounds"][1][1] == 2.0
    assert back.metrics["margin"] == -float("inf") and back.metrics["gap"] == [0.5, float("inf")] and back.metrics["turns"] is None


def test_a_none_beside_an_infinity_in_a_metric_stays_none(tmp_path):
    """The older list of metrics with non-finite numbers made every null of such a metric NaN."""
    back = Result.load(make_result(None, metrics={"margins": {"keep_out": None, "sun": float("inf")}, "turns": None}).save(tmp_path))
    assert back.metrics["margins"] == {"keep_out": None, "sun": float("inf")}


def test_infinities_of_the_top_level_and_float_tables_come_back_as_they_were(tmp_path):
    """Only the metrics and options kept their infinities: an infinite cost, violation, group
    violation or history number came back as NaN."""
    import json

    row = {"iter": 3, "objective": -float("inf"), "inf_pr": float("inf"), "inf_du": float("nan"), "mu": 0.1, "alpha_pr": 0.0}
    r = make_result(None, cost=-float("inf"), constraint_violation=float("inf"), violation_by_group={"dynamics": float("inf"), "bounds": float("nan")}, history=[row])
    back = Result.load(r.save(tmp_path))
    assert back.cost == -float("inf") and back.constraint_violation == float("inf")
    assert back.violation_by_group["dynamics"] == float("inf") and np.isnan(back.violation_by_group["bounds"])
    (loaded,) = back.history
    assert loaded["objective"] == -float("inf") and loaded["inf_pr"] == float("inf") and np.isnan(loaded["inf_du"])
    # the list jtraj read before (at 7307760, which refuses an entry of another field there)
    # names the metrics and options only; the rest is under a key it ignores
    data = json.loads((tmp_path / "result.json").read_text())
    assert data["non_finite_values"] == []
    assert sorted(entry[0][0] for entry in data["non_finite_values_more"]) == ["constraint_violation", "cost", "history", "history", "history", "violation_by_group", "violation_by_group"]
    # an entry of the top level that names no null is refused, as the others are
    data["non_finite_values_more"].append([["n_variables"], "inf"])
    (tmp_path / "result.json").write_text(json.dumps(data))
    with pytest.raises(FileFormatError, match=r"non_finite_values_more: \[\['n_variables'\], 'inf'\] names no null of the result"):
        Result.load(tmp_path)
    for bad in ([[["cost"]], "inf"], [["cost"], ["inf"]], 3, [[], "inf"]):  # a corrupt file: its error, not a TypeError
        data["non_finite_values_more"] = [bad]
        (tmp_path / "result.json").write_text(json.dumps(data))
        with pytest.raises(FileFormatError, match=r"non_finite_values_more: .* names no null of the result"):
            Result.load(tmp_path)


def test_a_field_of_the_wrong_type_is_named_and_a_missing_default_is_taken(tmp_path):
    """"iterations": "12" loaded as a string and a cost of "abc" failed later in summary() with
    a bare ValueError; a file without a field that has a default (one added later) was refused."""
    import json

    make_result(None).save(tmp_path)
    good = json.loads((tmp_path / "result.json").read_text())
    for key, value, said in (("iterations", "12", "'12': expected an integer"), ("cost", "abc", "'abc': expected a number"), ("n_variables", True, "True: expected an integer"), ("metrics", [1], r"\[1\]: expected a dict"), ("problem", 3, "3: expected a str")):
        (tmp_path / "result.json").write_text(json.dumps({**good, key: value}))
        with pytest.raises(FileFormatError, match=rf"result\.json: field '{key}': {said}$"):
            Result.load(tmp_path)
    (tmp_path / "result.json").write_text(json.dumps({**good, "cost": 3}))  # an integer is a number
    assert Result.load(tmp_path).cost == 3.0 and isinstance(Result.load(tmp_path).cost, float)
    older = {k: v for k, v in good.items() if k not in ("nnz_jacobian", "history", "options")}
    (tmp_path / "result.json").write_text(json.dumps(older))
    back = Result.load(tmp_path)
    assert (back.nnz_jacobian, back.history, back.options) == (0, [], {})
    for key in ("cost", "iterations", "time_total"):  # (Stats' fields have defaults, yet are required)
        (tmp_path / "result.json").write_text(json.dumps({k: v for k, v in good.items() if k != key}))
        with pytest.raises(FileFormatError, match=rf"missing field '{key}'; not a jtraj result"):
            Result.load(tmp_path)


def test_a_list_of_non_finite_values_naming_no_null_is_refused(tmp_path):
    import json

    make_result(None, options={"theta": {"max_delta_force": [float("inf")]}}).save(tmp_path)
    data = json.loads((tmp_path / "result.json").read_text())
    data["non_finite_values"] = [[["options", "tol"], "inf"]]
    (tmp_path / "result.json").write_text(json.dumps(data))
    with pytest.raises(FileFormatError, match=r"result\.json: non_finite_values: \[\['options', 'tol'\], 'inf'\] names no null of the result"):
        Result.load(tmp_path)
    # a deeper path: the error named the path's last key walked ("theta") for the list
    data["non_finite_values"] = [[["options", "theta", "max_delta_force", 5], "inf"]]
    (tmp_path / "result.json").write_text(json.dumps(data))
    with pytest.raises(FileFormatError, match=r"result\.json: non_finite_values: \[\['options', 'theta'"):
        Result.load(tmp_path)


def test_results_saved_before_the_list_of_non_finite_metrics_still_load(tmp_path):
    """Older files do not tell a NaN metric from a None one: their nulls stay None."""
    import json

    make_result(None, metrics={"turns": float("nan")}, options={"theta": {"max_delta_force": [float("inf")]}}).save(tmp_path)
    data = json.loads((tmp_path / "result.json").read_text())
    del data["metrics_non_finite"], data["non_finite_values"]
    (tmp_path / "result.json").write_text(json.dumps(data))
    back = Result.load(tmp_path)
    assert back.turns is None and back.options["theta"]["max_delta_force"] == [None]


def test_a_save_removes_the_provenance_of_the_run_that_wrote_the_earlier_result(tmp_path):
    """A result saved into a folder from jtraj solve kept that run's provenance.json beside it,
    which then claimed a complete run of another command for the new result."""
    (tmp_path / "provenance.json").write_text('{"command": "jtraj solve hop.toml", "complete": true}')
    make_result(None).save(tmp_path)
    assert not (tmp_path / "provenance.json").exists()


@pytest.mark.parametrize("name", ["result.json", "trajectory.npz", "notes.txt"])
def test_load_given_a_file(tmp_path, name):
    """A result's files load their folder; another file is one line naming it (it was a raw
    NotADirectoryError from a path under the file)."""
    make_result(state_trajectory(), cost=3.0).save(tmp_path)
    (tmp_path / "notes.txt").write_text("mine")
    if name == "notes.txt":
        with pytest.raises(FileFormatError, match=r"notes\.txt: is a file; expected a result's folder \(with result\.json\)$"):
            Result.load(tmp_path / name)
    else:
        assert Result.load(tmp_path / name).cost == 3.0


@pytest.mark.parametrize("trajectory", [state_trajectory, lambda: None])
def test_a_save_removes_the_files_derived_from_the_result_it_replaces(tmp_path, trajectory):
    """A reused folder kept the earlier solve's video, keyframe strip and figures (jtraj render,
    jtraj plot, jtraj solve's and jtraj attitude's figures) beside the new result; files jtraj
    does not write there stay."""
    make_result(state_trajectory()).save(tmp_path)
    derived = ["motion.mp4", "keyframes.png", "solution.png", "trajectory.png", "convergence.png", "plot.png"]
    for name in [*derived, "notes.txt", "comparison.png"]:
        (tmp_path / name).write_bytes(b"of the earlier solve")
    make_result(trajectory(), cost=2.0).save(tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["result.json", "notes.txt", "comparison.png"] + (["trajectory.npz"] if trajectory() is not None else []))
    assert Result.load(tmp_path).cost == 2.0


def test_plot_returns_the_path_for_every_kind_of_result(tmp_path):
    """Result.plot(path) returned the path for a whole-body result but the Figure for an
    attitude benchmark's (its own plot_result)."""
    X = np.zeros((5, 13))
    X[:, 3] = 1.0
    r = make_result(StateTrajectory(t=np.linspace(0, 1, 5), X=X, U=np.zeros((4, 4))))
    path = tmp_path / "plot.png"
    assert r.plot(path) == path and path.read_bytes()[:4] == b"\x89PNG"
    assert hasattr(r.plot(), "savefig")  # without a path, the figure


@pytest.mark.parametrize("second", ["with_trajectory", "without_trajectory"])
def test_a_save_interrupted_between_its_files_is_not_loaded_as_a_pair(tmp_path, monkeypatch, second):
    """save() replaces result.json, then trajectory.npz: killed in between, the folder held the
    new result beside the earlier solve's trajectory, and load() paired them without a word."""
    import jtraj.io

    make_result(state_trajectory(), cost=1.0).save(tmp_path)

    def killed(*args, **kwargs):
        raise KeyboardInterrupt

    path_type = type(tmp_path / "x")
    unlink = path_type.unlink

    def killed_at_the_trajectory(path, *args, **kwargs):  # the earlier figures go before either file
        if path.name == "trajectory.npz":
            raise KeyboardInterrupt
        return unlink(path, *args, **kwargs)

    monkeypatch.setattr(jtraj.io, "write_npz", killed)
    monkeypatch.setattr(path_type, "unlink", killed_at_the_trajectory)
    other = StateTrajectory(t=np.linspace(0, 2, 3), X=np.ones((3, 13)), U=np.ones((2, 4)))
    with pytest.raises(KeyboardInterrupt):
        make_result(other if second == "with_trajectory" else None, cost=2.0).save(tmp_path)
    monkeypatch.undo()
    if second == "with_trajectory":
        with pytest.raises(FileFormatError, match=r"trajectory\.npz: not the trajectory of .*result\.json"):
            Result.load(tmp_path)
    else:  # the new result has no trajectory: the earlier file beside it is not taken for its
        back = Result.load(tmp_path)
        assert back.cost == 2.0 and back.trajectory is None


def test_results_saved_without_a_trajectory_digest_still_load(tmp_path):
    """Folders written before result.json held the digest load as they did."""
    import json

    r = make_result(state_trajectory())
    r.save(tmp_path)
    data = json.loads((tmp_path / "result.json").read_text())
    del data["trajectory_sha256"]
    (tmp_path / "result.json").write_text(json.dumps(data))
    assert_same(r, Result.load(tmp_path))


def test_a_trajectory_that_could_not_be_loaded_is_not_saved(tmp_path):
    """A trajectory field that is None became a pickled object array: the save went through
    and every load then refused the file ('Object arrays cannot be loaded')."""
    r = make_result(StateTrajectory(t=np.linspace(0, 1, 5), X=np.zeros((5, 13)), U=None))
    with pytest.raises(TypeError, match=r"trajectory field 'U' is NoneType, not an array"):
        r.save(tmp_path)
    assert not (tmp_path / "trajectory.npz").exists()


def test_load_takes_the_result_file_for_its_folder(tmp_path):
    make_result(state_trajectory()).save(tmp_path / "r")
    assert_same(Result.load(tmp_path / "r" / "result.json"), Result.load(tmp_path / "r"))


def _save_with_arrays(d, **arrays):
    """A saved whole-body-like trajectory file whose arrays are replaced by ``arrays``."""
    make_result(state_trajectory()).save(d)
    with np.load(d / "trajectory.npz") as z:
        data = {k: z[k] for k in z.files}
    data.update(arrays)
    np.savez(d / "trajectory.npz", **data)


@pytest.mark.parametrize(
    "arrays, match",
    [
        ({"__trajectory_class__": np.array("builtins:dict")}, "expected a jtraj trajectory class"),
        ({"__trajectory_class__": np.array("jtraj.result:NoSuchTrajectory")}, "does not exist in this jtraj"),
        ({"__trajectory_class__": np.array("jtraj.result:Result")}, "does not match Result"),
        ({"base_xyz_wxyz": np.zeros((3, 7))}, r"'base_xyz_wxyz' has shape \(3, 7\), but 't' has 5 knots"),
        ({"t": np.zeros((5, 1))}, r"'t' has shape \(5, 1\)"),
    ],
)
def test_bad_trajectory_files_are_refused_by_name(tmp_path, arrays, match):
    """(A trajectory with NaN poses, which a solver stopped by one writes, still loads; the
    renderer refuses it, tests/test_render.py.)"""
    _save_with_arrays(tmp_path, **arrays)
    with pytest.raises(FileFormatError, match=match):
        Result.load(tmp_path)


@pytest.mark.parametrize("damage", ["missing", "empty", "corrupt", "not_a_result", "bad_npz", "missing_npz"])
def test_bad_folders_name_the_file(tmp_path, damage):
    d = tmp_path / "r"
    make_result(state_trajectory()).save(d)
    name = "trajectory.npz" if damage in ("bad_npz", "missing_npz") else "result.json"
    if damage in ("missing", "missing_npz"):  # a lost trajectory file loaded as a result without one
        (d / name).unlink()
    elif damage == "empty":
        (d / name).write_text("")
    elif damage == "corrupt":
        (d / name).write_text('{"problem": ')
    elif damage == "not_a_result":
        (d / name).write_text('{"problem": "x"}')
    else:
        (d / name).write_bytes(b"PK\x03\x04 not a zip")
    with pytest.raises(FileFormatError, match=name):
        Result.load(d)


def test_a_trajectory_file_that_is_no_archive_is_not_called_a_pickle(tmp_path):
    """numpy takes a file that is no zip archive for a pickle: the message advised loading it
    unsafely (allow_pickle) for a file of text."""
    d = tmp_path / "r"
    make_result(state_trajectory()).save(d)
    (d / "trajectory.npz").write_text("junk")
    with pytest.raises(FileFormatError) as info:
        Result.load(d)
    assert str(info.value) == f"{d / 'trajectory.npz'}: not a readable NPZ file (not a zip archive)"


def test_summary_does_not_split_a_time_the_solver_did_not_split():
    """jtraj's solver runs as one compiled program and reports time_evaluations 0: the summary
    read "derivatives 0.00 s, jtraj 0.29 s", a split that was never measured."""
    split = make_result(None).summary()
    assert split.endswith("0.75 s (compile 3.5 s; derivatives 0.25 s, ipopt 0.50 s)")
    whole = make_result(None, solver="jtraj", stats=Stats(iterations=12, time_total=0.29, time_evaluations=0.0)).summary()
    assert whole.endswith("0.29 s (compile 3.5 s; not split between the NLP's functions and jtraj)") and "derivatives" not in whole


@pytest.mark.parametrize(
    "status, violation, task_ok, outcome",
    [
        (Status.SOLVED, 1e-9, True, Outcome.SOLVED),
        (Status.ACCEPTABLE, 1e-9, False, Outcome.TASK_FAILED),
        (Status.SOLVED, 0.5, True, Outcome.NOT_CONVERGED),  # converged to an infeasible point
        (Status.SOLVED, 1e-2, True, Outcome.NOT_CONVERGED),  # at the tolerance is not below it
        (Status.MAX_ITER, 1e-9, True, Outcome.NOT_CONVERGED),
    ],
)
def test_from_solution_needs_convergence_and_a_violation_below_the_tolerance(status, violation, task_ok, outcome):
    """A solve is feasible when it converged with a violation below ``feasibility_tol`` (Table
    III's rule for runs, `jtraj.experiments.summarize_robustness`); the task check decides
    between SOLVED and TASK_FAILED only then."""
    from jtraj.solvers import Solution

    n, m = 3, 2
    solution = Solution(
        x=np.zeros(n), status=status, message=status.message, objective=1.0, constraint_violation=violation,
        mult_g=np.zeros(m), mult_x_lower=np.zeros(n), mult_x_upper=np.zeros(n), stats=Stats(iterations=7),
    )
    result = Result.from_solution(
        solution, feasibility_tol=1e-2, task_ok=task_ok, violation_by_group={"dynamics": violation},
        problem="hop", variant="se3", model="go2", solver="ipopt", time_compile=0.0, metrics={}, n_variables=n,
    )
    assert result.status is outcome and result.solver_status is status
    assert result.converged == status.converged and result.constraint_violation == violation and result.n_constraints == m


def test_save_refuses_a_folder_where_its_files_go_before_removing_anything(tmp_path):
    """A folder at keyframes.png (a file save removes) failed with IsADirectoryError half way,
    after the earlier files had been removed."""
    r = make_result(state_trajectory())
    r.save(tmp_path / "r")
    (tmp_path / "r" / "trajectory.png").write_bytes(b"an earlier figure")
    (tmp_path / "r" / "keyframes.png").mkdir()
    with pytest.raises(ValueError, match=r"Result.save: .*keyframes.png is a folder; expected room for the file keyframes.png"):
        r.save(tmp_path / "r")
    assert sorted(p.name for p in (tmp_path / "r").iterdir()) == ["keyframes.png", "result.json", "trajectory.npz", "trajectory.png"]


def test_save_refuses_an_empty_name_a_file_and_an_unwritable_place_before_removing_anything(tmp_path, monkeypatch):
    """``save("")`` (an unset variable) wrote into the current folder and removed its figures
    and provenance.json; a file's path or /proc raised the OS's FileExistsError or
    FileNotFoundError. Each is refused as `jtraj.solve`'s ``out`` is, before anything is touched."""
    r = make_result(state_trajectory())
    monkeypatch.chdir(tmp_path)
    for name in ("plot.png", "provenance.json", "notes.txt"):
        (tmp_path / name).write_text("the user's")
    with pytest.raises(ValueError, match=r"Result.save: directory='': expected a folder name"):
        r.save("")
    (tmp_path / "afile").write_text("x")
    with pytest.raises(ValueError, match=r"Result.save: directory='afile': is a file; expected a folder"):
        r.save("afile")
    with pytest.raises(ValueError, match=r"Result.save: directory='/proc/jtraj-x': cannot create a file in /proc"):
        r.save("/proc/jtraj-x")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile", "notes.txt", "plot.png", "provenance.json"]
