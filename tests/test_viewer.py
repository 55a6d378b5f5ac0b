"""render_mode="human" and `acl3d view`: a clear error without a display, a window under Xvfb."""

import os
import sys
import textwrap

import pytest
from gl_support import require_program, run_checked

from acl3d.cli import main
from acl3d.envs.track_env import TrackEnv

VIEWER_SCRIPT = textwrap.dedent(
    """
    import acl3d, gymnasium as gym
    from acl3d.cli import main
    env = gym.make("acl3d/StumpTracks-v0", render_mode="human")
    env.reset(seed=0, options={"task": {"stump_height": 2.0}})
    for _ in range(20):
        env.step(env.action_space.sample())
    assert env.unwrapped._viewer.is_running()
    env.reset(options={"task": {"stump_height": 0.5}})  # a new terrain is uploaded
    env.close()
    assert main(["view", "--steps", "25", "--task", "stump_height=1"]) == 0
    """
)


@pytest.fixture
def headless(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)


def test_human_mode_without_a_display_says_what_to_do(headless):
    with pytest.raises(RuntimeError, match="DISPLAY is not set.*xvfb-run"):
        TrackEnv(render_mode="human")


def test_an_unreachable_display_is_named(monkeypatch):
    monkeypatch.setenv("DISPLAY", ":4321")
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(RuntimeError, match="DISPLAY=:4321"):
        TrackEnv(render_mode="human")


def test_view_cli_without_a_display_exits_2_with_the_reason(headless, capsys):
    assert main(["view", "--steps", "5"]) == 2
    err = capsys.readouterr().err
    assert "acl3d view: error:" in err and "DISPLAY" in err and "xvfb" in err


def test_the_viewer_opens_under_xvfb():
    require_program("xvfb-run", "xvfb")
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")}
    proc = run_checked(["xvfb-run", "-a", sys.executable, "-c", VIEWER_SCRIPT], env=env)
    assert "viewed 25 steps" in proc.stdout
