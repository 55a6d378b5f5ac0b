"""A fixed rollout per env and body hashes to the fingerprint recorded before the env-core refactor.

Regenerate (only for an intended behaviour change, said in the commit) with
`python scripts/fingerprints.py --write`.
"""

import importlib.util
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("fingerprints", ROOT / "scripts" / "fingerprints.py")
fingerprints = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(fingerprints)
RECORDED = json.loads((ROOT / "tests" / "data" / "fingerprints.json").read_text())


@pytest.mark.parametrize("env_name, body", fingerprints.CASES)
def test_rollout_matches_recorded_fingerprint(env_name, body):
    assert fingerprints.fingerprint(env_name, body) == RECORDED[f"{env_name}/{body}"]
