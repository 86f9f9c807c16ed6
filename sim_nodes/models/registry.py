"""Which modules of ``sim_nodes/models`` are models, read from the files alone.

A model is a module of this folder that defines ``mdp_step_lanes`` at its top level; its
name is the file's stem (``model:`` in a problem YAML).  Nothing is imported here, so
``setup.py`` runs this file on its own to name the simulator executables, one per model.
"""
from __future__ import annotations

import ast
from pathlib import Path

FOLDER = Path(__file__).resolve().parent
KERNEL = 'mdp_step_lanes'   # the function that makes a module a model
GENERIC_SIM = 'sim_node'    # the simulator executable of every problem (``-p problem:=``)


def defines_kernel(path: Path) -> bool:
    """Whether the Python file ``path`` defines ``mdp_step_lanes`` at its top level."""
    tree = ast.parse(path.read_text(encoding='utf-8'), str(path))
    return any(isinstance(node, ast.FunctionDef) and node.name == KERNEL for node in tree.body)


def model_names(folder: Path = FOLDER) -> tuple[str, ...]:
    """The models of ``folder``, sorted: a model's number is its index here."""
    return tuple(sorted(p.stem for p in folder.glob('*.py')
                        if not p.stem.startswith('_') and defines_kernel(p)))


def sim_executable(model: str) -> str:
    """The simulator executable of ``model`` (``acrobot_sim``): ``sim_node`` with that
    model's problem (the YAML of the same name) as the default ``problem``."""
    return f'{model}_sim'
