"""The PyTorch device a setting names, checked before any work (sampling MPC's `device`, the particles of
`learning.particles`), and the CPU threads a computation uses: small utilities below every stage, so the closed loop
need not reach into learning."""
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


def compute_threads(threads: int) -> None:
    """Run this process's arithmetic on `threads` CPU threads: PyTorch's and those of the BLAS and OpenMP libraries
    numpy and torch load (threadpoolctl). The same count gives the same numbers on any machine: a float32 matrix
    product summed by two threads differs in its last bits from one thread's (held-out benchmark: the evaluation of
    the same weights on a Ray worker and in a 2-core driver differed at 1e-8)."""
    import threadpoolctl
    import torch
    torch.set_num_threads(threads)
    threadpoolctl.threadpool_limits(threads)
