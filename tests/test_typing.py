"""mypy runs clean on the package with the configuration in mypy.ini (its reasons are there)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.both_ways  # mypy's verdict must be clean without the extras and with all of them
def test_mypy_is_clean():
    exe = shutil.which("mypy", path=str(Path(sys.executable).parent)) or shutil.which("mypy")
    assert exe, "mypy is not installed"
    done = subprocess.run([exe, "--config-file", str(ROOT / "mypy.ini"), "--no-incremental"], cwd=ROOT,
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stdout[-6000:] + done.stderr[-2000:]
