"""The machine fingerprint recorded with each baseline entry."""

from __future__ import annotations

from importlib import metadata
from pathlib import Path

from pipelines.regress.machine import _cpu, machine_fingerprint

CPUINFO = """processor\t: 0
vendor_id\t: AuthenticAMD
model name\t: AMD EPYC 9R14 96-Core Processor
flags\t\t: fpu sse sse2 sse4_1 sse4_2 avx avx2 fma avx512f avx512bw

processor\t: 1
model name\t: something else
flags\t\t: fpu
"""


def test_cpu_model_and_flags_from_the_first_processor(tmp_path: Path) -> None:
    path = tmp_path / "cpuinfo"
    path.write_text(CPUINFO)
    model, flags = _cpu(path)
    assert model == "AMD EPYC 9R14 96-Core Processor"
    assert {"avx2", "fma", "avx512f", "avx512bw"} <= flags and "something" not in model
    assert _cpu(tmp_path / "absent") == ("", set())


def test_fingerprint_names_the_libraries_that_change_floating_point() -> None:
    line = machine_fingerprint()
    assert f"numpy {metadata.version('numpy')}" in line
    assert f"open3d {metadata.version('open3d')}" in line
    assert "gtsam " in line and "\n" not in line
