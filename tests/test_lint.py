"""The code follows ament_flake8's conventions (99 columns, single quotes; setup.cfg)."""
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_flake8_finds_nothing():
    """flake8 with the project's configuration reports no problem in any Python file."""
    r = subprocess.run([sys.executable, '-m', 'flake8', 'sapga_ros', 'sim_nodes', 'tests',
                        'setup.py'], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
