import pytest
import torch

from eponet.core.devices import native_bfloat16, resolve_precision, torch_device

SAPPHIRE_RAPIDS = "flags\t\t: fpu vme sse2 avx2 avx512f avx512bw avx512_vnni amx_bf16 amx_tile amx_int8\n"
COOPER_LAKE = "processor\t: 0\nflags\t\t: fpu sse2 avx2 avx512f avx512bw avx512_bf16 avx512_vnni\n"
SKYLAKE = "flags\t\t: fpu sse2 avx2 avx512f avx512bw avx512dq avx512vl\n"  # AVX-512 without BF16: emulated
ZEN3 = "flags\t\t: fpu sse2 avx2 fma\n"


@pytest.mark.parametrize("flags, native", [(SAPPHIRE_RAPIDS, True), (COOPER_LAKE, True), (SKYLAKE, False),
                                           (ZEN3, False)])
def test_native_bfloat16_reads_the_cpu_flags(tmp_path, flags, native):
    cpuinfo = tmp_path / "cpuinfo"
    cpuinfo.write_text(flags)
    assert native_bfloat16(str(cpuinfo)) is native


def test_native_bfloat16_is_false_without_cpuinfo(tmp_path):
    assert native_bfloat16(str(tmp_path / "absent")) is False


def test_auto_precision_is_bfloat16_only_on_a_cpu_that_has_it(monkeypatch):
    import eponet.core.devices as devices

    for native in (True, False):
        monkeypatch.setattr(devices, "native_bfloat16", lambda native=native: native)
        assert resolve_precision("auto", torch.device("cpu")) == ("bfloat16" if native else "float32")
        assert resolve_precision("auto", torch.device("cuda")) == "float32"
        assert resolve_precision("float32", torch.device("cpu")) == "float32"
        assert resolve_precision("bfloat16", torch.device("cpu")) == "bfloat16"


def test_torch_device_auto_is_the_cpu_without_a_gpu(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert torch_device("auto") == torch.device("cpu")
