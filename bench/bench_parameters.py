"""Inertial parameters as inputs: per-sample time of each function with the robot's compiled-in
parameters (params=None), with one set of parameters shared by the batch, and with one set per sample
(B = 4096, float64, one thread, best of repeats), and of forward + backward with respect to the
parameters. With --write, the table replaces its section of bench/RESULTS.md.

    python bench/bench_parameters.py [--robots iiwa14 go2 g1] [--write]
    python bench/bench_parameters.py --compiled-only   # the params=None column alone (any version)
"""
from __future__ import annotations

import argparse
import datetime
import platform
import re
from pathlib import Path

import torch

import torch_grid
from bench_cpu import ROBOTS, per_sample_us

HERE = Path(__file__).resolve().parent
B = 4096
FUNCTIONS = {
    "inverse_dynamics": lambda r, q, qd, x, **p: r.inverse_dynamics(q, qd, x, **p),
    "forward_dynamics": lambda r, q, qd, x, **p: r.forward_dynamics(q, qd, x, **p),
    "crba": lambda r, q, qd, x, **p: r.crba(q, **p),
    "minv": lambda r, q, qd, x, **p: r.minv(q, **p),
    "generalized_gravity": lambda r, q, qd, x, **p: r.generalized_gravity(q, **p),
    "nonlinear_effects": lambda r, q, qd, x, **p: r.nonlinear_effects(q, qd, **p),
    "energy": lambda r, q, qd, x, **p: r.energy(q, qd, **p),
    "com": lambda r, q, qd, x, **p: r.com(q, **p),
    "jacobian_com": lambda r, q, qd, x, **p: r.jacobian_com(q, **p),
    "ccrba": lambda r, q, qd, x, **p: r.ccrba(q, qd, **p),
}
BACKWARD = ("inverse_dynamics", "forward_dynamics", "crba", "energy")


def _robot_and_states(name: str):
    src, floating, bundled = ROBOTS[name]
    robot = torch_grid.load(bundled or src, floating_base=floating)
    g = torch.Generator().manual_seed(0)
    q = robot.random_configuration(B, generator=g)
    qd, x = (torch.randn(B, robot.nv, dtype=torch.float64, generator=g) for _ in range(2))
    return robot, q, qd, x


def compiled_times(name: str) -> dict[str, float]:
    robot, q, qd, x = _robot_and_states(name)
    return {f: per_sample_us(lambda: call(robot, q, qd, x), B) for f, call in FUNCTIONS.items()}


def parameter_rows(name: str) -> list[str]:
    robot, q, qd, x = _robot_and_states(name)
    shared = robot.inertial_parameters().view(robot.nbodies, 10)
    scale = 0.8 + 0.4 * torch.rand(B, robot.nbodies, 1, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    per_sample = shared * scale
    rows = []
    for f, call in FUNCTIONS.items():
        compiled = per_sample_us(lambda: call(robot, q, qd, x), B)
        one = per_sample_us(lambda: call(robot, q, qd, x, params=shared), B)
        each = per_sample_us(lambda: call(robot, q, qd, x, params=per_sample), B)
        backward = ""
        if f in BACKWARD:
            def both():
                p = per_sample.detach().requires_grad_(True)
                out = call(robot, q, qd, x, params=p)
                (out if isinstance(out, torch.Tensor) else out[0]).sum().backward()
            backward = f"{per_sample_us(both, B):.3f}"
        rows.append(f"| {name} | {f} | {compiled:.3f} | {one:.3f} | {each:.3f} | {each / compiled:.2f} | {backward} |")
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", nargs="+", default=list(ROBOTS))
    parser.add_argument("--compiled-only", action="store_true")
    parser.add_argument("--write", action="store_true")
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.compiled_only:
        for name in args.robots:
            for f, t in compiled_times(name).items():
                print(f"{name} {f} {t:.4f}")
        return
    rows = ["| robot | function | compiled (params=None) | params shared | params per sample | per sample / compiled "
            "| forward + backward to params, per sample |", "|---|---|---|---|---|---|---|"]
    for name in args.robots:
        rows += parameter_rows(name)
    section = (f"## Inertial parameters as inputs, {datetime.date.today()}\n\nProduced by `python bench/bench_parameters.py "
               f"--write`. {platform.processor() or platform.machine()}, one thread, torch {torch.__version__}, "
               f"B = {B}, float64, µs per sample (best of repeats). \"params shared\": one (nbodies, 10) tensor for the "
               "batch; \"per sample\": (B, nbodies, 10), each link's inertia scaled by U(0.8, 1.2); the last column "
               "times the call and a backward with respect to per-sample parameters.\n\n" + "\n".join(rows) + "\n")
    print(section)
    if args.write:
        path = HERE / "RESULTS.md"
        text = path.read_text()
        pattern = re.compile(r"## Inertial parameters as inputs.*?(?=\n## |\Z)", re.S)
        text = pattern.sub(lambda _: section.rstrip("\n"), text) if pattern.search(text) else text.rstrip("\n") + "\n\n" + section
        path.write_text(text)


if __name__ == "__main__":
    main()
