"""The package version, written here only (pyproject.toml and `acl3d --version` read it).

Semantic versioning: before 1.0, a minor release (0.x) may change the API or the install
(CHANGELOG.md says how); a patch release (0.x.y) only fixes. Environment behaviour that changes
what a seed plays (the fingerprints of scripts/fingerprints.py) is always a minor release.
"""

__version__ = "0.2.0"
