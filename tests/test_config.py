"""Process-wide settings (`jtraj.config`): JAX's CPU devices, chosen by ``import jtraj``."""

import os
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from jtraj import config


def _environment(env: dict[str, str]) -> dict[str, str]:
    """This process's environment without its CPU device count, plus ``env``."""
    clean = {k: v for k, v in os.environ.items() if k not in ("JTRAJ_CPU_DEVICES", "JAX_NUM_CPU_DEVICES")}
    clean["XLA_FLAGS"] = " ".join(f for f in clean.get("XLA_FLAGS", "").split() if "device_count" not in f)
    return {**clean, **env}


def _devices_after_import(env: dict[str, str], before: str = "") -> subprocess.CompletedProcess:
    """A fresh interpreter imports jtraj (after ``before``) and prints its CPU device count."""
    code = f"import jax\n{before}\nimport jtraj\nprint(len(jax.devices('cpu')))"
    return subprocess.run([sys.executable, "-c", code], env=_environment(env), capture_output=True, text=True, timeout=120)


def _command_lines() -> list[list[str]]:
    """The ways to run jtraj's command line: the console script where it is installed beside
    this interpreter, ``python -m jtraj`` and ``python -m jtraj.cli``."""
    script = Path(sys.executable).with_name("jtraj")
    return ([[str(script)]] if script.is_file() else []) + [[sys.executable, "-m", "jtraj"], [sys.executable, "-m", "jtraj.cli"]]


def test_import_gives_one_cpu_device_per_core():
    cores = len(os.sched_getaffinity(0))  # counted here, not by the function under test
    if cores < 2:
        pytest.skip("one core: one device is also JAX's default, so the count would check nothing")
    out = _devices_after_import({})
    assert out.returncode == 0, out.stderr
    assert int(out.stdout) == cores


@pytest.mark.parametrize(
    "env, before, expected",
    [
        ({"JTRAJ_CPU_DEVICES": "3"}, "", 3),
        ({"JTRAJ_CPU_DEVICES": "1"}, "", 1),
        # the user's own choice wins, and so does a JAX that has computed already
        ({"JAX_NUM_CPU_DEVICES": "4", "JTRAJ_CPU_DEVICES": "3"}, "", 4),
        ({"XLA_FLAGS": "--xla_force_host_platform_device_count=5"}, "", 5),
        ({"JTRAJ_CPU_DEVICES": "3"}, "jax.numpy.zeros(1)", 1),
    ],
)
def test_cpu_devices_follow_the_environment(env, before, expected):
    out = _devices_after_import(env, before)
    assert out.returncode == 0, out.stderr
    assert int(out.stdout) == expected


def test_a_bad_device_count_says_what_is_expected():
    # `import jtraj` from Python raises the ValueError
    out = _devices_after_import({"JTRAJ_CPU_DEVICES": "two"})
    assert out.returncode != 0 and "ValueError: JTRAJ_CPU_DEVICES='two': expected a positive whole number of CPU devices\n" in out.stderr


@pytest.mark.parametrize(
    "value, line",
    [
        ("two", "JTRAJ_CPU_DEVICES='two': expected a positive whole number of CPU devices"),
        # the message names the variable that gave the count, not only the count
        ("0", "JTRAJ_CPU_DEVICES='0': 0 CPU devices; expected a positive count (unset JTRAJ_CPU_DEVICES for one device per core)"),
        ("-2", "JTRAJ_CPU_DEVICES='-2': -2 CPU devices; expected a positive count (unset JTRAJ_CPU_DEVICES for one device per core)"),
        # int() read "1_6" as 16 devices
        ("1_6", "JTRAJ_CPU_DEVICES='1_6': expected a positive whole number of CPU devices"),
    ],
)
def test_a_bad_device_count_is_one_line_of_the_command_line(value, line):
    # every command, --help too, ended in an 8-line traceback from `import jtraj`
    runs = [[*command, *argv] for command in _command_lines() for argv in (["--help"], ["solve", "big_jump"])] if value == "two" else [[*_command_lines()[0], "--help"]]
    for argv in runs:
        out = subprocess.run(argv, env=_environment({"JTRAJ_CPU_DEVICES": value}), capture_output=True, text=True, timeout=120)
        assert (out.returncode, out.stderr, out.stdout) == (2, f"jtraj: {line}\n", ""), argv


def test_split_cpu_leaves_a_started_jax_alone():
    # this process computed already (conftest set two devices before jtraj's import)
    assert len(jax.devices("cpu")) == 2
    assert config.split_cpu(3) is None
    assert len(jax.devices("cpu")) == 2


@pytest.mark.parametrize(
    "env, expected",
    [
        ({"JTRAJ_NO_CACHE": "1"}, None),
        # 0 turned the cache off as well (any non-empty value did): every process compiled again
        ({"JTRAJ_NO_CACHE": "0"}, "default"),
        ({"JTRAJ_NO_CACHE": "false"}, "default"),
        # an empty folder name put the cache into the working directory
        ({"JTRAJ_CACHE_DIR": ""}, "default"),
        ({"JTRAJ_CACHE_DIR": "elsewhere"}, "elsewhere"),
        # a "~" was not expanded: a folder named "~" in the working directory
        ({"JTRAJ_CACHE_DIR": "~/cache"}, "home/cache"),
    ],
)
def test_cache_switches_read_as_documented(monkeypatch, tmp_path, env, expected):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    for name in ("JTRAJ_NO_CACHE", "JTRAJ_CACHE_DIR"):
        monkeypatch.delenv(name, raising=False)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    updates: dict = {}
    monkeypatch.setattr(jax.config, "update", lambda name, value: updates.__setitem__(name, value))  # this process's cache stays as it is
    # a fresh process's state: no cache chosen yet, by jtraj or for JAX (this one's, e.g. CI's
    # JTRAJ_CACHE_DIR, would be kept as a cache set up before)
    monkeypatch.setattr(config, "_enabled", None)
    monkeypatch.setattr(config, "_given", False)
    monkeypatch.setattr(config, "_jax_cache_dir", lambda: None)
    target = config.enable_compilation_cache()
    if expected is None:
        assert target is None and not updates
    else:
        want = tmp_path / "xdg" / "jtraj" / "jax" if expected == "default" else tmp_path / expected
        assert target is not None and target.absolute() == want and updates["jax_compilation_cache_dir"] == str(target)


def test_a_cache_folder_that_cannot_be_made_warns_and_leaves_the_cache_off(monkeypatch, tmp_path):
    # mkdir's error (here a file where the folder should be; a read-only home the same) failed every solve
    (tmp_path / "file").write_text("")
    monkeypatch.delenv("JTRAJ_NO_CACHE", raising=False)
    monkeypatch.setenv("JTRAJ_CACHE_DIR", str(tmp_path / "file" / "cache"))
    updates: dict = {}
    monkeypatch.setattr(jax.config, "update", lambda name, value: updates.__setitem__(name, value))
    monkeypatch.setattr(config, "_enabled", None)
    monkeypatch.setattr(config, "_jax_cache_dir", lambda: None)
    with pytest.warns(RuntimeWarning, match="cannot be made .*set JTRAJ_CACHE_DIR to a writable folder, or JTRAJ_NO_CACHE=1"):
        assert config.enable_compilation_cache() is None
    assert not updates and config._enabled is None


def test_split_cpu_takes_whole_counts_only(monkeypatch):
    # JAX itself refused numpy's integers, took True as one device and said of 2.5 only that it wants an int
    from types import SimpleNamespace

    updates: dict = {}
    fake = SimpleNamespace(config=SimpleNamespace(jax_num_cpu_devices=-1, update=lambda name, value: updates.__setitem__(name, value)))
    monkeypatch.setattr(config, "jax", fake)  # a JAX that has not chosen its devices yet
    monkeypatch.setenv("XLA_FLAGS", "")
    for count in (2.5, True, "2", 0, -1):
        with pytest.raises(ValueError, match=r"split_cpu\(count=.*\): expected a positive whole number of CPU devices"):
            config.split_cpu(count)
    assert not updates
    assert config.split_cpu(np.int64(3)) == 3 and updates == {"jax_num_cpu_devices": 3} and type(updates["jax_num_cpu_devices"]) is int


def test_a_later_cache_folder_or_switch_takes_effect():
    """JAX sets its persistent cache up once: a second call's folder (or JTRAJ_NO_CACHE=1 set
    after the first) was returned while the entries still went to the first folder. A fresh
    interpreter (this process's cache stays as it is) compiles a tiny program after each call."""
    code = """
import os, sys, tempfile
import jax, jax.numpy as jnp
from jtraj import config
first, second = tempfile.mkdtemp(), tempfile.mkdtemp()
def compile_one(k):  # a new program, cached however quickly it compiles
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
    jax.jit(lambda x: jnp.sin(x) * k + k)(jnp.ones(k)).block_until_ready()
    return [len(os.listdir(d)) for d in (first, second)]
assert str(config.enable_compilation_cache(first)) == first
one = compile_one(2)
assert one[0] > 0 and one[1] == 0, one
assert str(config.enable_compilation_cache(second)) == second
two = compile_one(3)
assert two[0] == one[0] and two[1] > 0, (one, two)
os.environ["JTRAJ_NO_CACHE"] = "1"
assert config.enable_compilation_cache() is None and jax.config.jax_compilation_cache_dir is None
assert compile_one(4) == two, two
del os.environ["JTRAJ_NO_CACHE"]
assert str(config.enable_compilation_cache(first)) == first
three = compile_one(5)
assert three[0] > two[0] and three[1] == two[1], (two, three)
print("ok")
"""
    env = _environment({"JTRAJ_CPU_DEVICES": "1"})
    for name in ("JTRAJ_NO_CACHE", "JTRAJ_CACHE_DIR"):
        env.pop(name, None)
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout == "ok\n", out.stderr


def test_a_cache_the_user_set_up_for_jax_is_left_as_it_is(tmp_path):
    """jtraj.solve and differentiable turn the cache on without arguments: they overwrote the
    folder and thresholds a user had given JAX. A folder given to jtraj (path=, or
    JTRAJ_CACHE_DIR) still takes effect. A fresh interpreter, so this process's cache stays."""
    code = f"""
import os
import jax
from jtraj import config
mine = {str(tmp_path / "mine")!r}
jax.config.update("jax_compilation_cache_dir", mine)
jax.config.update("jax_persistent_cache_min_compile_time_secs", 5.0)
assert str(config.enable_compilation_cache()) == mine
assert jax.config.jax_compilation_cache_dir == mine and jax.config.jax_persistent_cache_min_compile_time_secs == 5.0
theirs = {str(tmp_path / "jtraj")!r}
assert str(config.enable_compilation_cache(theirs)) == theirs == jax.config.jax_compilation_cache_dir
assert jax.config.jax_persistent_cache_min_compile_time_secs == 0.2
assert str(config.enable_compilation_cache()) == theirs  # jtraj's own, once chosen, stays
# ... also where JTRAJ_CACHE_DIR was set when it was chosen, until that changes
os.environ["JTRAJ_CACHE_DIR"] = env = {str(tmp_path / "env1")!r}
given = {str(tmp_path / "given")!r}
assert str(config.enable_compilation_cache(given)) == given
assert str(config.enable_compilation_cache()) == given
os.environ["JTRAJ_CACHE_DIR"] = moved = {str(tmp_path / "env2")!r}
assert str(config.enable_compilation_cache()) == moved == jax.config.jax_compilation_cache_dir
print("ok")
"""
    env = _environment({"JTRAJ_CPU_DEVICES": "1"})
    for name in ("JTRAJ_NO_CACHE", "JTRAJ_CACHE_DIR", "JAX_COMPILATION_CACHE_DIR"):
        env.pop(name, None)
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr[-2000:]
    # JAX's own variable is a cache set up for JAX too
    code = "import jax; from jtraj import config; print(config.enable_compilation_cache(), jax.config.jax_persistent_cache_min_compile_time_secs)"
    out = subprocess.run([sys.executable, "-c", code], env={**env, "JAX_COMPILATION_CACHE_DIR": str(tmp_path / "env")}, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.split() == [str(tmp_path / "env"), "1.0"], (out.stdout, out.stderr[-2000:])


def test_what_the_cache_call_returns_is_where_jax_caches(tmp_path):
    """A folder that could not be made returned None ("no compilation cache") while JAX went on
    writing to the earlier folder; a cache jtraj turned on and the user turned off for JAX was
    reported on, or turned on again at the default folder. A fresh interpreter."""
    code = f"""
import warnings
import jax
from jtraj import config
first = {str(tmp_path / "first")!r}
assert str(config.enable_compilation_cache(first)) == first
with warnings.catch_warnings(record=True) as said:
    warnings.simplefilter("always")
    assert str(config.enable_compilation_cache({str(tmp_path / "file" / "cache")!r})) == first
assert jax.config.jax_compilation_cache_dir == first
assert len(said) == 1 and f"the compilations go on to {{first!r}}" in str(said[0].message), [str(w.message) for w in said]
jax.config.update("jax_compilation_cache_dir", None)  # the user's: no cache
assert config.enable_compilation_cache() is None and jax.config.jax_compilation_cache_dir is None
again = {str(tmp_path / "again")!r}  # a folder asked for turns it on again
assert str(config.enable_compilation_cache(again)) == again == jax.config.jax_compilation_cache_dir
print("ok")
"""
    (tmp_path / "file").write_text("")
    env = _environment({"JTRAJ_CPU_DEVICES": "1"})
    for name in ("JTRAJ_NO_CACHE", "JTRAJ_CACHE_DIR", "JAX_COMPILATION_CACHE_DIR"):
        env.pop(name, None)
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr[-2000:]
