"""Which torch devices this machine has: a device a user names is checked here before anything
is built, so that a mistyped or absent one is refused naming it (torch imported only then, so
the CLI's parser stays fast)."""

from __future__ import annotations

from acl3d import validation as check


def usable(device, *, name: str = "device", mps: bool = False, also: tuple[str, ...] = ()):
    """`device` (a string or a torch.device) as a `torch.device` this machine has: the CPU, a
    visible CUDA GPU (cuda or cuda:N) or, with `mps`, Apple's GPU where usable. Otherwise the
    error names `name`, the value, and what is valid here (`also`: other names the caller
    accepts, listed with them)."""
    import torch

    listed = _either(["cpu", *also, "cuda", "cuda:N", *(["mps (where present)"] if mps else [])])
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError):
        raise check.fail(name, device, listed) from None
    if dev.type == "cpu":
        return dev
    if dev.type == "cuda":
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        others = _either(["cpu", *also])
        if count == 0:
            raise check.fail(name, device, f"{others} (no CUDA GPU is visible)")
        if dev.index is not None and dev.index >= count:
            raise check.fail(name, device, f"cuda:0 to cuda:{count - 1} or {others}")
        return dev
    if mps and dev.type == "mps" and torch.backends.mps.is_available():
        return dev
    raise check.fail(name, device, listed)


def _either(names: list[str]) -> str:
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + f" or {names[-1]}"


def check_device(device: str) -> None:
    """A run's device: `usable` (mps included), or auto (the run picks)."""
    if device != "auto":
        usable(device, mps=True, also=("auto",))
