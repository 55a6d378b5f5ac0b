"""The release metadata agree: version, changelog, citation, licence, type hints."""

from __future__ import annotations

from pathlib import Path

import yaml

from acl3d.cli import main
from acl3d.version import __version__

ROOT = Path(__file__).resolve().parents[1]


def test_acl3d_version_prints_the_package_version(capsys):
    try:
        main(["--version"])
    except SystemExit as exc:
        assert exc.code == 0
    assert capsys.readouterr().out.strip() == f"acl3d {__version__}"


def test_changelog_and_citation_name_the_current_version():
    assert f"## [{__version__}]" in (ROOT / "CHANGELOG.md").read_text()
    citation = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert str(citation["version"]) == __version__
    assert citation["license"] == "MIT"


def test_the_package_ships_its_licence_and_type_hints():
    assert (ROOT / "LICENSE").read_text().startswith("MIT License")
    assert (ROOT / "acl3d" / "py.typed").exists()
    pyproject = (ROOT / "pyproject.toml").read_text()
    assert '"py.typed"' in pyproject and 'attr = "acl3d.version.__version__"' in pyproject


def test_the_wheel_lists_every_python_package_of_the_source_tree():
    """A package missing from pyproject's list installs without it (the source tree hides that)."""
    import tomllib

    listed = set(
        tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]
    )
    found = {
        ".".join(init.parent.relative_to(ROOT).parts)
        for init in (ROOT / "acl3d").rglob("__init__.py")
    }
    assert found - listed == set(), "add these packages to [tool.setuptools] packages"
