"""MuJoCo's interactive viewer (`mujoco.viewer`, GLFW) for an env's model: render_mode="human".

The viewer needs a display. Without one, `launch_passive` would wait forever for a window that
GLFW cannot open, so the display is checked first and a missing one is a clear RuntimeError.
"""

from __future__ import annotations

import ctypes
import os
import sys
import threading
import time

NEW_TASK_KEY = 257  # GLFW_KEY_ENTER: every letter is already a shortcut of MuJoCo's viewer
HEADLESS_HELP = (
    "run it on a machine with a screen, over `ssh -X`, or in a virtual display: "
    "`xvfb-run -a acl3d view ...` (Debian package xvfb); videos need no display: "
    "render_mode='rgb_array' or `acl3d render`"
)


def check_display() -> None:
    """RuntimeError naming DISPLAY when no X11/Wayland display can be reached."""
    if not sys.platform.startswith("linux") or os.environ.get("WAYLAND_DISPLAY"):
        return
    display = os.environ.get("DISPLAY")
    if not display:
        raise RuntimeError(
            f"the interactive viewer needs a display and DISPLAY is not set; {HEADLESS_HELP}"
        )
    try:
        xlib = ctypes.CDLL("libX11.so.6")
    except OSError:
        raise RuntimeError(
            f"the interactive viewer needs libX11 (Debian: apt-get install libx11-6) for "
            f"DISPLAY={display}"
        ) from None
    xlib.XOpenDisplay.restype = ctypes.c_void_p
    xlib.XOpenDisplay.argtypes = [ctypes.c_char_p]
    xlib.XCloseDisplay.argtypes = [ctypes.c_void_p]
    handle = xlib.XOpenDisplay(display.encode())
    if not handle:
        raise RuntimeError(f"cannot connect to the display DISPLAY={display}; {HEADLESS_HELP}")
    xlib.XCloseDisplay(handle)


class HumanViewer:
    """A passive viewer window on (model, data), looking through `camera` (the follow camera).

    `sync()` shows the current state (uploading heightfields whose version changed) and paces
    calls to `fps`; `new_task_requested` turns True when Enter is pressed in the window.
    """

    def __init__(self, model, data, camera: str | None = None, fps: float = 50.0):
        check_display()
        import mujoco
        import mujoco.viewer

        self.new_task_requested = False
        before = set(threading.enumerate())
        self._handle = mujoco.viewer.launch_passive(
            model, data, key_callback=self._on_key, show_left_ui=False, show_right_ui=False
        )
        self._threads = set(threading.enumerate()) - before  # joined at close
        if camera is not None:
            camera_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera)
            if camera_id >= 0:
                with self._handle.lock():
                    self._handle.cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
                    self._handle.cam.fixedcamid = camera_id
        self._period = 1.0 / fps
        self._next_time = time.perf_counter()
        self._versions: dict[int, int] = {}

    def _on_key(self, keycode: int) -> None:
        if keycode == NEW_TASK_KEY:
            self.new_task_requested = True

    def is_running(self) -> bool:
        return self._handle is not None and self._handle.is_running()

    def sync(self, hfield_ids=(), version: int = 0) -> None:
        """Show the current state in real time (no-op once the window is closed)."""
        if not self.is_running():
            return
        for hfield in hfield_ids:
            if self._versions.get(hfield) != version:
                self._handle.update_hfield(hfield)
                self._versions[hfield] = version
        self._handle.sync()
        self._next_time += self._period
        delay = self._next_time - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
        else:  # running late (slow machine): do not try to catch up
            self._next_time = time.perf_counter()

    def close(self) -> None:
        """Close the window and wait for the viewer's thread (exiting while it runs crashes)."""
        if self._handle is None:
            return
        self._handle.close()
        self._handle = None
        for thread in self._threads:
            thread.join(timeout=10)
