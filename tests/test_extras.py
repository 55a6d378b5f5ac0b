"""The light core install and its extras: what works without them, what says which to install."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from acl3d.extras import PACKAGES, MissingExtraError, optional_dependency

ROOT = Path(__file__).resolve().parents[1]

# Runs in a fresh interpreter where every optional package fails to import, as in a core install.
_WITHOUT_EXTRAS = """
import importlib.abc, json, sys
from acl3d.extras import PACKAGES, MissingExtraError

class NotInstalled(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split(".")[0] in PACKAGES:
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)

sys.meta_path.insert(0, NotInstalled())
import gymnasium as gym
import numpy as np
import acl3d
from acl3d import teachers
from acl3d.cli import main


out = {"envs": {}, "teachers": {}, "errors": {}}
from acl3d.envs import ENV_IDS
for env_id in ENV_IDS.values():
    env = gym.make(env_id)
    env.reset(seed=0)
    obs, reward, *_ = env.step(env.action_space.sample())
    out["envs"][env_id] = bool(np.isfinite(reward))
venv = gym.make_vec("acl3d/StumpTracks-v0", num_envs=2, vectorization_mode="vector_entry_point")
venv.reset(seed=0)
venv.step(venv.action_space.sample())
space = gym.make("acl3d/StumpTracks-v0").unwrapped.task_space
for name in teachers.TEACHERS:
    params = {"curriculum": {"measure": "reward", "thresholds": [1.0],
                             "parameters": {"stump_height": [0.0, 1.0]}}} if name == "lessons" else {}
    try:
        teachers.make(name, space, seed=0, **params).sample_task()
        out["teachers"][name] = "ok"
    except MissingExtraError as exc:
        out["teachers"][name] = str(exc)
def error(call):
    try:
        call()
    except MissingExtraError as exc:
        return str(exc)
    return None
out["errors"]["train"] = error(lambda: __import__("acl3d.training", fromlist=["x"]).train)
out["errors"]["dmc"] = error(lambda: gym.make("acl3d/StumpTracks-v0", body="dmc:ant"))
out["errors"]["sb3"] = error(lambda: __import__("acl3d.vec.batched_sb3"))
out["errors"]["sklearn"] = error(lambda: teachers.make("alp-gmm", space, gmm_backend="sklearn"))
out["cli_train"] = main(["train", "--steps", "1000", "--out", "unused-run"])
out["cli_campaign"] = main(["campaign", "run", "quick", "--out", "unused-campaign"])
print("RESULT " + json.dumps(out))
"""


@pytest.fixture(scope="module")
def without_extras(tmp_path_factory):
    cwd = tmp_path_factory.mktemp("core")
    done = subprocess.run(
        [sys.executable, "-c", _WITHOUT_EXTRAS],
        capture_output=True,
        text=True,
        cwd=cwd,
        env={**_env(), "PYTHONPATH": str(ROOT)},
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    line = next(x for x in done.stdout.splitlines() if x.startswith("RESULT "))
    assert not (cwd / "unused-run").exists()  # the refused commands wrote nothing
    assert not (cwd / "unused-campaign").exists()
    return json.loads(line[len("RESULT ") :]), done.stderr


def _env():
    import os

    return {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}


def test_the_core_runs_every_environment_without_the_extras(without_extras):
    out, _ = without_extras
    assert out["envs"] and all(out["envs"].values())


def test_torch_teachers_name_the_train_extra_and_the_others_run(without_extras):
    out, _ = without_extras
    needs_torch = {"self-paced", "goal-gan", "setter-solver"}
    for name, result in out["teachers"].items():
        if name in needs_torch:
            assert "'torch'" in result and 'pip install "acl3d[train]"' in result, result
        else:
            assert result == "ok", (name, result)


def test_missing_extras_are_named_with_their_install_command(without_extras):
    out, stderr = without_extras
    assert 'pip install "acl3d[train]"' in out["errors"]["train"]
    assert 'pip install "acl3d[dmc]"' in out["errors"]["dmc"]
    assert 'pip install "acl3d[train]"' in out["errors"]["sb3"]
    assert 'gmm_backend="sklearn"' in out["errors"]["sklearn"]
    assert 'pip install "acl3d[sklearn]"' in out["errors"]["sklearn"]
    assert out["cli_train"] == out["cli_campaign"] == 1
    assert re.search(r"acl3d campaign: error: .*pip install \"acl3d\[campaign\]\"", stderr)
    assert re.search(r"acl3d train: error: .*pip install \"acl3d\[train\]\"", stderr)


def test_every_optional_package_belongs_to_its_extra_and_not_to_the_core():
    tomllib = pytest.importorskip("tomllib")
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = project["optional-dependencies"]

    def names(requirements):
        return {re.split(r"[<>=\[ ;]", r, maxsplit=1)[0].lower() for r in requirements}

    core = names(project["dependencies"])
    for module, (package, extra) in PACKAGES.items():
        assert package not in core, f"{package} is optional ({extra}) but a core dependency"
        assert package in names(extras[extra]), f"{module}: {package} missing from [{extra}]"
    assert {"train", "campaign", "dmc", "sklearn", "video", "all", "dev"} <= set(extras)
    (everything,) = extras["all"]
    assert everything.startswith("acl3d[") and everything.endswith("]")
    assert set(everything[len("acl3d[") : -1].split(",")) == {e for _, e in PACKAGES.values()}


def test_optional_dependency_leaves_other_import_errors_alone():
    with pytest.raises(ModuleNotFoundError) as info, optional_dependency("something"):
        raise ModuleNotFoundError("No module named 'not_an_extra'", name="not_an_extra")
    assert not isinstance(info.value, MissingExtraError)
    with pytest.raises(MissingExtraError, match=r"acl3d\[campaign\]"), optional_dependency("x"):
        raise ModuleNotFoundError("No module named 'ray.util'", name="ray.util")


def test_a_ray_campaign_without_ray_is_refused_before_its_directory(tmp_path, monkeypatch, capsys):
    from acl3d.cli import main

    monkeypatch.setitem(sys.modules, "ray", None)  # [train] installed, [campaign] not
    assert main(["campaign", "run", "quick", "--out", str(tmp_path / "camp")]) == 1
    assert not (tmp_path / "camp").exists()
    assert "'ray'" in capsys.readouterr().err
    assert main(["campaign", "show", "quick"]) == 0  # what needs no Ray still works
