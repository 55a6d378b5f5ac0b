"""Re-running one cell of a campaign (`--only`) and the Python recipe run as a script."""

import subprocess
import sys
import types

import pytest

from acl3d.campaign.executors import check_executor
from acl3d.campaign.spec import load_spec
from acl3d.cli import main
from acl3d.cli.campaign import narrowed


def test_only_keeps_one_teacher_and_seed():
    spec = narrowed(load_spec("stump-v1"), ["teacher=alp-gmm", "seed=1"])
    assert [r.name for r in spec.expand()] == ["alp-gmm__s1"]


def test_labels_of_one_axis_add_up():
    spec = narrowed(
        load_spec("stump-v2"), ["teacher=random", "teacher=alp-gmm", "seed=1", "seed=0"]
    )
    names = [r.name for r in spec.expand()]
    assert sorted(names) == ["alp-gmm__s0", "alp-gmm__s1", "random__s0", "random__s1"]


@pytest.mark.parametrize(
    ("rule", "message"),
    [
        ("teacher=foo", "teacher is one of random"),
        ("color=red", "axes: teacher, seed"),
        ("seed=x", "integer"),
        ("teacher", "AXIS=LABEL"),
    ],  # fmt: skip
)
def test_only_names_what_is_valid(rule, message):
    with pytest.raises(ValueError, match=message):
        narrowed(load_spec("stump-v1"), [rule])


def test_cli_shows_the_one_cell(capsys):
    assert (
        main(["campaign", "show", "stump-v1", "--only", "teacher=oracle", "--only", "seed=2"]) == 0
    )
    assert "# 1 runs" in capsys.readouterr().out


def test_a_worker_reimporting_an_unguarded_script_gets_the_fix(monkeypatch):
    worker_main = types.ModuleType("__mp_main__")
    worker_main.__file__ = "recipe.py"
    monkeypatch.setitem(sys.modules, "__main__", worker_main)
    with pytest.raises(RuntimeError, match='if __name__ == "__main__"'):
        check_executor("local", 2)


UNGUARDED = """
import multiprocessing, sys
from acl3d.campaign.executors import check_executor

check_executor("local", 1)  # at top level, as run_campaign in an unguarded recipe
if __name__ == "__main__":
    worker = multiprocessing.get_context("spawn").Process(target=len, args=((),))
    worker.start()
    worker.join()
    sys.exit(worker.exitcode)
"""


def test_a_spawned_worker_running_an_unguarded_script_gets_the_fix(tmp_path):
    """A real spawn worker: while it re-runs the script, its `__main__` is still its own (the
    check above once looked only there, and the worker died on the campaign lock)."""
    script = tmp_path / "recipe.py"
    script.write_text(UNGUARDED)
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 1, done.stderr
    assert f"worker imported {script}: put the call under" in done.stderr
