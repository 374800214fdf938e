"""The public API as a user meets it: every module's ``__all__`` names something that exists
and is documented, ``dir(jtraj)`` and ``help(jtraj)`` show the lazily imported names, and the
former names still work with a warning that gives the new one."""

import importlib
import inspect
import pkgutil
import pydoc
import re
import warnings

import pytest

import jtraj


def _modules() -> list[str]:
    names = ["jtraj"]
    for info in pkgutil.walk_packages(jtraj.__path__, "jtraj."):
        names.append(info.name)
    return sorted(names)


MODULES = _modules()

def test_the_walk_finds_the_subpackages():
    assert {"jtraj.solver", "jtraj.solvers.ipm", "jtraj.attitude.wahba", "jtraj.provenance"} <= set(MODULES)


@pytest.mark.parametrize("name", MODULES)
def test_all_names_exist_and_are_documented(name):
    module = importlib.import_module(name)
    assert inspect.getdoc(module), f"{name} has no module docstring"
    exported = getattr(module, "__all__", None)
    if name == "jtraj.cli":  # the command line: main() is its interface
        return
    assert exported is not None, f"{name} has no __all__: `from {name} import *` would take its imports too"
    assert len(set(exported)) == len(exported), f"{name}.__all__ repeats a name"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a name in __all__ is not a deprecated one
        for entry in exported:
            assert isinstance(entry, str)
            assert hasattr(module, entry), f"{name}.__all__ names {entry!r}, which {name} does not have"
            obj = getattr(module, entry)
            if callable(obj) or inspect.ismodule(obj):
                # functions, classes, jitted and cached functions alike
                assert inspect.getdoc(obj), f"{name}.{entry} has no docstring"
            if inspect.isclass(obj):
                # a class's own: getdoc falls back on its base's (an Enum's "Create a collection
                # of name/value pairs"), and dataclass writes "Name(field, ...)" where none is
                assert _own_docstring(obj), f"{name}.{entry} has no docstring of its own"


def _own_docstring(cls: type) -> bool:
    doc = vars(cls).get("__doc__")
    return bool(doc and doc.strip()) and not doc.startswith(f"{cls.__name__}(")


def test_own_docstring_sees_through_inherited_and_generated_ones():
    import dataclasses
    import enum

    class Bare(enum.Enum):
        A = 1

    @dataclasses.dataclass
    class Plain:
        x: int

    @dataclasses.dataclass
    class Said:
        """Documented."""

        x: int

    assert inspect.getdoc(Bare) and inspect.getdoc(Plain)  # what the check above used to accept
    assert not _own_docstring(Bare) and not _own_docstring(Plain) and _own_docstring(Said)


def test_star_import_gives_every_name_of_jtraj_all():
    namespace: dict = {}
    exec("from jtraj import *", namespace)
    assert set(jtraj.__all__) <= set(namespace)


def test_dir_and_help_show_the_lazily_imported_names():
    # solve, Result, load_task... are imported on first use (module __getattr__); dir() did not
    # list them, and so help(jtraj) documented none of them
    assert set(jtraj.__all__) <= set(dir(jtraj))
    text = pydoc.render_doc(jtraj, renderer=pydoc.plaintext)
    for name in ("solve", "load_task", "load_robot", "differentiable", "OptimalMotion", "TaskParams"):
        # the entry itself: "\n    solve" alone also matched the submodule line "    solver"
        assert re.search(rf"\n    {name}(\(| = |\n)", text) or f"class {name}" in text, name
    # the private alias of jtraj.config that `import jtraj` uses was listed as a submodule
    # (pydoc's SUBMODULES section itself depends on what else this process imported: the
    # package-data folders jtraj.robots and jtraj.tasks appear there once read)
    assert "_config" not in dir(jtraj) and "\n    _config\n" not in text


@pytest.mark.parametrize(
    "module, old, new",
    [
        ("jtraj.solver", "LAYOUTS", "jtraj.solver.VARIABLES"),
        ("jtraj.transcription", "PAPER_LAYOUT", "jtraj.transcription.PAPER_VARIABLES"),
        ("jtraj.dynamics", "inverse_dynamics_jacobians", "jtraj.dynamics.batched_inverse_dynamics_derivatives"),
    ],
)
def test_former_names_warn_with_the_new_name(module, old, new):
    m = importlib.import_module(module)
    with pytest.warns(DeprecationWarning, match=new.replace(".", r"\.")):
        value = getattr(m, old)
    assert value is getattr(m, new.rsplit(".", 1)[1])


def test_submodules_are_attributes_of_a_fresh_import():
    """``jtraj.solvers.IpoptOptions`` (as docstrings write it) was an AttributeError after
    ``import jtraj`` until a lazy name had imported the module; `import jtraj` still imports
    none of them, and an unknown name is still an AttributeError."""
    import os
    import subprocess
    import sys

    code = """
import sys
import jtraj
heavy = ("jtraj.solver", "jtraj.solvers", "jtraj.robot", "jtraj.render", "mujoco")
assert not [m for m in heavy if m in sys.modules], [m for m in heavy if m in sys.modules]
assert jtraj.solvers.IpoptOptions.__name__ == "IpoptOptions"
for name in ("solver", "task", "transcription", "experiments", "result", "robot", "attitude"):
    assert getattr(jtraj, name) is sys.modules["jtraj." + name], name
for name in ("no_such_name", "_private"):
    try:
        getattr(jtraj, name)
    except AttributeError as e:
        assert str(e) == f"module 'jtraj' has no attribute {name!r}", str(e)
    else:
        raise AssertionError(name)
print("ok")
"""
    env = {**os.environ, "JTRAJ_CPU_DEVICES": "1"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout == "ok\n", out.stderr
