"""The policy file of a torch-native student (`final_model.zip`, a checkpoint's `model.zip`),
recognised without importing its learner's library."""

from __future__ import annotations

import zipfile

POLICY_MEMBERS = ("acl3d_policy.json", "actor.pt")


def is_policy_file(path) -> bool:
    """Whether `path` is a policy saved by a torch-native student (else e.g. an SB3 zip)."""
    try:
        with zipfile.ZipFile(path) as z:
            return POLICY_MEMBERS[0] in z.namelist()
    except (OSError, zipfile.BadZipFile):
        return False
