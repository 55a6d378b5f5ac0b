"""Campaign mistakes that must change nothing: bad spec values refused before anything is
written, one campaign process per directory (an atomic lock), and no attempt started in a run
directory where another process still works."""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path

import pytest
import yaml

from acl3d.campaign import CampaignDir, CampaignSpec, load_spec, run_campaign
from acl3d.campaign.attempt import run_attempt
from acl3d.campaign.lock import LockBusy
from acl3d.campaign.spec import check_runs
from acl3d.cli import main

TINY = {"n_envs": 1, "vec_env": "dummy", "nb_test_episodes": 4, "steps": 512, "verbose": 0}


@pytest.mark.parametrize(
    "sets, message",
    [
        (["steps=-5"], "steps=-5"),
        (["n_envs=0"], "n_envs=0"),
        (["teacher=nope"], "teacher 'nope'"),
        (["eval_every=-3"], "eval_every=-3"),
        (["nb_test_episodes=0"], "nb_test_episodes=0"),
        (["reset_student_every=-7000"], "reset_student_every=-7000"),
        (["student=ppo", "buffer_size=100"], "buffer_size applies to the sac student only"),
    ],
)
def test_bad_values_are_refused_before_anything_is_written(sets, message, tmp_path, capsys):
    out = tmp_path / "camp"
    argv = ["campaign", "run", "quick", "--out", str(out), "--executor", "local"]
    for item in sets:
        argv += ["--set", item]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and "error: run " in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_negative_step_counts_in_a_spec_are_not_scaled_into_valid_ones(tmp_path):
    for key, value in [("steps", -4096), ("eval_every", -3), ("reset_student_every", -7000)]:
        spec = CampaignSpec.from_dict(
            {"name": "neg", "base": {**TINY, key: value}, "grid": {"teacher": ["random"]}}
        )
        for budget in (1.0, 0.5):
            with pytest.raises(ValueError, match=f"run s0: {key}={value};"):
                run_campaign(spec.scaled(budget=budget), tmp_path / "camp", executor="local")
    assert not (tmp_path / "camp").exists()


def test_exclude_that_removes_every_run_says_so():
    spec = CampaignSpec.from_dict(
        {"name": "none", "grid": {"teacher": ["random"]}, "exclude": [{"teacher": "random"}]}
    )
    with pytest.raises(ValueError, match="exclude rules remove every run"):
        spec.expand()


def test_campaign_lock_has_one_holder_among_simultaneous_attempts(tmp_path):
    camp, start = CampaignDir(tmp_path / "camp"), threading.Barrier(8)
    got, refused, release = [], [], threading.Event()

    def attempt(i: int) -> None:
        start.wait()
        try:
            with camp.lock():
                got.append(i)
                release.wait(10)
        except LockBusy as exc:
            refused.append(str(exc))

    threads = [threading.Thread(target=attempt, args=(i,)) for i in range(8)]
    for t in threads:
        t.start()
    # the holder keeps the lock until every attempt has been answered (a refused thread ends
    # at once, so waiting on the threads being alive let a late one in after the release)
    deadline = time.monotonic() + 10
    while len(got) + len(refused) < 8 and time.monotonic() < deadline:
        time.sleep(0.01)
    release.set()
    for t in threads:
        t.join()
    assert len(got) == 1 and len(refused) == 7
    assert all("is in use by pid" in message for message in refused)
    with camp.lock():  # released by its holder
        pass


def test_refused_second_campaign_process_changes_nothing(tmp_path):
    out = tmp_path / "camp"
    spec = load_spec("quick").scaled(seeds=2, sets=TINY)
    camp = CampaignDir(out)
    with camp.lock():
        camp.prepare(spec, spec.expand(), {})
        manifest = camp.manifest.read_bytes()
        more = load_spec("quick").scaled(seeds=3, sets=TINY)
        with pytest.raises(LockBusy, match=f"campaign directory '{out}' is in use by pid"):
            run_campaign(more, out, executor="local")
        assert camp.manifest.read_bytes() == manifest


def test_runs_that_never_started_may_change_options(tmp_path):
    """A campaign whose runs all failed before starting (a wrong option train refused) does not
    block the corrected command; once a run has started, its options are fixed."""
    camp = CampaignDir(tmp_path)
    wrong = load_spec("quick").scaled(seeds=1, sets={**TINY, "teacher_params": {"nope": 1}})
    camp.prepare(wrong, wrong.expand(), {})
    (camp.run_dir("random__s0") / "failures").mkdir(parents=True)
    right = load_spec("quick").scaled(seeds=2, sets=TINY)
    camp.prepare(right, right.expand(), {})
    assert "teacher_params" not in camp.read()["runs"][0]["options"]
    (camp.run_dir("random__s0") / "config.yaml").write_text("config: {}\n")  # it started
    with pytest.raises(ValueError, match=r"started runs \['random__s0'\] are not in this one"):
        camp.prepare(wrong, wrong.expand(), {})
    fewer = load_spec("quick").scaled(seeds=1, sets=TINY)
    camp.prepare(fewer, fewer.expand(), {})  # the seed-1 runs never started: they may go
    assert [r["name"] for r in camp.read()["runs"]] == ["random__s0", "alp-gmm__s0"]


def _hold_log(run: Path):
    """Another attempt of the run, still ending: holds the run's campaign log."""
    from acl3d.campaign.lock import try_lock

    run.mkdir(parents=True, exist_ok=True)
    f = (run / "campaign.log").open("a")
    assert try_lock(f.fileno())
    return f


def test_attempt_does_not_start_beside_a_live_attempt_of_the_same_run(tmp_path):
    run = tmp_path / "run"
    holder = _hold_log(run)
    (run / "evals.csv").write_text("the other attempt's\n")
    result = run_attempt(str(run), {"steps": 512}, 1, wait_s=0.3)
    assert result == {
        "ok": False,
        "error": f"another attempt of this run (of a campaign process that was stopped?) still "
        f"works in {str(run)!r} after 0.3 s: not started",
        "retry": False,
    }
    assert (run / "evals.csv").read_text() == "the other attempt's\n"
    assert not (run / "failures").exists()
    log = (run / "campaign.log").read_text()
    assert "waiting for another attempt of this run" in log and "not started" in log
    # once the other attempt ends, the next one goes ahead (here: a finished run, left alone)
    (run / "config.yaml").write_text("config: {}\n")
    (run / "status.json").write_text('{"status": "finished", "steps": 512}')
    threading.Timer(0.5, holder.close).start()
    assert run_attempt(str(run), {"steps": 512}, 1, wait_s=30) == {"ok": True, "steps": 512}
    assert "already finished" in (run / "campaign.log").read_text()


def test_bounds_of_this_machine_are_left_to_the_cluster_nodes():
    """A campaign submitted to a cluster may ask for more threads than this machine has (or a
    GPU it lacks): the nodes check those; the machine-independent bounds are checked here."""
    more = (os.cpu_count() or 1) + 1
    spec = load_spec("quick").scaled(seeds=1, sets={**TINY, "torch_threads": more})
    with pytest.raises(ValueError, match=f"torch_threads={more}"):
        check_runs(spec.expand())
    check_runs(spec.expand(), on_this_machine=False)
    too_many = load_spec("quick").scaled(seeds=1, sets={**TINY, "n_envs": 5000})
    with pytest.raises(ValueError, match="n_envs=5000"):
        check_runs(too_many.expand(), on_this_machine=False)


def test_out_at_or_under_a_file_is_one_line(tmp_path, capsys):
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    for out in (a_file, a_file / "camp"):
        assert main(["campaign", "run", "quick", "--out", str(out), "--executor", "local"]) == 2
        err = capsys.readouterr().err
        assert "cannot be created" in err and len(err.strip().splitlines()) == 1
    assert a_file.read_text() == "x"


@pytest.mark.parametrize(
    "sets, message",
    [
        (['env_kwargs={"bogus": 1}'], "env_kwargs['bogus']=1; valid: keyword arguments"),
        (['test_set="missing.json"'], "test_set='missing.json': no such file"),
        (['bounds={"stump_height": [3, 1]}'], "min <= max"),
        (['bounds={"stump_height": [0, 100]}'], "stump-tracks can build"),
    ],
)
def test_values_only_the_environment_checks_are_refused_before_anything_is_written(
    sets, message, tmp_path, capsys, monkeypatch
):
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "camp"
    argv = ["campaign", "run", "quick", "--out", str(out), "--executor", "local"]
    assert main([*argv, *(x for item in sets for x in ("--set", item))]) == 2
    err = capsys.readouterr().err
    assert message in err and "error: run random__s0: " in err and len(err.splitlines()) == 1
    assert not out.exists()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--budget", "-1"], "--budget=-1.0; valid: a finite number > 0"),
        (["--budget", "nan"], "--budget=nan; valid: a finite number > 0"),
        (["--seeds", "0"], "--seeds=0; valid: an integer >= 1"),
        (["--retries", "-1"], "--retries=-1; valid: an integer >= 0"),
        (["--max-parallel", "0"], "--max-parallel=0; valid: an integer >= 1"),
    ],
)
def test_numbers_are_named_as_typed_whatever_the_executor(args, message, tmp_path, capsys):
    out = tmp_path / "camp"
    assert main(["campaign", "run", "quick", "--out", str(out), *args]) == 2  # the ray executor
    err = capsys.readouterr().err.strip()
    assert err == f"acl3d campaign: error: {message}" and not out.exists()


def test_an_export_never_replaces_a_folder_that_is_not_an_export(tmp_path, capsys, monkeypatch):
    import acl3d.results

    camp = tmp_path / "work" / "camp"
    camp.mkdir(parents=True)
    doc = {"spec": {"name": "quick"}, "invocation": {"budget": 0.01}, "runs": []}
    (camp / "campaign.yaml").write_text(yaml.safe_dump(doc))
    (tmp_path / "work" / "notes.txt").write_text("mine")
    shipped = tmp_path / "package" / "results"
    (shipped / "stump-v1").mkdir(parents=True)
    (shipped / "stump-v1" / "protocol.yaml").write_text("protocol: stump-v1\n")
    monkeypatch.setattr(acl3d.results, "__file__", str(shipped / "__init__.py"))
    before = sorted(str(p) for p in tmp_path.rglob("*"))
    export = ["campaign", "export", str(camp), "--protocol"]
    for args, words in [
        ([*export, "mine", "--out", str(tmp_path / "work")], ("holds the campaign",)),
        ([*export, "mine", "--out", str(camp)], ("holds the campaign",)),
        ([*export, "mine", "--out", str(tmp_path)], ("holds the campaign",)),
        ([*export, "stump-v1"], ("is not protocol 'stump-v1' at full budget", "--out DIR")),
    ]:
        assert main(args) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and all(w in err for w in words), err
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    assert main([*export, "mine", "--out", str(other)]) == 2
    assert "not an export (no protocol.yaml)" in capsys.readouterr().err
    after = sorted(str(p) for p in tmp_path.rglob("*"))
    assert after == sorted([*before, str(other), str(other / "notes.txt")])


def test_spec_mistakes_are_one_line_before_anything_is_written(tmp_path, capsys):
    long_label = "a" * 300
    specs = {
        "exclude.yaml": ({"name": "x", "grid": {"teacher": ["random"]}, "exclude": 5}, []),
        "budget.yaml": (
            {"name": "x", "base": {"steps": 4096}, "grid": {"teacher": ["random"]}},
            ["--budget", "1e306"],
        ),
        "nosteps.yaml": ({"name": "x", "grid": {"teacher": ["random"]}}, []),
        "long.yaml": (
            {"name": "x", "base": {"steps": 4096}, "grid": {"criterion": {long_label: {}}}},
            [],
        ),
    }
    messages = {
        "exclude.yaml": "exclude: expected a list of mappings, got 5",
        "budget.yaml": "budget=1e+306: steps=4096 x budget is not a finite number",
        "nosteps.yaml": "runs ['s0'] set no steps",
        "long.yaml": "run name='aaa",
    }
    for name, (doc, extra) in specs.items():
        spec = tmp_path / name
        spec.write_text(yaml.safe_dump(doc))
        out = tmp_path / f"camp_{name}"
        assert main(["campaign", "run", str(spec), "--out", str(out), *extra]) == 2
        err = capsys.readouterr().err
        assert messages[name] in err and len(err.strip().splitlines()) == 1, err
        assert not out.exists()
