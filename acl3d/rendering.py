"""Headless offscreen rendering: choose the OpenGL backend before MuJoCo loads, render fast.

MuJoCo reads MUJOCO_GL once, when it is imported. `select_gl_backend()` runs on `import acl3d`
and, if the user has not chosen, picks EGL, then OSMesa, from the libraries present. Every
failure of the backend (at `import mujoco`, which loads it, or when a renderer is created) is
turned into a RuntimeError naming the backend tried and the Debian package to install.
"""

from __future__ import annotations

import atexit
import ctypes
import ctypes.util
import importlib.abc
import importlib.util
import os
import sys
import weakref

# backend -> (shared library, Debian package(s) that provide it)
BACKEND_LIBRARIES = {
    "egl": ("EGL", "libegl1 libegl-mesa0"),
    "osmesa": ("OSMesa", "libosmesa6"),
}
_chosen: dict[str, object] = {"backend": None, "tried": [], "note": ""}


def library_available(backend: str) -> bool:
    """Whether the shared library of `backend` (egl, osmesa) can be loaded, as PyOpenGL loads it."""
    lib = BACKEND_LIBRARIES[backend][0]
    if ctypes.util.find_library(lib):
        return True
    for name in [f"lib{lib}.so"] + [f"lib{lib}.so.{i}" for i in range(9, -1, -1)]:
        try:
            ctypes.CDLL(name)
            return True
        except OSError:
            continue
    return False


def select_gl_backend() -> str | None:
    """Set MUJOCO_GL to egl or osmesa when the user has not set it and no display exists."""
    if "mujoco" not in sys.modules and not any(
        isinstance(f, _MujocoImportGuard) for f in sys.meta_path
    ):
        sys.meta_path.insert(0, _MujocoImportGuard())
    if "MUJOCO_GL" in os.environ:
        _chosen.update(backend=os.environ["MUJOCO_GL"], note="MUJOCO_GL was set by the user")
        return os.environ["MUJOCO_GL"]
    if "mujoco" in sys.modules:  # too late to choose: MuJoCo picked its platform at import
        _chosen["note"] = "mujoco was imported before acl3d, too late to choose; import acl3d first"
        return None
    if (
        sys.platform.startswith("linux")
        and not os.environ.get("DISPLAY")
        and not os.environ.get("WAYLAND_DISPLAY")
    ):
        for backend in BACKEND_LIBRARIES:
            _chosen["tried"].append(backend)
            if library_available(backend):
                os.environ["MUJOCO_GL"] = backend
                if backend == "osmesa":
                    os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
                _chosen.update(backend=backend, note=f"chosen automatically: {backend}")
                return backend
        _chosen["note"] = "no EGL or OSMesa library found"
    else:
        _chosen["note"] = "a display is available, MuJoCo's default (GLFW) is used"
    return None


def gl_error_message(exc: BaseException) -> str:
    backend = os.environ.get("MUJOCO_GL")
    tried = ", ".join(_chosen["tried"]) or "none"
    if backend in BACKEND_LIBRARIES:
        lib, pkgs = BACKEND_LIBRARIES[backend]
        need = f"MUJOCO_GL={backend} needs lib{lib} (Debian: apt-get install {pkgs})"
    else:
        need = f"MUJOCO_GL={backend or '(unset)'}: MuJoCo's default (GLFW) needs a display"
    others = "; ".join(
        f"MUJOCO_GL={b} needs apt-get install {pkgs}"
        for b, (_, pkgs) in BACKEND_LIBRARIES.items()
        if b != backend
    )
    return (
        f"OpenGL rendering failed with MUJOCO_GL={backend or '(unset)'} "
        f"({type(exc).__name__}: {exc}). {need}. Backends tried automatically: {tried} "
        f"({_chosen['note']}). Alternatives: {others}. Set MUJOCO_GL before importing mujoco "
        "or acl3d, e.g. `MUJOCO_GL=egl python ...`, or unset it to let acl3d choose."
    )


class _MujocoImportGuard(importlib.abc.MetaPathFinder):
    """Makes a failing `import mujoco` (it loads the GL backend) raise gl_error_message."""

    def find_spec(self, fullname, path=None, target=None):
        if fullname != "mujoco":
            return None
        sys.meta_path.remove(self)  # one use: find the real spec without ourselves
        spec = importlib.util.find_spec("mujoco")
        if spec is not None and spec.loader is not None:
            spec.loader = _GuardedLoader(spec.loader)
        return spec


class _GuardedLoader(importlib.abc.Loader):
    def __init__(self, loader):
        self._loader = loader

    def create_module(self, spec):
        return self._loader.create_module(spec)

    def exec_module(self, module):
        module.__spec__.loader = module.__loader__ = self._loader  # MuJoCo's own, from now on
        try:
            self._loader.exec_module(module)
        except Exception as exc:
            raise RuntimeError(gl_error_message(exc)) from exc


_live_renderers: weakref.WeakSet = weakref.WeakSet()
# Texels of a shadow map in the fast preset: the shadow pass is mostly a second lit pass of the
# scene, whatever its map size; 512 keeps a walker's shadow clean at 640 x 480.
FAST_SHADOW_SIZE = 512


def _close_live_renderers() -> None:
    """Free GL contexts before MuJoCo's own exit hooks tear the GL display down."""
    for renderer in list(_live_renderers):
        renderer.close()


def _swap_material(model, old: str, new: str) -> None:
    """Draw geoms that use material `old` with `new` (when the model defines both)."""
    import mujoco

    old_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_MATERIAL, old)
    new_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_MATERIAL, new)
    if old_id >= 0 and new_id >= 0:
        model.geom_matid[model.geom_matid == old_id] = new_id


class TrackRenderer:
    """A mujoco.Renderer bound to one model, with a camera, quality preset and hfield re-uploads."""

    def __init__(
        self,
        model,
        width: int = 640,
        height: int = 480,
        camera: str | int = -1,
        quality: str = "fast",
    ):
        import mujoco

        if quality not in ("fast", "high"):
            raise ValueError(
                f"quality={quality!r}; valid: 'fast' (no MSAA; shadows only from the lights an "
                "arena makes cast them) or 'high' (MSAA, every light casts shadows)"
            )
        model.vis.quality.offsamples = 0 if quality == "fast" else 8
        if quality == "fast":  # textured ground costs ~40% of a software-rendered frame
            _swap_material(model, "ground", "ground_fast")
            model.vis.quality.shadowsize = FAST_SHADOW_SIZE
        if quality == "high":  # the arena template's shadow map size (2048)
            model.light_castshadow[:] = True
        model.vis.global_.offwidth = max(model.vis.global_.offwidth, width)
        model.vis.global_.offheight = max(model.vis.global_.offheight, height)
        try:
            self._renderer = mujoco.Renderer(model, height=height, width=width)
        except Exception as exc:  # mujoco.FatalError, EGL/OSMesa errors from PyOpenGL
            raise RuntimeError(gl_error_message(exc)) from exc
        self._renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = True  # lights decide
        self._renderer.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = quality == "high"
        if not _live_renderers:  # registered after mujoco's GL hooks, so it runs before them
            atexit.register(_close_live_renderers)
        _live_renderers.add(self)
        self.model = model
        self.camera = camera
        self._uploaded_versions: dict[int, int] = {}

    def upload_hfield(self, hfield_id: int, version: int) -> None:
        """Send a heightfield to the GPU only when its contents changed since the last upload."""
        import mujoco

        if self._uploaded_versions.get(hfield_id) != version:
            mujoco.mjr_uploadHField(self.model, self._renderer._mjr_context, hfield_id)
            self._uploaded_versions[hfield_id] = version

    def render(self, data):
        self._renderer.update_scene(data, camera=self.camera)
        return self._renderer.render()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
