"""CPU benchmark: per-sample time of batched torch_grid ops (B = 4096, float64) on one thread and
on all threads, against Pinocchio's per-call time through Python and in C++ (pinocchio_cpp.py);
first build and warm reload times of each robot and of the shared torch glue; a small call's
overhead; with --cuda, the per-thread stack of the G1 humanoid's CUDA kernels. With --write, its
tables replace bench/RESULTS.md's CPU section (and, with --cuda, the resources table), leaving the
sections of the other benchmarks as they are.

    python bench/bench_cpu.py [--write] [--cuda] [--robots iiwa14 go2 g1]
"""
from __future__ import annotations

import argparse
import datetime
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
import timeit
from pathlib import Path

import numpy as np
import pinocchio as pin
import torch

import torch_grid
from bench_step import step_section
from pinocchio_cpp import pinocchio_cpp_times

HERE = Path(__file__).resolve().parent
ERD = Path(sys.prefix) / "lib" / f"python{sys.version_info[0]}.{sys.version_info[1]}" / "site-packages" / \
    "cmeel.prefix" / "share" / "example-robot-data" / "robots"
ROBOTS = {
    "iiwa14": (str(torch_grid.model.parse.ROBOTS_DIR / "iiwa14.urdf"), False, "iiwa14"),
    "go2": (str(torch_grid.model.parse.ROBOTS_DIR / "go2.urdf"), True, "go2"),
    "g1": (str(ERD / "g1_description" / "urdf" / "g1_29dof_rev_1_0.urdf"), True, None),
}
B = 4096


def per_sample_us(fn, batch: int, seconds: float = 1.0) -> float:
    """Best over repeats of the time of one batched call, divided by the batch size (the
    machine is shared: the minimum is the stable estimate, as for Pinocchio below)."""
    fn()
    times = []
    deadline = time.perf_counter() + seconds
    while time.perf_counter() < deadline or len(times) < 5:
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times) / batch * 1e6


def per_call_us(fn, calls: int = 20000) -> float:
    fn()
    best = float("inf")
    for _ in range(5):
        t = time.perf_counter()
        for _ in range(calls // 5):
            fn()
        best = min(best, (time.perf_counter() - t) / (calls // 5) * 1e6)
    return best


def _load_seconds(source: str, floating: bool | None, cache: str) -> float:
    script = ("import time, torch; t = time.perf_counter(); import torch_grid; "
              f"torch_grid.load({source!r}, floating_base={floating!r}); print(time.perf_counter() - t)")
    return float(subprocess.run([sys.executable, "-c", script], env=dict(os.environ, TORCH_GRID_CACHE=cache),
                                capture_output=True, text=True, check=True).stdout.split()[-1])


def glue_build_time() -> tuple[float, str]:
    """Seconds to build the torch glue into an empty cache, and that cache (kept for build_times)."""
    cache = tempfile.mkdtemp(prefix="torch_grid_bench_")
    script = "from torch_grid.ops import build; build._load_glue(build._cache_root(None), build._cuda_available())"
    start = time.perf_counter()
    subprocess.run([sys.executable, "-c", script], env=dict(os.environ, TORCH_GRID_CACHE=cache), check=True,
                   capture_output=True)
    return time.perf_counter() - start, cache


def build_times(name: str, glue_cache: str) -> tuple[float, float]:
    """(first build of the robot, warm load in a new process after `import torch`), seconds, in a
    cache that holds only the torch glue (as after any first robot)."""
    src, floating, bundled = ROBOTS[name]
    with tempfile.TemporaryDirectory() as cache:
        shutil.copytree(Path(glue_cache) / ".glue", Path(cache) / ".glue")
        first, warm = (_load_seconds(bundled or src, floating, cache) for _ in range(2))
    return first, warm


def call_overhead(number: int = 20000) -> list[tuple[str, float]]:
    """µs per batch-of-one iiwa14 inverse_dynamics call through Robot and through the raw op (its
    autograd kernel included), best of 7; Pinocchio's rnea from Python for scale."""
    robot = torch_grid.load("iiwa14")
    q, qd, qdd = (torch.rand(1, robot.nv, dtype=torch.float64) for _ in range(3))
    q1, qd1, qdd1 = q[0].clone(), qd[0].clone(), qdd[0].clone()  # sliced once, so that only the call is timed
    op = robot._ops.inverse_dynamics
    model = pin.buildModelFromUrdf(ROBOTS["iiwa14"][0])
    data, x = model.createData(), np.zeros(model.nq)

    def best(fn) -> float:
        return min(timeit.timeit(fn, number=number) for _ in range(7)) / number * 1e6

    return [("Robot.inverse_dynamics, batch (1, 7)", best(lambda: robot.inverse_dynamics(q, qd, qdd))),
            ("Robot.inverse_dynamics, unbatched (7,)", best(lambda: robot.inverse_dynamics(q1, qd1, qdd1))),
            ("torch.ops op (through its autograd kernel)", best(lambda: op(q, qd, qdd, None, None, 0))),
            ("pinocchio.rnea from Python", best(lambda: pin.rnea(model, data, x, x, x)))]


STACK_HEADER = "| op | convention | registers | stack (bytes) | spill stores / loads (bytes) |"


def cuda_stack(name: str = "g1") -> list[str]:
    """Per-thread stack and registers of every float64 CUDA kernel (sm_90), both conventions."""
    from torch_grid.ops import cuda_report

    src, floating, bundled = ROBOTS[name]
    model = torch_grid.model.parse.source_to_model(bundled or src, floating)
    rows = [STACK_HEADER, "|---|---|---|---|---|"]
    for u in cuda_report.report(model, ("float64",)):
        name = u.op if u.kernel == "thread" else f"{u.op} [{u.kernel}]"
        rows.append(f"| {name} | {u.convention} | {u.registers} | {u.stack} | {u.spill_stores} / {u.spill_loads} |")
    return rows


def cases(name: str):
    """name -> (torch_grid batched call, Pinocchio single call from Python) for one robot; the names
    are also the keys of pinocchio_cpp_times."""
    src, floating, bundled = ROBOTS[name]
    robot = torch_grid.load(bundled or src, floating_base=floating)
    model = pin.buildModelFromUrdf(src, pin.JointModelFreeFlyer()) if floating else pin.buildModelFromUrdf(src)
    data = model.createData()
    g = torch.Generator().manual_seed(0)
    q = robot.random_configuration(B, generator=g)
    qd, qdd = (torch.randn(B, robot.nv, dtype=torch.float64, generator=g) for _ in range(2))
    frame = robot.nframes - 1
    qn, vn, an = (x[0].numpy() for x in (q, qd, qdd))
    return {
        "inverse_dynamics": (lambda: robot.inverse_dynamics(q, qd, qdd), lambda: pin.rnea(model, data, qn, vn, an)),
        "crba": (lambda: robot.crba(q), lambda: pin.crba(model, data, qn)),
        "minv": (lambda: robot.minv(q), lambda: pin.computeMinverse(model, data, qn)),
        "forward_dynamics": (lambda: robot.forward_dynamics(q, qd, qdd), lambda: pin.aba(model, data, qn, vn, an)),
        "frame_jacobian": (lambda: robot.frame_jacobian(q, frame),
                           lambda: pin.computeFrameJacobian(model, data, qn, frame, pin.LOCAL_WORLD_ALIGNED)),
        "inverse_dynamics_derivatives": (lambda: robot.inverse_dynamics_derivatives(q, qd, qdd),
                                      lambda: pin.computeRNEADerivatives(model, data, qn, vn, an)),
        "forward_dynamics_derivatives": (lambda: robot.forward_dynamics_derivatives(q, qd, qdd),
                                      lambda: pin.computeABADerivatives(model, data, qn, vn, an)),
        "nonlinear_effects": (lambda: robot.nonlinear_effects(q, qd),
                              lambda: pin.nonLinearEffects(model, data, qn, vn)),
        "generalized_gravity": (lambda: robot.generalized_gravity(q),
                                lambda: pin.computeGeneralizedGravity(model, data, qn)),
        # torch_grid returns the whole-body centre of mass only: Pinocchio skips the subtree ones.
        "com": (lambda: robot.com(q), lambda: pin.centerOfMass(model, data, qn, False)),
        "jacobian_com": (lambda: robot.jacobian_com(q), lambda: pin.jacobianCenterOfMass(model, data, qn, False)),
        "ccrba": (lambda: robot.ccrba(q, qd), lambda: pin.ccrba(model, data, qn, vn)),
        "coriolis_matrix": (lambda: robot.coriolis_matrix(q, qd),
                            lambda: pin.computeCoriolisMatrix(model, data, qn, vn)),
    }


def forward_and_backward_us(fn, inputs, batch: int, seconds: float = 1.0) -> tuple[float, float]:
    """Per-sample time of fn(*inputs) alone and of it plus a backward with respect to every input,
    one thread."""
    def both():
        leaves = [x.detach().requires_grad_(True) for x in inputs]
        out = fn(*leaves)
        sum(o.sum() for o in (out if isinstance(out, tuple) else (out,))).backward()

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    times = per_sample_us(lambda: fn(*inputs), batch), per_sample_us(both, batch, seconds)
    torch.set_num_threads(threads)
    return times


def backward_ratio(name: str) -> tuple[float, float]:
    """forward_dynamics alone and forward + backward (q, qd, tau), per sample, 1 thread."""
    src, floating, bundled = ROBOTS[name]
    robot = torch_grid.load(bundled or src, floating_base=floating)
    g = torch.Generator().manual_seed(0)
    inputs = [robot.random_configuration(B, generator=g)] + \
        [torch.randn(B, robot.nv, dtype=torch.float64, generator=g) for _ in range(2)]
    return forward_and_backward_us(robot.forward_dynamics, inputs, B)


def second_order(name: str, batch: int = B) -> list[tuple[str, float, float]]:
    """(function, forward, forward + backward) per sample, 1 thread, for functions whose backward is
    second order (q, qd and qdd all requiring grad)."""
    src, floating, bundled = ROBOTS[name]
    robot = torch_grid.load(bundled or src, floating_base=floating)
    g = torch.Generator().manual_seed(0)
    inputs = [robot.random_configuration(batch, generator=g)] + \
        [torch.randn(batch, robot.nv, dtype=torch.float64, generator=g) for _ in range(2)]
    frame = robot.nframes - 1
    functions = {
        "crba": (lambda q, qd, qdd: robot.crba(q)),
        "minv": (lambda q, qd, qdd: robot.minv(q)),
        "frame_jacobian": (lambda q, qd, qdd: robot.frame_jacobian(q, frame)),
        "coriolis_matrix": (lambda q, qd, qdd: robot.coriolis_matrix(q, qd)),
        "inverse_dynamics_derivatives": (lambda q, qd, qdd: robot.inverse_dynamics_derivatives(q, qd, qdd)),
        "forward_dynamics_derivatives": (lambda q, qd, tau: robot.forward_dynamics_derivatives(q, qd, tau)),
    }
    return [(fn_name, *forward_and_backward_us(fn, inputs, batch, seconds=0.5)) for fn_name, fn in functions.items()]


def second_order_kernel(name: str, cpp: dict[str, float]) -> list[str]:
    """Rows of inverse_dynamics_second_derivatives per sample (one thread, float64) at B = 4096 and 256,
    and forward_dynamics_second_derivatives at B = 256, beside Pinocchio's C++ ComputeRNEASecondOrderDerivatives
    per call (it reuses its four tensors, in cache; a batch writes B sets of them)."""
    src, floating, bundled = ROBOTS[name]
    robot = torch_grid.load(bundled or src, floating_base=floating)
    rows = []
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    for batch in (B, 256):
        g = torch.Generator().manual_seed(0)
        q = robot.random_configuration(batch, generator=g)
        qd, qdd = (torch.randn(batch, robot.nv, dtype=torch.float64, generator=g) for _ in range(2))
        ours = per_sample_us(lambda: robot.inverse_dynamics_second_derivatives(q, qd, qdd), batch)
        theirs = cpp["inverse_dynamics_second_derivatives"]
        rows.append(f"| {name} | inverse_dynamics_second_derivatives | {batch} | {ours:.2f} | {theirs:.2f} | {ours / theirs:.2f} |")
        print(rows[-1], flush=True)
    fd = per_sample_us(lambda: robot.forward_dynamics_second_derivatives(q, qd, qdd), 256)
    rows.append(f"| {name} | forward_dynamics_second_derivatives | 256 | {fd:.2f} | | |")
    torch.set_num_threads(threads)
    return rows


def transforms(name: str) -> list[str]:
    """Rows: a torch.func.vmap of inverse_dynamics and of crba against the batched call, and a
    Hessian-vector product (double backward) of a scalar loss on forward_dynamics against the forward,
    per sample, one thread, B = 4096."""
    src, floating, bundled = ROBOTS[name]
    robot = torch_grid.load(bundled or src, floating_base=floating)
    g = torch.Generator().manual_seed(0)
    q = robot.random_configuration(B, generator=g)
    qd, x, w = (torch.randn(B, robot.nv, dtype=torch.float64, generator=g) for _ in range(3))
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    rows = []
    for fn_name, fn, args in (("inverse_dynamics", robot.inverse_dynamics, (q, qd, x)), ("crba", robot.crba, (q,))):
        batched, mapped = per_sample_us(lambda: fn(*args), B), per_sample_us(lambda: torch.func.vmap(fn)(*args), B)
        rows.append(f"| {name} | vmap of {fn_name} | {batched:.3f} | {mapped:.3f} | {mapped / batched:.2f} |")

    def hvp():
        leaves = [t.detach().requires_grad_(True) for t in (q, qd, x)]
        loss = (w * robot.forward_dynamics(*leaves)).sum()
        grads = torch.autograd.grad(loss, leaves, create_graph=True)
        torch.autograd.grad(sum((gr * v).sum() for gr, v in zip(grads, (q, qd, x))), leaves)

    forward, both = per_sample_us(lambda: robot.forward_dynamics(q, qd, x), B), per_sample_us(hvp, B)
    rows.append(f"| {name} | Hessian-vector product through forward_dynamics | {forward:.3f} | {both:.3f} | {both / forward:.2f} |")
    torch.set_num_threads(threads)
    for row in rows:
        print(row, flush=True)
    return rows


def bench_robot(name: str) -> tuple[list[tuple[str, str, float, float, float, float]], float]:
    """Rows (robot, function, torch_grid µs/sample on 1 thread, on all threads, Pinocchio µs/call
    from Python, in C++), and Pinocchio's C++ crba without the lower-triangle fill, µs/call."""
    src, floating, bundled = ROBOTS[name]
    frame = torch_grid.load(bundled or src, floating_base=floating).nframes - 1  # as in cases()
    cpp = pinocchio_cpp_times(src, floating, B, frame=frame)
    rows = []
    threads = torch.get_num_threads()
    for fn_name, (ours, theirs) in cases(name).items():
        torch.set_num_threads(1)
        one = per_sample_us(ours, B)
        torch.set_num_threads(threads)
        many = per_sample_us(ours, B)
        ref = per_call_us(theirs)
        rows.append((name, fn_name, one, many, ref, cpp[fn_name]))
    return rows, cpp["crba_upper"], second_order_kernel(name, cpp)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", nargs="*", default=list(ROBOTS))
    parser.add_argument("--write", action="store_true", help="write bench/RESULTS.md")
    parser.add_argument("--cuda", action="store_true", help="also compile the G1 CUDA kernels and list their stack")
    args = parser.parse_args()
    glue_seconds, glue_cache = glue_build_time()
    print(f"torch glue built in {glue_seconds:.1f} s", flush=True)
    threads = torch.get_num_threads()
    lines = [f"| robot | function | 1 thread | {threads} threads | Pinocchio Python per call | "
             "Pinocchio C++ per call | 1 thread / C++ | 1 thread ≤ Pinocchio Python |", "|---|---|---|---|---|---|---|---|"]
    crba_upper = []
    builds = ["| robot | nq | nv | first build (s) | warm load, new process (s) |", "|---|---|---|---|---|"]
    grads = ["| robot | forward_dynamics (µs/sample) | forward + backward (µs/sample) | ratio |", "|---|---|---|---|"]
    second = ["| robot | function | forward (µs/sample) | forward + backward (µs/sample) |", "|---|---|---|---|"]
    kernels = ["| robot | function | B | 1 thread (µs/sample) | Pinocchio C++ per call | ratio |", "|---|---|---|---|---|---|"]
    func_rows = ["| robot | case | reference (µs/sample) | case (µs/sample) | ratio |", "|---|---|---|---|---|"]
    for name in args.robots:
        rows, upper, kernel_rows = bench_robot(name)
        kernels += kernel_rows
        func_rows += transforms(name)
        for robot, fn, one, many, ref, cpp in rows:
            lines.append(f"| {robot} | {fn} | {one:.3f} | {many:.3f} | {ref:.3f} | {cpp:.3f} | {one / cpp:.2f} | "
                         f"{'yes' if one <= ref else 'NO'} |")
            print(lines[-1], flush=True)
        crba_upper.append(f"{name} {upper:.3f} µs")
        forward, both = backward_ratio(name)
        grads.append(f"| {name} | {forward:.3f} | {both:.3f} | {both / forward:.2f} |")
        print(grads[-1], flush=True)
        for fn, forward, both in second_order(name):
            second.append(f"| {name} | {fn} | {forward:.2f} | {both:.1f} |")
            print(second[-1], flush=True)
        first, warm = build_times(name, glue_cache)
        src, floating, bundled = ROBOTS[name]
        r = torch_grid.load(bundled or src, floating_base=floating)
        builds.append(f"| {name} | {r.nq} | {r.nv} | {first:.1f} | {warm:.2f} |")
        print(builds[-1], flush=True)
    cpu = platform.processor() or platform.machine()
    try:
        cpu = next(line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo") if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    header = (f"## CPU, {datetime.date.today()}\n\nMachine: {cpu}, {os.cpu_count()} cores; torch {torch.__version__}, "
              f"Pinocchio {pin.__version__}; batch B = {B}, float64. Pinocchio is called once per sample from "
              "Python (its usual use), and from C++ in a loop over B random states with one Data reused "
              "(bench/pinocchio_cpp.cpp: its algorithms compiled with -O3 -march=native, one thread, best of 5 "
              "passes); torch_grid's time is one batched call divided by B, in µs per sample, including the "
              "allocation of the batched output. \"1 thread / C++\" is torch_grid on one thread over Pinocchio "
              "in C++ (below 1: torch_grid is faster).\n")
    text = header + "\n" + "\n".join(lines) + "\n\nPinocchio's crba and computeMinverse fill the upper " \
        "triangle only; as torch_grid returns the full matrix, their C++ times include the copy to the lower " \
        f"triangle. crba in C++ without it: {', '.join(crba_upper)}.\n\n" \
        f"First build of a robot: all functions, both conventions, float32 + float64, CPU, into a cache holding " \
        f"only the torch glue (which every robot shares; built once in {glue_seconds:.1f} s); warm load: " \
        "`import torch_grid` and `torch_grid.load` in a new process after `import torch`.\n\n" + "\n".join(builds) + \
        "\n\nAutograd: forward_dynamics alone against forward + backward with respect to q, qd and tau " \
        "(one thread, float64, B = 4096).\n\n" + "\n".join(grads) + \
        "\n\nSecond-order backwards (crba, frame_jacobian and inverse_dynamics_derivatives by their O(n d) kernels, " \
        "minv through crba's; forward_dynamics_derivatives through -M^-1 dtau/dx, the inverse-dynamics gradient's " \
        "backward and minv's; coriolis_matrix by its forward-mode dual-number kernel), with respect to every " \
        f"input, one thread, float64, B = {B}.\n\n" + "\n".join(second) + \
        "\n\nSecond-order kernels: the four (nv, nv, nv) tensors of inverse_dynamics_second_derivatives per sample, " \
        "one thread, float64, against Pinocchio's C++ ComputeRNEASecondOrderDerivatives per call (one Data and " \
        "four tensors reused, so they stay in cache; a batch writes 4 nv^3 numbers per sample to main " \
        "memory, kept for the next call up to a quarter of the machine's memory); forward_dynamics_second_derivatives adds M^-1 products in torch." \
        "\n\n" + "\n".join(kernels) + "\n\nTransforms, one thread, float64, B = 4096: torch.func.vmap against " \
        "the batched call (reference), and a Hessian-vector product of w . forward_dynamics(q, qd, tau) with " \
        "respect to all three (forward + backward with create_graph + double backward) against the forward " \
        "(reference).\n\n" + "\n".join(func_rows) + "\n"
    text += "\n\n" + step_section({k: v for k, v in ROBOTS.items() if k in args.robots and k != "iiwa14"})
    overhead = call_overhead()
    text += ("\n\nCall overhead: one small call, µs (best of 7 x 20000; iiwa14, float64, CPU).\n\n| call | µs |\n|---|---|\n"
             + "\n".join(f"| {call} | {us:.2f} |" for call, us in overhead) + "\n")
    shutil.rmtree(glue_cache, ignore_errors=True)
    print(text)
    stack = cuda_stack() if args.cuda else None
    if stack:
        print("\n".join(stack))
    if args.write:
        path = HERE / "RESULTS.md"
        path.write_text(updated_results(path.read_text() if path.exists() else "", text, stack))


def updated_results(results: str, cpu_section: str, stack: list[str] | None) -> str:
    """RESULTS.md with its CPU section (from its "## CPU, " heading to the next "## ") replaced by cpu_section, and,
    given the CUDA resources table, that table's rows in their section; every other section as it was (the GPU
    figures, lanes, steps and other benchmarks write their own)."""
    lines = results.splitlines(keepends=True)
    heading = next((k for k, line in enumerate(lines) if line.startswith("## CPU, ")), None)
    if heading is None:
        head = "".join(lines) or ("# Benchmark results\n\nThe CPU section and the CUDA resources table are produced by "
                                  "`python bench/bench_cpu.py --write [--cuda]`;\nthe other sections by the benchmarks they name.\n")
        lines = (head.rstrip("\n") + "\n\n" + cpu_section.rstrip("\n") + "\n").splitlines(keepends=True)
    else:
        end = next((k for k in range(heading + 1, len(lines)) if lines[k].startswith("## ")), len(lines))
        lines[heading:end] = (cpu_section.rstrip("\n") + "\n\n").splitlines(keepends=True)
    if stack:
        section = next((k for k, line in enumerate(lines) if line.startswith("## CUDA per-thread resources")), None)
        table = None if section is None else next(
            (k for k in range(section + 1, len(lines)) if lines[k].rstrip("\n") == STACK_HEADER), None)
        if table is None:
            lines += ["\n## CUDA per-thread resources, G1 humanoid (float64, sm_90)\n\n", "From `python -m torch_grid.ops.cuda_report` "
                      "(ptxas, no GPU needed): local memory a GPU reserves for every resident thread; budget 64 KiB.\n\n",
                      *(row + "\n" for row in stack)]
        else:
            end = next((k for k in range(table, len(lines)) if not lines[k].startswith("|")), len(lines))
            lines[table:end] = [row + "\n" for row in stack]
    return "".join(lines)


if __name__ == "__main__":
    main()
