"""Offscreen rendering through EGL and OSMesa, GL failures, and the `acl3d render` CLI's files."""

import os
import subprocess
import sys
import textwrap

import gymnasium as gym
import imageio.v2 as imageio
import numpy as np
import pytest
from cli_support import one_line_error
from gl_support import require_backend, require_offscreen_gl, run_checked

from acl3d.cli import main
from acl3d.envs.track_env import TrackEnv

FRAME_SCRIPT = textwrap.dedent(
    """
    import json, sys
    import numpy as np
    import acl3d, gymnasium as gym
    env = gym.make("acl3d/StumpTracks-v0", render_mode="rgb_array", width=160, height=120)
    env.reset(seed=0, options={"task": {"stump_height": 2.0, "obstacle_spacing": 1.0}})
    for _ in range(10):
        env.step(np.full(4, 0.3))
    frame = env.render()
    env.close()
    np.save(sys.argv[1], frame)
    """
)

# Hides one GL library from this process (as on a machine without it), then renders.
HIDDEN_LIBRARY_SCRIPT = textwrap.dedent(
    """
    import ctypes, ctypes.util, sys
    hidden = sys.argv[1]
    load, find = ctypes.CDLL.__init__, ctypes.util.find_library
    def refuse(self, name, *args, **kwargs):
        if name and hidden in str(name):
            raise OSError(f"{name}: cannot open shared object file")
        load(self, name, *args, **kwargs)
    ctypes.CDLL.__init__ = refuse
    ctypes.util.find_library = lambda name: None if hidden in name else find(name)
    import acl3d, gymnasium as gym
    env = gym.make("acl3d/StumpTracks-v0", render_mode="rgb_array", width=64, height=48)
    env.reset(seed=0)
    env.render()
    """
)


def render_in_subprocess(backend, tmp_path):
    require_backend(backend)
    out = tmp_path / f"{backend}.npy"
    env = {**os.environ, "MUJOCO_GL": backend}
    env.pop("PYOPENGL_PLATFORM", None)
    run_checked([sys.executable, "-c", FRAME_SCRIPT, str(out)], env=env)
    return np.load(out)


def test_egl_and_osmesa_render_the_same_frame(tmp_path):
    egl = render_in_subprocess("egl", tmp_path)
    osmesa = render_in_subprocess("osmesa", tmp_path)
    assert egl.shape == (120, 160, 3) and egl.dtype == np.uint8
    assert egl.std() > 10  # not blank: sky, ground, walker
    assert np.array_equal(egl, osmesa)


def _pixel_of(model, data, camera: int, point, width: int, height: int) -> np.ndarray:
    """(column, row) where `camera` (pinhole, MuJoCo's axes: it looks along its -z) sees `point`."""
    local = data.cam_xmat[camera].reshape(3, 3).T @ (np.asarray(point) - data.cam_xpos[camera])
    focal = (height / 2) / np.tan(np.radians(model.cam_fovy[camera]) / 2)
    depth = -local[2]
    assert depth > 0, "the point is behind the camera"
    return np.array([width / 2 + focal * local[0] / depth, height / 2 - focal * local[1] / depth])


def test_render_follows_the_walker_and_sees_new_terrain():
    """The default camera keeps the walker at the same place in the frame wherever it goes,
    and a new task's terrain reaches the renderer."""
    import mujoco

    require_offscreen_gl()
    width, height = 160, 120
    env = gym.make("acl3d/StumpTracks-v0", render_mode="rgb_array", width=width, height=height)
    env.reset(seed=0, options={"task": {"stump_height": 0.0, "obstacle_spacing": 6.0}})
    u = env.unwrapped
    cam = mujoco.mj_name2id(u.model, mujoco.mjtObj.mjOBJ_CAMERA, u.arena.camera)
    torso = u.model.cam_bodyid[cam]  # the camera rides on the walker's root body
    start = env.render()
    start_x, start_offset = u.data.xpos[torso][0], u.data.cam_xpos[cam] - u.data.xpos[torso]
    start_pixel = _pixel_of(u.model, u.data, cam, u.data.xpos[torso], width, height)
    u.data.qpos[u.model.jnt_qposadr[u.model.body_jntadr[torso]]] += 20.0  # 20 m along the track
    mujoco.mj_forward(u.model, u.data)
    ahead = env.render()
    assert u.data.xpos[torso][0] - start_x == pytest.approx(20.0, abs=1e-3)
    np.testing.assert_allclose(u.data.cam_xpos[cam] - u.data.xpos[torso], start_offset, atol=1e-3)
    ahead_pixel = _pixel_of(u.model, u.data, cam, u.data.xpos[torso], width, height)
    np.testing.assert_allclose(ahead_pixel, start_pixel, atol=0.05)  # pixels
    assert 0 < start_pixel[0] < width and 0 < start_pixel[1] < height  # the walker is in view
    assert not np.array_equal(start, ahead)  # the same walker over other ground

    env.reset(seed=0, options={"task": {"stump_height": 3.0, "obstacle_spacing": 0.2}})
    stumps = env.render()  # heights re-uploaded to the renderer after the new task
    env.close()
    assert not np.array_equal(start, stumps)


def test_terrain3d_renders_its_relief_by_default():
    """The fast preset on 3D Terrain: a camera looking down on the field, a checkered ground and
    the walker's shadow on it; the tracks' fast frames cast no shadow (their cost unchanged)."""
    import mujoco

    require_offscreen_gl()
    env = gym.make("acl3d/Terrain3D-v0", render_mode="rgb_array", width=160, height=120)
    env.reset(seed=0)
    u = env.unwrapped
    lit = env.render().astype(int)
    cam = mujoco.mj_name2id(u.model, mujoco.mjtObj.mjOBJ_CAMERA, u.arena.camera)
    view = -u.data.cam_xmat[cam].reshape(3, 3)[:, 2]  # MuJoCo's cameras look along their -z
    assert view[2] < -np.sin(np.radians(25))  # looks down on the field, not along it
    field = u.model.material("field").id
    assert u.model.geom_matid[u.model.geom("terrain").id] == field
    assert u.model.mat_texid[field].max() >= 0  # textured in the fast preset
    u.model.light_castshadow[:] = False
    unlit = env.render().astype(int)
    env.close()
    shadowed = (lit.sum(axis=2) < unlit.sum(axis=2) - 60).mean()
    assert shadowed > 0.003, f"{shadowed:.4f} of the frame in shadow"  # ~0.007: the walker's
    tracks = gym.make("acl3d/StumpTracks-v0", render_mode="rgb_array", width=32, height=24)
    tracks.reset(seed=0)
    tracks.render()
    assert not tracks.unwrapped.model.light_castshadow.any()
    tracks.close()


def test_bad_render_arguments():
    with pytest.raises(ValueError, match="quality"):
        gym.make("acl3d/StumpTracks-v0", render_mode="rgb_array", quality="ultra")
    with pytest.raises(ValueError, match="render_mode"):
        TrackEnv(render_mode="rgb_arary")


@pytest.mark.parametrize("suffix", [".mp4", ".gif"])
def test_render_cli_writes_a_video(tmp_path, suffix, capsys):
    require_offscreen_gl()
    out = tmp_path / f"rollout{suffix}"
    code = main(
        [
            "render",
            "--env",
            "stump-tracks",
            "--body",
            "classic_bipedal",
            "--task",
            "stump_height=1.5,obstacle_spacing=3",
            "--episodes",
            "1",
            "--max-steps",
            "30",
            "--width",
            "160",
            "--height",
            "120",
            "--out",
            str(out),
            "--no-progress",
        ]
    )
    assert code == 0 and out.exists()
    reader = imageio.get_reader(out)
    first = reader.get_data(0)
    assert first.shape[:2] == (120, 160) and first.std() > 10
    assert reader.get_data(1) is not None  # more than one frame
    reader.close()
    assert "wrote" in capsys.readouterr().out


def test_render_cli_rejects_bad_task(tmp_path, capsys):
    code = main(
        ["render", "--task", "stump_hight=1", "--out", str(tmp_path / "x.mp4"), "--no-progress"]
    )
    assert code == 2
    assert "stump_hight" in capsys.readouterr().err


def test_render_cli_refuses_an_unbuildable_task_before_playing(tmp_path, capsys):
    require_offscreen_gl()
    out = tmp_path / "x.mp4"
    assert main(["render", "--task", "stump_height=99", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "stump_height=99.0; valid: values in the buildable range" in err
    assert "step" not in err and not out.exists()  # no progress bar, no file


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--policy", "random", "--seed", "-4"], "--seed=-4; valid: an integer in [0, 2147483647]"),
        (["--policy", "random", "--out", "{file}/x.mp4"], "--out's folder="),
        (["--curriculum", "{file}", "--out", "{file}/c.gif"], "--out's folder="),
        (["--policy", "random", "--format", "mp4", "--out", "{dir}"], "valid: a file path"),
    ],
)
def test_render_cli_refuses_a_bad_seed_or_out_path_before_playing(
    tmp_path, capsys, monkeypatch, args, message
):
    (tmp_path / "notes.txt").write_text("a file where a folder is meant")
    where = {"file": str(tmp_path / "notes.txt"), "dir": str(tmp_path)}
    monkeypatch.setattr("acl3d.cli.render.resolve_source", lambda *a: pytest.fail("played"))
    assert main(["render", *(a.format(**where) for a in args), "--no-progress"]) == 2
    one_line_error(capsys, message)
    assert [p.name for p in tmp_path.iterdir()] == ["notes.txt"]


def test_missing_gl_backend_gives_an_actionable_message(tmp_path):
    script = "import mujoco, acl3d, gymnasium as gym\nenv = gym.make('acl3d/StumpTracks-v0', render_mode='rgb_array')\nenv.reset(seed=0)\nenv.render()\n"
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM", "DISPLAY")
    }
    proc = run_failing([sys.executable, "-c", script], env=env)
    assert "libosmesa6" in proc.stderr and "import acl3d first" in proc.stderr


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="GLFW needs X11 or Wayland here")
def test_render_cli_without_a_display_fails_in_one_line_before_writing(tmp_path):
    hidden = ("MUJOCO_GL", "PYOPENGL_PLATFORM", "DISPLAY", "WAYLAND_DISPLAY")
    env = {k: v for k, v in os.environ.items() if k not in hidden}
    env["MUJOCO_GL"] = "glfw"  # MuJoCo's default, which needs a display
    out = tmp_path / "x.png"
    args = ["render", "--policy", "random", "--max-steps", "5", "--out", str(out), "--no-progress"]
    proc = subprocess.run(
        [sys.executable, "-m", "acl3d", *args], env=env, capture_output=True, text=True, timeout=180
    )
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("acl3d render: error: OpenGL rendering failed with MUJOCO_GL=glfw")
    assert "apt-get install libegl1 libegl-mesa0" in last and not out.exists()


def run_failing(args, env):
    proc = subprocess.run(args, env=env, capture_output=True, text=True, timeout=180)
    assert proc.returncode != 0, f"expected a failure; stdout:\n{proc.stdout}"
    return proc


@pytest.mark.parametrize(
    ("backend", "library", "package"),
    [("osmesa", "OSMesa", "libosmesa6"), ("egl", "EGL", "libegl1 libegl-mesa0")],
)
def test_a_missing_backend_library_names_the_backend_and_its_package(backend, library, package):
    env = {k: v for k, v in os.environ.items() if k != "PYOPENGL_PLATFORM"}
    env["MUJOCO_GL"] = backend
    proc = run_failing([sys.executable, "-c", HIDDEN_LIBRARY_SCRIPT, library], env)
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("RuntimeError: OpenGL rendering failed"), proc.stderr
    assert f"MUJOCO_GL={backend}" in last and f"apt-get install {package}" in last
    assert "NoneType" in last  # the original error is kept in the message


def test_a_long_label_wraps_inside_the_frame_and_episode_outcomes_are_named():
    from acl3d.overlay import _advance, draw_label, episode_lines, font_size_for, wrap_line

    task = {name: 1.0 for name in ("block_height", "block_width", "block_spacing")}
    task |= {"cross_slope": 12.0, "hill_slope": 8.0, "roughness": 0.15}
    lines = episode_lines("run (alp-gmm)", task, 120, 45.6, "time limit")
    assert lines[-1].endswith("time limit") and "roughness=0.15" in lines[1]
    size = font_size_for(480)
    parts = wrap_line(lines[1], size, 640 - 16)
    assert len(parts) > 1 and " ".join(parts) == lines[1]  # nothing cut, only wrapped
    assert all(_advance(part, size) <= 640 - 16 for part in parts)
    frame = np.zeros((480, 640, 3), dtype=np.uint8)
    draw_label(frame, lines)
    lit_rows = np.flatnonzero(frame.max(axis=(1, 2)) > 100)
    one_line = np.zeros((480, 640, 3), dtype=np.uint8)
    draw_label(one_line, lines[:1])
    assert lit_rows.max() > 3 * np.flatnonzero(one_line.max(axis=(1, 2)) > 100).max()
    with pytest.raises(ValueError, match="outcome"):
        episode_lines("t", task, 1, 0.0, "done")
