"""RUN/checkpoints/: the folders a run resumes from, each sealed by a manifest of hashes.

A checkpoint is filled as `.partial_step_N/`, sealed by `manifest.json` (the size and SHA-256 of
every other file in it), renamed to `step_N/` and only then named in `LATEST`. A `step_N` folder
is therefore complete when published; its manifest proves that no file changed since (a
truncated zip, a hand-edited `rng.json`). `LATEST` is where a resume starts; when it is empty
or names a folder that is gone, the newest `step_N` folder is.
"""

from __future__ import annotations

import hashlib
import json
import re
import zipfile
import zlib
from pathlib import Path

from acl3d.run_format.layout import LATEST, MANIFEST

MANIFEST_FORMAT = 1
_STEP_NAME = re.compile(r"^step_(\d+)$")
_CHUNK = 1 << 20


class DamagedCheckpoint(ValueError):
    """A checkpoint file is missing, truncated, corrupt or edited (a resume falls back past it)."""


def checkpoint_name(step: int) -> str:
    return f"step_{int(step):012d}"


def checkpoint_step(name: str) -> int | None:
    match = _STEP_NAME.match(name)
    return int(match[1]) if match else None


def latest_name(checkpoints: Path) -> str | None:
    """What LATEST says (possibly empty), or None when there is no LATEST."""
    try:
        return (Path(checkpoints) / LATEST).read_text().strip()
    except FileNotFoundError:
        return None


def published(checkpoints: Path) -> list[Path]:
    """The published `step_N` folders, newest first."""
    folder = Path(checkpoints)
    found = [p for p in folder.iterdir() if _STEP_NAME.match(p.name) and p.is_dir()]
    return sorted(found, key=lambda p: checkpoint_step(p.name), reverse=True)


def resume_candidates(checkpoints: Path) -> tuple[list[Path], str | None]:
    """The checkpoints a resume may start from, newest first: LATEST and those before it; or,
    when LATEST is empty or names a folder that is gone, every published one (with the reason
    to say). Folders after LATEST were published by a writer killed before naming them."""
    if not Path(checkpoints).is_dir():
        return [], None
    folders = published(checkpoints)
    latest = latest_name(checkpoints)
    names = [p.name for p in folders]
    if latest in names:
        return folders[names.index(latest) :], None
    if latest is None or not folders:
        return folders, None
    said = "is empty" if not latest else f"names {latest!r}, which is not there"
    return folders, f"{Path(checkpoints) / LATEST} {said}: using the newest checkpoint instead"


def file_hash(path: Path) -> str:
    digest = hashlib.sha256()
    with Path(path).open("rb") as f:
        while chunk := f.read(_CHUNK):
            digest.update(chunk)
    return digest.hexdigest()


def write_manifest(folder: Path) -> None:
    """Seal a filled checkpoint folder: manifest.json lists every other file's size and hash."""
    files = {
        p.name: {"bytes": p.stat().st_size, "sha256": file_hash(p)}
        for p in sorted(Path(folder).iterdir())
        if p.is_file() and p.name != MANIFEST
    }
    doc = {"format": MANIFEST_FORMAT, "files": files}
    (Path(folder) / MANIFEST).write_text(json.dumps(doc, indent=1))


def verify_manifest(folder: Path, prefix: str = "") -> None:
    """Every file the manifest lists (those whose names start with `prefix`) is there with its
    size and hash: `DamagedCheckpoint` naming the first that is not, or a missing manifest."""
    folder = Path(folder)
    try:
        doc = json.loads((folder / MANIFEST).read_text())
    except FileNotFoundError:
        raise DamagedCheckpoint(
            f"{folder / MANIFEST} is missing (a checkpoint written before checkpoints carried "
            "hashes, or damaged)"
        ) from None
    except (OSError, ValueError):
        doc = None
    files = doc.get("files") if isinstance(doc, dict) else None
    if not isinstance(files, dict) or doc.get("format") != MANIFEST_FORMAT:
        raise DamagedCheckpoint(f"{folder / MANIFEST} cannot be read (truncated or edited)")
    for name, expected in sorted(files.items()):
        if not name.startswith(prefix):
            continue
        path = folder / name
        if not path.is_file():
            raise DamagedCheckpoint(f"{path} is missing")
        if not isinstance(expected, dict) or not _matches(path, expected):
            raise DamagedCheckpoint(
                f"{path} differs from the checkpoint's {MANIFEST} (truncated, corrupt or edited "
                "since it was written)"
            )


def _matches(path: Path, expected: dict) -> bool:
    return path.stat().st_size == expected.get("bytes") and file_hash(path) == expected.get(
        "sha256"
    )


def check_zip(path: Path, members: tuple[str, ...] = ()) -> None:
    """A complete zip holding `members` (every member's CRC checked): ValueError naming the
    file otherwise. Name the members: the half of a truncated SB3 zip can read as the zip
    stored inside it (its policy.pth)."""
    try:
        with zipfile.ZipFile(path) as z:
            missing = sorted(set(members) - set(z.namelist()))
            bad = z.testzip()
    except FileNotFoundError:
        raise ValueError(f"{path} is missing") from None
    except (OSError, zipfile.BadZipFile, EOFError, zlib.error) as exc:
        raise ValueError(f"{path} is truncated or corrupt: {exc}") from None
    if missing or bad is not None:
        why = f"member {bad!r} fails its CRC check" if bad else f"no {', '.join(missing)}"
        raise ValueError(f"{path} is truncated or corrupt: {why}")
