"""acl3d: automatic curriculum learning on procedurally generated 3D MuJoCo tracks."""

from acl3d.rendering import select_gl_backend

select_gl_backend()  # must run before anything imports mujoco

from acl3d.envs import ENV_NAMES, make  # noqa: E402  (registers the gymnasium ids)
from acl3d.envs.curriculum_wrapper import CurriculumWrapper  # noqa: E402
from acl3d.version import __version__  # noqa: E402

__all__ = ["ENV_NAMES", "CurriculumWrapper", "make", "__version__"]
