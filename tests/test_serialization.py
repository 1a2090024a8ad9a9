"""Robots travel: a Robot pickles (pickle, copy.deepcopy, torch.save, spawned workers) as its model
and options, and a program exported with torch.export names ops that do not depend on the machine,
so it loads in another process once the same robot is loaded there."""
from __future__ import annotations

import copy
import io
import multiprocessing
import os
import pickle
import subprocess
import sys
import textwrap

import torch

import torch_grid
from torch_grid.ops.build import op_namespace


def _check_same(a, b, q):
    assert a.model == b.model and a.convention == b.convention
    assert torch.equal(a.crba(q), b.crba(q))


def test_robot_pickles(robots):
    robot = robots["go2"]
    mujoco = torch_grid.load("go2", convention="mujoco")
    q = robot.random_configuration(3)
    for r in (robot, mujoco):
        _check_same(r, pickle.loads(pickle.dumps(r)), q)
        _check_same(r, copy.deepcopy(r), q)
        buffer = io.BytesIO()
        torch.save({"robot": r}, buffer)
        buffer.seek(0)
        _check_same(r, torch.load(buffer, weights_only=False)["robot"], q)
    view = pickle.loads(pickle.dumps(robot.mujoco))
    assert torch.equal(view.crba(q), robot.mujoco.crba(q))
    # the cache it was loaded from travels with it (a worker looks there, not in the default cache)
    cached = torch_grid.load("go2", cache_dir=torch_grid.ops.build.default_cache_dir())
    assert cached._cache_dir == str(torch_grid.ops.build.default_cache_dir().resolve())
    assert pickle.loads(pickle.dumps(cached))._cache_dir == cached._cache_dir


def _gravity_in_worker(args):
    robot, q = args
    return robot.generalized_gravity(q)


def test_robot_travels_to_spawned_workers(robots):
    robot = robots["iiwa14"]
    q = robot.random_configuration(4)
    with multiprocessing.get_context("spawn").Pool(1) as pool:
        (got,) = pool.map(_gravity_in_worker, [(robot, q)])
    assert torch.equal(got, robot.generalized_gravity(q))


def test_namespace_ignores_machine_and_names_the_robot(robots, monkeypatch):
    robot = robots["go2"]
    namespace = op_namespace(robot.model, True)
    assert robot._ops.name == namespace and namespace.startswith("torch_grid_go2_")
    monkeypatch.setenv("TORCH_GRID_PORTABLE", "1")  # other CPU flags: another binary, the same ops
    assert op_namespace(robot.model, True) == namespace
    assert op_namespace(robot.model, False) != namespace


class _Policy(torch.nn.Module):
    def __init__(self, robot):
        super().__init__()
        self.robot = robot

    def forward(self, q, qd, tau):
        return self.robot.mujoco.forward_dynamics(q, qd, tau) + self.robot.com(q).sum(-1, keepdim=True)


def test_exported_program_loads_in_another_process(robots, tmp_path):
    robot = robots["go2"]
    q = robot.mujoco.random_configuration(2)
    qd, tau = torch.randn(2, robot.nv, dtype=torch.float64), torch.randn(2, robot.nv, dtype=torch.float64)
    program = torch.export.export(_Policy(robot), (q, qd, tau))
    path = tmp_path / "policy.pt2"
    torch.export.save(program, path)
    torch.save((q, qd, tau, _Policy(robot)(q, qd, tau)), tmp_path / "io.pt")
    script = f"""
        import torch, torch_grid
        q, qd, tau, expected = torch.load({str(tmp_path / 'io.pt')!r})
        {{load}}
        program = torch.export.load({str(path)!r})
        print(torch.equal(program.module()(q, qd, tau), expected))
    """
    env = {**os.environ}
    loaded = subprocess.run([sys.executable, "-c", textwrap.dedent(script.format(load="torch_grid.load('go2')"))],
                            capture_output=True, text=True, timeout=900, env=env)
    assert loaded.returncode == 0 and loaded.stdout.strip() == "True", loaded.stderr[-3000:]
    early = subprocess.run([sys.executable, "-c", textwrap.dedent(script.format(load=""))], capture_output=True, text=True,
                           timeout=900, env=env)
    assert early.returncode != 0 and "go2" in early.stderr, early.stderr[-3000:]
