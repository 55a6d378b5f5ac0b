"""Provenance of a run: one segment per start and resume, how each ended, and what differs
from a reference's machine and versions."""

import json

import pytest

from acl3d import provenance


def test_segments_per_start_and_resume_with_their_end(tmp_path):
    first = provenance.record(tmp_path, "start", 0, "cpu")
    for key in ("acl3d", "commit", "dirty", "cpu_model", "host", "python", "torch", "mujoco",
                "numpy", "device"):  # fmt: skip
        assert key in first
    assert first["acl3d"] and first["numpy"] and first["device"] == "cpu"
    provenance.close(tmp_path, "interrupted", 5000)
    provenance.record(tmp_path, "resume", 4096, "cpu")
    provenance.close(tmp_path, "finished", 10000)
    segments = json.loads((tmp_path / "provenance.json").read_text())
    assert [s["event"] for s in segments] == ["start", "resume"]
    assert [s["end"] for s in segments] == ["interrupted", "finished"]
    assert segments[1]["step"] == 4096 and provenance.interruptions(segments) == 1
    provenance.record(tmp_path, "start")  # a fresh start (overwrite) begins a new list
    assert len(provenance.load(tmp_path)) == 1


def test_bad_input_is_refused_naming_the_parameter(tmp_path):
    with pytest.raises(ValueError, match="event"):
        provenance.record(tmp_path, "restart")
    with pytest.raises(ValueError, match="step"):
        provenance.record(tmp_path, "start", -1)
    with pytest.raises(ValueError, match="end"):
        provenance.close(tmp_path, "done", 1)
    assert not (tmp_path / "provenance.json").exists()


def test_differences_name_the_field_or_say_unknown():
    base = {k: "x" for k in provenance.COMPARED}
    assert provenance.differences([base], [dict(base)]) == []
    other = {**base, "cpu_model": "AMD EPYC", "torch": "2.12"}
    diffs = provenance.differences([other], [base])
    assert len(diffs) == 2 and "cpu_model" in diffs[0] and "AMD EPYC" in diffs[0]
    assert "unknown" in provenance.differences([base], None)[0]


def test_the_module_imports_neither_torch_nor_mujoco():
    import subprocess
    import sys

    code = "import sys, acl3d.provenance as p; p.collect(); print('torch' in sys.modules, 'mujoco' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"]
