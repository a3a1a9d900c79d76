"""Where and in what arithmetic torch stages run: the ``device`` parameter (``auto``, ``cpu``, ``cuda``) as a
torch device, and the ``precision`` parameter (``float32``, ``bfloat16``, ``auto``)."""

from __future__ import annotations

__all__ = ["DEVICES", "PRECISIONS", "native_bfloat16", "resolve_precision", "torch_device"]

#: Values of a stage's ``device`` parameter.
DEVICES = ("auto", "cpu", "cuda")

#: Values of a stage's ``precision`` parameter.
PRECISIONS = ("float32", "bfloat16", "auto")


def torch_device(name: str):
    """``torch.device`` for ``name``; ``auto`` is the GPU when one is available, else the CPU."""
    import torch

    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


def native_bfloat16(cpuinfo: str = "/proc/cpuinfo") -> bool:
    """Whether this CPU multiplies bfloat16 in hardware (x86 AVX-512 BF16 or AMX-BF16, from the kernel's CPU
    flags): there bfloat16 autocast runs convolutions about twice as fast as float32; elsewhere (older AVX-512,
    AVX2, systems without ``/proc/cpuinfo``) oneDNN emulates it, far slower, and this is False."""
    try:
        with open(cpuinfo) as f:
            for line in f:
                if line.startswith("flags"):
                    return bool({"avx512_bf16", "amx_bf16"} & set(line.split(":", 1)[1].split()))
    except OSError:
        pass
    return False


def resolve_precision(name: str, device) -> str:
    """What a ``precision`` parameter means on ``device`` (a ``torch.device``): ``auto`` is bfloat16 on a CPU
    with :func:`native_bfloat16`, float32 elsewhere (on a GPU the networks are a few per cent of a run's time)."""
    if name != "auto":
        return name
    return "bfloat16" if device.type == "cpu" and native_bfloat16() else "float32"
