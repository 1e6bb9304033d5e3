"""odolab.core.machine: the machine block every benchmark and study records."""

from __future__ import annotations

from odolab.core import machine as machine_module


def test_machine_reads_the_cpus_model_family_and_bf16_flags(tmp_path, monkeypatch):
    cpuinfo = tmp_path / "cpuinfo"
    cpuinfo.write_text(
        "processor\t: 0\nmodel name\t: Some CPU\ncpu family\t: 25\nmodel\t\t: 17\nflags\t\t: fpu avx2 avx512_bf16\n\n"
        "processor\t: 1\nmodel name\t: Another\n"
    )
    real_open = open
    monkeypatch.setattr(
        machine_module,
        "open",
        lambda path, *a, **k: real_open(cpuinfo if path == "/proc/cpuinfo" else path, *a, **k),
        raising=False,
    )
    found = machine_module.machine()
    assert (found["cpu_model"], found["cpu_family_model"], found["native_bf16"]) == ("Some CPU", "25/17", True)
    cpuinfo.write_text("processor\t: 0\nFeatures\t: fp asimd\n")  # an Arm CPU without bf16
    found = machine_module.machine()
    assert (found["cpu_model"], found["cpu_family_model"], found["native_bf16"]) == ("unknown", "", False)
    cpuinfo.unlink()  # no /proc/cpuinfo: nothing known
    assert machine_module.machine()["native_bf16"] is None
