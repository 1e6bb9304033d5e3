"""odolab.core.machine: the machine block every benchmark and study records, and the CPU's flags."""

from __future__ import annotations

from odolab.core import machine as machine_module


def test_machine_reads_the_cpus_model_family_and_bf16_flags(monkeypatch):
    text = {
        "now": "processor\t: 0\nmodel name\t: Some CPU\ncpu family\t: 25\nmodel\t\t: 17\n"
        "flags\t\t: fpu avx2 avx512_bf16\n\nprocessor\t: 1\nmodel name\t: Another\n"
    }
    monkeypatch.setattr(machine_module, "_read_cpuinfo", lambda: text["now"])
    found = machine_module.machine()
    assert (found["cpu_model"], found["cpu_family_model"], found["native_bf16"]) == ("Some CPU", "25/17", True)
    assert machine_module.cpu_flags() == {"fpu", "avx2", "avx512_bf16"}
    text["now"] = "processor\t: 0\nFeatures\t: fp asimd\n"  # an Arm CPU without bf16
    found = machine_module.machine()
    assert (found["cpu_model"], found["cpu_family_model"], found["native_bf16"]) == ("unknown", "", False)
    text["now"] = ""  # no /proc/cpuinfo: nothing known
    assert machine_module.machine()["native_bf16"] is None and machine_module.cpu_flags() == set()
