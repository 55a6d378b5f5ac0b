"""render_mode="human" and `acl3d view`: a clear error without a display, a window under Xvfb."""

import ctypes
import os
import subprocess
import sys
import textwrap
import time

import pytest
from gl_support import missing, require_program, run_checked

from acl3d.cli import main
from acl3d.envs.track_env import TrackEnv

HUMAN_MODE_SCRIPT = textwrap.dedent(
    """
    import acl3d, gymnasium as gym
    env = gym.make("acl3d/StumpTracks-v0", render_mode="human")
    env.reset(seed=0, options={"task": {"stump_height": 2.0}})
    for _ in range(20):
        env.step(env.action_space.sample())
    assert env.unwrapped._viewer.is_running()
    env.reset(options={"task": {"stump_height": 0.5}})  # a new terrain is uploaded
    env.close()
    print("closed")
    """
)


def press_enter(display: str) -> None:
    """A real Enter key press on `display` (XTest), over the viewer window at the top-left."""
    try:
        x11, xtst = ctypes.CDLL("libX11.so.6"), ctypes.CDLL("libXtst.so.6")
    except OSError as exc:
        missing(f"pressing a key needs libX11/libXtst ({exc}): apt-get install libx11-6 libxtst6")
    x11.XOpenDisplay.restype = ctypes.c_void_p
    x11.XOpenDisplay.argtypes = [ctypes.c_char_p]
    x11.XKeysymToKeycode.argtypes = [ctypes.c_void_p, ctypes.c_ulong]
    x11.XKeysymToKeycode.restype = ctypes.c_ubyte
    x11.XFlush.argtypes = x11.XCloseDisplay.argtypes = [ctypes.c_void_p]
    xtst.XTestFakeMotionEvent.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_int] + [
        ctypes.c_int,
        ctypes.c_ulong,
    ]
    xtst.XTestFakeKeyEvent.argtypes = [ctypes.c_void_p, ctypes.c_uint, ctypes.c_int, ctypes.c_ulong]
    handle = x11.XOpenDisplay(display.encode())
    assert handle, f"cannot open {display}"
    enter = x11.XKeysymToKeycode(handle, 0xFF0D)  # XK_Return
    xtst.XTestFakeMotionEvent(handle, -1, 300, 300, 0)  # no window manager: focus follows pointer
    xtst.XTestFakeKeyEvent(handle, enter, 1, 0)
    xtst.XTestFakeKeyEvent(handle, enter, 0, 0)
    x11.XFlush(handle)
    x11.XCloseDisplay(handle)


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


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--steps", "0"], "--steps=0; valid: an integer >= 1"),
        (["--seed", "-1"], "--seed=-1; valid: an integer in [0, 2147483647]"),
    ],
)
def test_view_cli_names_a_bad_count_before_looking_for_a_display(args, message, capsys):
    assert main(["view", *args]) == 2
    assert capsys.readouterr().err.strip() == f"acl3d view: error: {message}"


@pytest.fixture
def xvfb_display():
    """A private Xvfb server; -displayfd reports its display number once it accepts clients."""
    require_program("Xvfb", "xvfb")
    server = subprocess.Popen(
        ["Xvfb", "-displayfd", "1", "-screen", "0", "800x600x24", "-nolisten", "tcp"],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        yield f":{server.stdout.readline().strip()}"
    finally:
        server.terminate()
        server.wait(timeout=30)


def test_the_viewer_opens_under_xvfb_and_enter_gives_a_new_task(xvfb_display):
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")}
    env["DISPLAY"] = xvfb_display
    assert "closed" in run_checked([sys.executable, "-c", HUMAN_MODE_SCRIPT], env=env).stdout
    view = [sys.executable, "-m", "acl3d", "view", "--steps", "150", "--task", "stump_height=1"]
    proc = subprocess.Popen(
        view, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    assert proc.stdout.readline().startswith("Enter: a new random task")  # the window is open
    time.sleep(0.5)
    press_enter(xvfb_display)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    assert "new task: {'stump_height'" in out and "viewed 150 steps" in out
