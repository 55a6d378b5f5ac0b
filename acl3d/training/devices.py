"""Which torch devices this machine has: a run's `device` is checked here before anything is
built (torch imported only then, so the CLI's parser stays fast)."""

from __future__ import annotations

from acl3d import validation as check


def check_device(device: str) -> None:
    """A torch device this machine has: cpu, auto, cuda[:N] with that GPU, or mps where usable."""
    import torch

    valid = "cpu, auto, cuda, cuda:N or mps (where present)"
    if device == "auto":
        return
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError):
        raise check.fail("device", device, valid) from None
    if dev.type == "cpu":
        return
    if dev.type == "cuda":
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if count == 0:
            raise check.fail("device", device, "cpu or auto (no CUDA GPU is visible)")
        if dev.index is not None and dev.index >= count:
            raise check.fail("device", device, f"cuda:0 to cuda:{count - 1}, cpu or auto")
        return
    if dev.type == "mps" and torch.backends.mps.is_available():
        return
    raise check.fail("device", device, valid)
