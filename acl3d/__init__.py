"""acl3d: automatic curriculum learning on procedurally generated 3D MuJoCo tracks."""

__version__ = "0.1.0"
