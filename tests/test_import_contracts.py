"""The house rules in pyproject.toml ([tool.importlinter]) hold, checked by import-linter's `lint-imports`."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LINT = Path(sys.executable).with_name("lint-imports")


def _lint(*args):
    if not LINT.exists():
        pytest.fail(f"{LINT} not found: pip install -e '.[test]' installs import-linter")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    return subprocess.run(
        [str(LINT), "--no-cache", *args], cwd=ROOT, env=env, capture_output=True, text=True, timeout=120, check=False
    )


def test_import_contracts_are_kept():
    proc = _lint()
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-2000:]
    assert "0 broken" in proc.stdout and "8 kept" in proc.stdout


def test_a_broken_contract_is_reported(tmp_path):
    # The runner does import geometry: a contract forbidding it must fail, so the check above is real.
    cfg = tmp_path / "contracts.toml"
    cfg.write_text(
        '[tool.importlinter]\nroot_packages = ["odolab"]\n\n[[tool.importlinter.contracts]]\n'
        'name = "runner without geometry"\ntype = "forbidden"\nsource_modules = ["odolab.running.runner"]\n'
        'forbidden_modules = ["odolab.core.geometry"]\n'
    )
    proc = _lint("--config", str(cfg))
    assert proc.returncode != 0 and "BROKEN" in proc.stdout


def test_no_contract_ignores_an_import():
    """The contracts hold as written: none lists an import it lets through."""
    assert all("ignore_imports" not in c for c in _contracts())


def test_the_plug_in_contracts_name_every_wing_but_the_public_faces():
    """A wing added to odolab/ falls under the plug-in contracts: each forbids every module and
    package directly in odolab/ but odolab.api (and, for the learned plug-ins, odolab.learned.training)."""
    wings = {
        f"odolab.{p.stem}" for p in (ROOT / "odolab").iterdir() if p.suffix == ".py" or (p / "__init__.py").exists()
    }
    wings -= {"odolab.__init__", "odolab.api", "odolab.data"}  # odolab/data holds the shipped files, no code
    learned = {
        f"odolab.learned.{p.name}" for p in (ROOT / "odolab" / "learned").iterdir() if (p / "__init__.py").exists()
    }
    forbidden = {
        tuple(c["source_modules"]): set(c["forbidden_modules"]) for c in _contracts() if c["type"] == "forbidden"
    }
    assert forbidden[("baselines",)] == wings
    assert forbidden[("odolab.learned.deepvo", "examples")] == wings - {"odolab.learned"} | learned - {
        "odolab.learned.training",
        "odolab.learned.deepvo",
    }


def _contracts() -> list[dict]:
    import tomllib

    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]


def test_only_the_command_wing_builds_argument_parsers():
    """Every command line lives in odolab/cli/ (the examples are a user's own code); elsewhere a
    command's python -m face hands over to it."""
    builders = [
        path.relative_to(ROOT).as_posix()
        for folder in ("odolab", "baselines", "studies")
        for path in sorted((ROOT / folder).rglob("*.py"))
        if "ArgumentParser(" in path.read_text(encoding="utf-8") and "odolab/cli/" not in path.as_posix()
    ]
    assert builders == []
