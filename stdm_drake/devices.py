"""The PyTorch device a setting names, checked before any work (sampling MPC's `device`, the particles of
`learning.particles`): one small utility below every stage, so the closed loop need not reach into learning."""
from __future__ import annotations

from stdm_drake.errors import InputError


def torch_device(name: str):
    """The `torch.device` `name` ("cpu", "cuda", "cuda:1"); InputError in one line for a name PyTorch does not
    know or a device this machine does not have."""
    import torch
    try:
        device = torch.device(name)
    except (RuntimeError, ValueError):
        raise InputError(f"device {name!r} is not a PyTorch device (cpu, cuda, cuda:N)") from None
    if device.type == "cuda":
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if count == 0:
            raise InputError(f"device {name!r}: this machine has no CUDA device (torch.cuda.is_available() is False)")
        if device.index is not None and device.index >= count:
            raise InputError(f"device {name!r}: this machine has {count} CUDA device(s), cuda:0..cuda:{count - 1}")
    elif device.type != "cpu":
        raise InputError(f"device {name!r}: sampling MPC runs on cpu or cuda, not {device.type}")
    return device
