"""config.yaml (with its copy config.json) and provenance.json: written whole, read with errors
that name the file.

config.yaml holds sections: `config` (what `read_config` rebuilds the run from), derived facts
such as `resolved`, `environment` and, after a resume, `resumed`. provenance.json is a JSON list
of segments, one per start or resume of the run, each an object describing where and with what
that part was made (`acl3d.provenance` fills them); this package stores them as given.
"""

from __future__ import annotations

import json
from pathlib import Path

import yaml

from acl3d.atomic_files import atomic_write
from acl3d.run_format.layout import CONFIG_JSON, CONFIG_YAML, PROVENANCE


def read_doc(run: Path) -> dict:
    """The whole of RUN/config.yaml; a ValueError naming the file if it is missing or invalid."""
    path = Path(run) / CONFIG_YAML
    if not path.exists():
        raise ValueError(f"{str(Path(run))!r} is not a run directory (no {CONFIG_YAML})")
    try:
        doc = yaml.safe_load(path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        where = " ".join(str(exc).split())
        raise ValueError(f"{path} is not valid YAML: {where}") from None
    if not isinstance(doc, dict):
        raise ValueError(f"{path} is not a mapping of sections (was it edited?)")
    return doc


def read_section(run: Path, name: str):
    doc = read_doc(run)
    if name not in doc:
        raise ValueError(
            f"{Path(run) / CONFIG_YAML} has no {name!r} section (was it edited?); valid: the "
            f"{CONFIG_YAML} that acl3d train wrote ({CONFIG_JSON} holds a copy)"
        )
    return doc[name]


def write_doc(run: Path, doc: dict) -> None:
    atomic_write(Path(run) / CONFIG_YAML, yaml.safe_dump(doc, sort_keys=False))
    atomic_write(Path(run) / CONFIG_JSON, json.dumps(doc, indent=2))


def write_provenance(run: Path, segments: list) -> None:
    """RUN/provenance.json, replaced whole (a JSON list of objects of plain values)."""
    if not isinstance(segments, list) or not all(isinstance(s, dict) for s in segments):
        raise ValueError(f"provenance={segments!r}; valid: a list of mappings (segments)")
    atomic_write(Path(run) / PROVENANCE, json.dumps(segments, indent=1, sort_keys=True))


def read_provenance(run: Path) -> list | None:
    """RUN/provenance.json's segments, or None for a run written before it existed."""
    path = Path(run) / PROVENANCE
    if not path.exists():
        return None
    try:
        segments = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path} cannot be read: {exc}") from None
    if not isinstance(segments, list) or not all(isinstance(s, dict) for s in segments):
        raise ValueError(f"{path} is not a JSON list of segments (was it edited?)")
    return segments
