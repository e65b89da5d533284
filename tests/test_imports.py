"""What importing a part of pved loads: the models and the Gymnasium ids come without the
simulator (``import pved`` registers the ids from the catalogue, ``pved.env_ids``)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pved


def _python(code: str) -> subprocess.CompletedProcess[str]:
    """``code`` run by a fresh interpreter that imports this checkout's pved."""
    src = str(Path(pved.__file__).resolve().parents[1])
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([src, os.environ.get("PYTHONPATH", "")])}
    return subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300
    )


def test_importing_the_models_loads_neither_the_envs_nor_the_simulator() -> None:
    done = _python(
        "import sys, pved.models\n"
        "loaded = sorted(m for m in sys.modules if m.split('.')[:2] == ['pved', 'envs'])\n"
        "assert not loaded, loaded\n"
        "assert 'mujoco' not in sys.modules\n"
        "print(pved.__file__)\n"
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == pved.__file__  # this checkout's pved, not another


def test_import_pved_registers_every_id_and_gymnasium_makes_one() -> None:
    done = _python(
        "import sys, pved, gymnasium\n"
        "from pved.env_ids import ENV_IDS\n"
        "assert 'pved.envs' not in sys.modules\n"
        "for name, entry in ENV_IDS.items():\n"
        "    assert gymnasium.spec(name).entry_point == entry.gym_entry_point, name\n"
        "env = gymnasium.make('pved/Reacher3Reach-v0')\n"
        "obs, _ = env.reset(seed=0)\n"
        "assert obs.shape == env.observation_space.shape\n"
        "assert 'pved.envs.reacher' in sys.modules and 'pved.envs.locomotion' not in sys.modules\n"
    )
    assert done.returncode == 0, done.stderr
