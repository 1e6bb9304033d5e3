"""odolab/core/memory.py: glibc's malloc keeps freed blocks for reuse in a command's process and in the
workers of the local Ray instance it starts; a user's own malloc settings are left alone."""

from __future__ import annotations

import os
import platform
import subprocess
import sys

import pytest

from odolab.core.memory import ENVIRONMENT, children_keep_freed_memory
from tests.helpers import run_python

#: keep_freed_memory sets glibc's mallopt thresholds; other C libraries (macOS, musl) have none, and it
#: then leaves the process as it is (returns False), so there is nothing to measure.
glibc = pytest.mark.skipif(
    platform.system() != "Linux" or platform.libc_ver()[0] != "glibc",
    reason="keep_freed_memory sets glibc's malloc thresholds; this C library has none",
)

#: Blocks of 1-5 MiB allocated and written, all alive at once, then freed, as a network pass's
#: activations are; prints the minor page faults of the rounds after the first.
_CHURN = """
import resource, sys
import numpy as np
from odolab.core.memory import keep_freed_memory
if sys.argv[-1] == "keep":
    assert keep_freed_memory()
def churn():
    blocks = [np.ones(mib << 17) for mib in (1, 3, 2, 5, 4, 1, 3, 2, 5, 4)]
    del blocks
churn()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):
    churn()
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _faults(tmp_path, how: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    script = tmp_path / "churn.py"
    script.write_text(_CHURN)
    environ = {k: v for k, v in os.environ.items() if k not in (*ENVIRONMENT, "GLIBC_TUNABLES")} | (env or {})
    return subprocess.run(
        [sys.executable, str(script), how], capture_output=True, text=True, env=environ, timeout=60, check=False
    )


@glibc
def test_keep_freed_memory_reuses_freed_blocks_instead_of_faulting_them_in_again(tmp_path):
    default, kept = _faults(tmp_path, "default"), _faults(tmp_path, "keep")
    assert default.returncode == 0 and kept.returncode == 0, default.stderr + kept.stderr
    pages = 20 * 30 * (1 << 20) // 4096  # what the rounds write
    assert int(default.stdout) > pages // 4  # glibc's defaults map many of them anew
    assert int(kept.stdout) < pages // 20


@glibc
def test_keep_freed_memory_leaves_a_users_own_settings(tmp_path):
    done = _faults(tmp_path, "keep", env={"MALLOC_TRIM_THRESHOLD_": "0"})
    assert done.returncode != 0 and "AssertionError" in done.stderr


def test_children_keep_freed_memory_only_for_processes_started_in_the_block(monkeypatch):
    for name in (*ENVIRONMENT, "GLIBC_TUNABLES"):
        monkeypatch.delenv(name, raising=False)
    show = [sys.executable, "-c", "import os; print(os.environ.get('MALLOC_MMAP_THRESHOLD_'))"]
    with children_keep_freed_memory():
        inside = subprocess.run(show, capture_output=True, text=True, check=True).stdout.strip()
    after = subprocess.run(show, capture_output=True, text=True, check=True).stdout.strip()
    assert (inside, after) == (ENVIRONMENT["MALLOC_MMAP_THRESHOLD_"], "None")
    assert not any(name in os.environ for name in ENVIRONMENT)


def test_children_keep_freed_memory_leaves_a_users_own_settings(monkeypatch):
    monkeypatch.setenv("GLIBC_TUNABLES", "glibc.malloc.trim_threshold=0")
    monkeypatch.delenv("MALLOC_MMAP_THRESHOLD_", raising=False)
    with children_keep_freed_memory():
        assert "MALLOC_MMAP_THRESHOLD_" not in os.environ
    assert os.environ["GLIBC_TUNABLES"] == "glibc.malloc.trim_threshold=0"


@pytest.mark.slow
def test_the_workers_of_a_local_ray_instance_keep_freed_memory(tmp_path):
    done = run_python(
        tmp_path,
        "import os, ray\n"
        "from odolab.core.parallel import shutdown_ray, start_ray\n"
        "assert start_ray(None, quiet=True)\n"
        "seen = ray.get(ray.remote(lambda: os.environ.get('MALLOC_MMAP_THRESHOLD_')).remote())\n"
        "print(seen, os.environ.get('MALLOC_MMAP_THRESHOLD_'))\n"
        "shutdown_ray()\n",
        env={},
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split() == [ENVIRONMENT["MALLOC_MMAP_THRESHOLD_"], "None"]
