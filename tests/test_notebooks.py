"""The notebooks run top to bottom in their small mode (JTRAJ_SMALL=1) and produce what they show:
every code cell ran, the files each one writes are there (under the repository's runs/notebooks/,
which git ignores, and none beside the notebook), and its figures and key lines are in the
outputs."""

import contextlib
import io
import json
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOKS = sorted((Path(__file__).parent.parent / "notebooks").glob("*.ipynb"))

#: Per notebook: files it writes (relative to the repository root, the parent of the notebooks/
#: folder Jupyter runs it in), the least number of images it displays, and text its outputs must
#: contain.
PRODUCES = {
    "attitude": dict(files=(), images=2, text=("small mode", "final median error", "satellite: minimum camera-sun angle", "quadrotor:")),
    "comparison": dict(files=("runs/notebooks/compare_small/table_iv.json", "runs/notebooks/compare_small/table_iv.md", "runs/notebooks/comparison.png"), images=1, text=("| hop | go2 | se3 | solved |", "| hop | go2 | euler | solved |", "hop ['hop_se3', 'hop_euler']")),
    "design": dict(files=(), images=2, text=("degenerate:",)),
    "quickstart": dict(files=("runs/notebooks/trajectory.png",), images=1, text=("hop [", "] solved: ", "se3    solved ", "euler  solved ")),
    "robustness": dict(files=("runs/notebooks/robustness_small/runs.jsonl", "runs/notebooks/fig2.png"), images=1, text=("8 runs from ", "| task | parameterization | sigma=0.001 | sigma=0.1 |", "| hop | se3 | ")),
}


def _outputs(nb) -> list[dict]:
    return [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])]


def _text(output: dict) -> str:
    if output.get("output_type") == "stream":
        return output.get("text", "")
    return output.get("data", {}).get("text/plain", "") + output.get("data", {}).get("text/markdown", "")


def test_every_notebook_has_expectations():
    assert {p.stem for p in NOTEBOOKS} == set(PRODUCES)


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_runs(path, tmp_path, monkeypatch):
    # tmp_path stands for the repository root: Jupyter runs a notebook in the notebooks/ folder
    here = tmp_path / "notebooks"
    here.mkdir()
    monkeypatch.setenv("JTRAJ_SMALL", "1")
    monkeypatch.chdir(here)
    nb = nbformat.read(path, as_version=4)
    # a failing cell raises CellExecutionError here
    NotebookClient(nb, timeout=900, kernel_name="python3", resources={"metadata": {"path": str(here)}}).execute()
    want = PRODUCES[path.stem]
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert code and all(c.get("execution_count") for c in code), "a code cell did not run"
    for name in want["files"]:
        f = tmp_path / name
        assert f.is_file() and f.stat().st_size > 0, f"{path.name} did not write {name}"
    # what it writes beside the notebook would be an untracked file in the checkout's notebooks/
    assert not any(here.iterdir()), f"{path.name} wrote {sorted(p.name for p in here.iterdir())} into notebooks/"
    images = [o for o in _outputs(nb) if "image/png" in o.get("data", {})]
    assert len(images) >= want["images"], f"{path.name} displayed {len(images)} images, expected at least {want['images']}"
    text = "".join(_text(o) for o in _outputs(nb))
    for line in want["text"]:
        assert line in text, f"{path.name}'s outputs lack {line!r}"
    if path.stem == "robustness":
        runs = [json.loads(line) for line in (tmp_path / "runs/notebooks/robustness_small/runs.jsonl").read_text().splitlines() if line.strip()]
        assert len(runs) == 2 * 2 * 2  # two parameterizations, two sigmas, two replicates
        assert {(r["parameterization"], r["sigma"]) for r in runs} == {(p, s) for p in ("se3", "euler") for s in (1e-3, 0.1)}


@pytest.mark.parametrize(("name", "variable", "default", "file"), [("comparison", "JTRAJ_COMPARE", "runs/table_iv", "table_iv.json"), ("robustness", "JTRAJ_ROBUSTNESS", "runs/robustness", "runs.jsonl")])
def test_notebook_reads_the_repository_runs_folder_from_notebooks(name, variable, default, file, tmp_path, monkeypatch, capsys):
    # `jtraj compare` / `jtraj robustness` from the repository root write runs/... there, and
    # Jupyter runs the notebook in notebooks/: the default folder is the root's, not notebooks/runs/
    here = tmp_path / "notebooks"
    here.mkdir()
    monkeypatch.delenv("JTRAJ_SMALL", raising=False)
    monkeypatch.delenv(variable, raising=False)
    monkeypatch.chdir(here)
    nb = nbformat.read(next(p for p in NOTEBOOKS if p.stem == name), as_version=4)
    cell = next(c.source for c in nb.cells if c.cell_type == "code")  # the one that finds the folder
    folder = (tmp_path / default).resolve()
    with pytest.raises(FileNotFoundError) as missing:
        exec(cell, {})
    assert str(folder / file) in str(missing.value) and variable in str(missing.value), missing.value
    folder.mkdir(parents=True)
    (folder / file).write_text("[]" if file.endswith(".json") else "")
    capsys.readouterr()
    exec(cell, {})
    assert str(folder) in capsys.readouterr().out
    assert not any(here.iterdir())


def test_comparison_notebook_draws_the_runs_that_have_a_trajectory(tmp_path, monkeypatch):
    # a `jtraj compare` folder where the table's first run, and every run of one task, saved no
    # trajectory (--no-trajectories): the notebook draws the others instead of failing
    import dataclasses

    from test_render import _result

    result = _result()
    folder = tmp_path / "table"
    result.save(folder / "made_up_flip_se3")
    dataclasses.replace(result, trajectory=None).save(folder / "made_up_flip_euler")
    dataclasses.replace(result, trajectory=None).save(folder / "made_up_hop_se3")
    rows = [{"task": task, "parameterization": p, "status": "solved", "iterations": 0} for task, p in (("made_up_flip", "euler"), ("made_up_flip", "se3"), ("made_up_hop", "se3"))]
    (folder / "table_iv.json").write_text(json.dumps(rows))
    (folder / "table_iv.md").write_text("| task | parameterization |\n")
    monkeypatch.delenv("JTRAJ_SMALL", raising=False)
    monkeypatch.setenv("JTRAJ_COMPARE", str(folder))
    monkeypatch.chdir(tmp_path)
    path = next(p for p in NOTEBOOKS if p.stem == "comparison")
    nb = nbformat.read(path, as_version=4)
    NotebookClient(nb, timeout=900, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}).execute()
    text = "".join(_text(o) for o in _outputs(nb))
    for line in ("made_up_flip_euler: no trajectory saved", "made_up_flip ['made_up_flip_se3']", "made_up_hop []"):
        assert line in text, text
    outputs = nb.cells[-1].outputs  # the video of the first run that has a trajectory
    assert outputs and "text/html" in outputs[0].get("data", {}), outputs


def test_robustness_notebook_marks_cells_without_a_converged_run(tmp_path, monkeypatch):
    # a runs file (no solve): at sigma 0.5 no run converged, which the table printed as "0 it"
    def run(sigma, replicate, converged, iterations):
        return {
            "task_hash": "h", "parameterization": "se3", "layout": "paper", "variables_hash": "v", "hessian": "limited-memory", "options_hash": "o",
            "seed": 0, "sigma": sigma, "replicate": replicate, "solver": "ipopt", "noise_chart": None, "task": "hop",
            "converged": converged, "constraint_violation": 0.0 if converged else 1.0, "success": converged, "iterations": iterations,
        }

    folder = tmp_path / "study"
    folder.mkdir()
    runs = [run(1e-3, 0, True, 12), run(1e-3, 1, True, 14), run(0.5, 0, False, 3000), run(0.5, 1, False, 3000)]
    (folder / "runs.jsonl").write_text("".join(json.dumps(r) + "\n" for r in runs))
    monkeypatch.delenv("JTRAJ_SMALL", raising=False)
    monkeypatch.setenv("JTRAJ_ROBUSTNESS", str(folder))
    monkeypatch.chdir(tmp_path)
    nb = nbformat.read(next(p for p in NOTEBOOKS if p.stem == "robustness"), as_version=4)
    NotebookClient(nb, timeout=900, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}).execute()
    table = [line for o in _outputs(nb) for line in _text(o).splitlines() if line.startswith("| hop |")]
    assert table == ["| hop | se3 | 100% / 100% (13) | 0% / 0% (-) |"], table


def test_design_notebook_reports_a_first_solution_that_is_not_differentiable():
    # the optimization cell run alone, its solve replaced by one that is singular at once: the
    # stop at "the last differentiable timestep" read history[-1] of an empty history (IndexError)
    import types

    import jax.numpy as jnp
    import optax

    nb = nbformat.read(next(p for p in NOTEBOOKS if p.stem == "design"), as_version=4)
    cell = next(c.source for c in nb.cells if c.cell_type == "code" and "value_and_grad" in c.source)

    from jtraj.sensitivity import SINGULAR_PREFIX, SingularKKTError

    # the message as a jitted derivative passes it on: JAX's error, ending with the
    # sensitivity's own (the cell looked for "not differentiable here", words of an earlier
    # message that no error has now, and so re-raised where it was to stop)
    message = f"INTERNAL: CpuCallback error: {SingularKKTError.__name__}: {SINGULAR_PREFIX} is singular (Factor is exactly singular) at this solution"

    def singular(log_h):
        raise RuntimeError(message)

    fake_jax = types.SimpleNamespace(jit=lambda f: singular, value_and_grad=lambda f: f)
    theta0 = types.SimpleNamespace(timestep=0.05, replace=lambda **changes: theta0)
    names = {"jax": fake_jax, "jnp": jnp, "optax": optax, "hop": None, "theta0": theta0, "SMALL": True, "SINGULAR_PREFIX": SINGULAR_PREFIX}
    with pytest.raises(RuntimeError, match="is singular"):
        exec(cell, dict(names))
    # singular after one good timestep: the design stops there, back at that timestep
    calls = []

    def once(log_h):
        calls.append(float(log_h))
        if len(calls) > 1:
            raise RuntimeError(message)
        return jnp.asarray(3.0), jnp.asarray(1.0)

    stopped = dict(names, jax=types.SimpleNamespace(jit=lambda f: once, value_and_grad=lambda f: f))
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        exec(cell, stopped)
    assert "the solution is not differentiable here; stopping" in printed.getvalue()
    assert [h for _, h, _ in stopped["history"]] == [pytest.approx(0.05)]
    assert float(jnp.exp(stopped["log_h"])) == pytest.approx(0.05)
    # any other error is raised as it is
    other = dict(names, jax=types.SimpleNamespace(jit=lambda f: lambda log_h: (_ for _ in ()).throw(ValueError("bad input")), value_and_grad=lambda f: f))
    with pytest.raises(ValueError, match="bad input"):
        exec(cell, other)
