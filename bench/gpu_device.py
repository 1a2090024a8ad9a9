"""The stages of bench/gpu_check.py that are about the device rather than one function: streams, CUDA
graphs, torch.compile, the examples, the local-memory reservation and budget refusal, and the calls
that compute-sanitizer and ncu watch."""
from __future__ import annotations

import os

import torch

from gpu_correctness import F64_TOL, GRAD_TOL, Checks, Skip, compare, on, states, tensors, value_calls
from gpu_figures import OPS as FIGURE_CALLS


def _cuda_only(checks: Checks, name: str, robot, device: torch.device, batch: int, seed: int):
    """(view, q, qd, x) of the robot's Pinocchio view on the device; None (the check skipped) on a CPU."""
    if device.type != "cuda":
        checks.run(name, lambda: Skip("CUDA only"))
        return None
    view = robot.pin
    return (view, *on(states(view, batch, seed)[:3], device))


def streams(checks: Checks, robot, device: torch.device) -> None:
    """A call on a side stream, and several streams at once, give the default stream's results."""
    if not (found := _cuda_only(checks, "side stream", robot, device, 4096, 4)):
        return
    view, q, qd, x = found
    ref = view.forward_dynamics_derivatives(q, qd, x)

    def side():
        stream = torch.cuda.Stream()
        stream.wait_stream(torch.cuda.current_stream())
        with torch.cuda.stream(stream):
            out = view.forward_dynamics_derivatives(q, qd, x)
        torch.cuda.current_stream().wait_stream(stream)
        return compare(out, ref, F64_TOL, device)
    checks.run("side stream", side)

    def several():
        outs, pool = [], [torch.cuda.Stream() for _ in range(4)]
        for k, stream in enumerate(pool):
            stream.wait_stream(torch.cuda.current_stream())
            with torch.cuda.stream(stream):
                outs.append(view.forward_dynamics_derivatives(q[k::4], qd[k::4], x[k::4]))
        for stream in pool:
            torch.cuda.current_stream().wait_stream(stream)
        return compare([torch.stack([o[i] for o in outs], 1).flatten(0, 1) for i in range(3)], ref, F64_TOL, device)
    checks.run("four streams", several)


def graphs(checks: Checks, robot, device: torch.device) -> None:
    """A kernel's first launch inside a capture is refused by name; after a warm-up, a captured
    forward_dynamics, rk4 step and its derivatives replay on new inputs to the eager results."""
    if device.type != "cuda":
        checks.run("graph capture", lambda: Skip("CUDA only"))
        return
    view = robot.pin
    q, qd, x, _ = on(states(view, 256, seed=5), device)

    def first_launch_refused():
        graph = torch.cuda.CUDAGraph()
        try:
            with torch.cuda.graph(graph):
                view.crba(q)
        except RuntimeError as e:
            return None if "cannot be captured" in str(e) and "crba" in str(e) else f"unexpected error: {e}"
        return "a kernel's first launch was captured without an error"
    checks.run("graph first launch refused", first_launch_refused)

    def step(a, b, c):
        return (view.forward_dynamics(a, b, c), *view.step(a, b, c, 0.01, "rk4"),
                *view.step_derivatives(a, b, c, 0.01, "rk4"))

    def replay():
        static = [t.clone() for t in (q, qd, x)]
        side = torch.cuda.Stream()
        side.wait_stream(torch.cuda.current_stream())
        with torch.cuda.stream(side):
            for _ in range(2):
                step(*static)
        torch.cuda.current_stream().wait_stream(side)
        graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(graph):
            out = step(*static)
        fresh = on(states(view, 256, seed=6)[:3], device)
        for s, t in zip(static, fresh):
            s.copy_(t)
        graph.replay()
        torch.cuda.synchronize()
        return compare(out, step(*fresh), F64_TOL, device)
    checks.run("graph capture and replay", replay)


def compiled(checks: Checks, robot, device: torch.device) -> None:
    """torch.compile(fullgraph=True) of a short rollout, forward and backward, against eager."""
    view = robot.pin
    q, qd, x, _ = on(states(view, 32, seed=7), device)

    def rollout(a, b, c):
        for _ in range(3):
            a, b = view.step(a, b, c, 0.01, "semi_implicit_euler")
        return view.forward_kinematics(a)[0].square().sum() + b.square().sum()

    def run(fn):
        leaves = [t.clone().requires_grad_(True) for t in (q, qd, x)]
        loss = fn(*leaves)
        return [loss.detach(), *torch.autograd.grad(loss, leaves)]
    torch._dynamo.reset()
    checks.run("torch.compile(fullgraph=True) rollout",
               lambda: compare(run(torch.compile(rollout, fullgraph=True)), run(rollout), GRAD_TOL, device))


def examples(checks: Checks, device: torch.device) -> None:
    """examples/ilqr.py (both tasks) and the policy rollout's training on the device equal the CPU."""
    import ilqr
    import policy_rollout

    quiet = lambda *_: None  # noqa: E731
    for task in ("reach", "balance"):
        run = getattr(ilqr, task)
        checks.run(f"examples/ilqr.py {task}", lambda run=run: compare(
            torch.tensor(run(str(device), batch=8, T=20, iterations=2, log=quiet)),
            torch.tensor(run("cpu", batch=8, T=20, iterations=2, log=quiet)), 1e-9))

    def policy(dev):
        import torch_grid

        torch.manual_seed(0)
        robot = torch_grid.load("iiwa14")
        frame, nv, batch = robot.nframes - 1, robot.nv, 16
        g = torch.Generator().manual_seed(0)
        q0 = robot.random_configuration(batch, generator=g)
        target = robot.pin.forward_kinematics(q0)[0][:, frame] + 0.2 * torch.randn(batch, 3, dtype=torch.float64, generator=g)
        net = torch.nn.Sequential(torch.nn.Linear(2 * nv + 3, 32), torch.nn.Tanh(), torch.nn.Linear(32, nv)).double()
        net = net.to(dev)
        optimizer = torch.optim.Adam(net.parameters(), lr=3e-3)
        rollout = policy_rollout.make_rollout(robot, frame, steps=10)
        losses = []
        for _ in range(3):
            optimizer.zero_grad()
            loss = rollout(net, q0.to(dev), torch.zeros(batch, nv, dtype=torch.float64, device=dev), target.to(dev))
            loss.backward()
            optimizer.step()
            losses.append(loss.detach().cpu())
        return torch.stack(losses)
    checks.run("examples/policy_rollout.py training", lambda: compare(policy(device), policy("cpu"), 1e-9))


def refusal(checks: Checks, robot, device: torch.device) -> None:
    """In a fresh process: a kernel above the local-memory budget is refused, naming the op."""
    if not (found := _cuda_only(checks, "local memory budget refusal", robot, device, 64, 8)):
        return
    view, q, qd, x = found

    def refused():
        os.environ["TORCH_GRID_CUDA_LOCAL_MEMORY_MB"] = "1"
        try:
            view.forward_dynamics_derivatives(q, qd, x)
        except RuntimeError as e:
            text = str(e)
            return None if "forward_dynamics_derivatives" in text and "TORCH_GRID_CUDA_LOCAL_MEMORY_MB" in text \
                else f"unexpected error: {text[:300]}"
        finally:
            del os.environ["TORCH_GRID_CUDA_LOCAL_MEMORY_MB"]
        return "a kernel above the budget was launched"
    checks.run("local memory budget refusal", refused)
    checks.run("the same kernel within the budget", lambda: compare(
        view.forward_dynamics_derivatives(q, qd, x), view.forward_dynamics_derivatives(*on((q, qd, x), "cpu")), F64_TOL, device))


def reservation(checks: Checks, robot, device: torch.device) -> None:
    """In a fresh process: the largest kernels' first launches succeed after torch's allocator has cached
    most of the free memory, as blocks of 1 GiB (as tensors of a program leave it) and as one block. torch
    releases only blocks wholly free: the glue empties its cache before the call's outputs are cut from a
    cached block (then a single block of all the memory would stay held), and retries a failed launch once
    after emptying it again."""
    if not (found := _cuda_only(checks, "first launch after torch cached the free memory", robot, device, 64, 8)):
        return
    view, q, qd, x = found

    def reserve(dtype, blocks):
        free, total = torch.cuda.mem_get_info()
        gib = 1 << 30
        sizes = [gib] * (free // gib - 1) if blocks else [free - gib]  # 1-2 GiB left
        hoard = [torch.empty(size, dtype=torch.uint8, device=device) for size in sizes]
        del hoard  # cached by torch's allocator, invisible to the driver
        cached = torch.cuda.memory_reserved()
        inputs = [t.to(dtype) for t in (q, qd, x)]
        try:
            out = view.step_derivatives(*inputs, 0.01, "rk4")  # the largest kernel's first launch (about 11 GB)
        except RuntimeError:
            # what torch holds then, and whether emptying its cache from Python frees it (the glue's did not)
            held, (free_now, _) = torch.cuda.memory_reserved(), torch.cuda.mem_get_info()
            torch.cuda.empty_cache()
            print(f"INFO reservation failed: torch held {held / 2**30:.1f} GiB, {free_now / 2**30:.1f} GiB free; after "
                  f"torch.cuda.empty_cache() torch holds {torch.cuda.memory_reserved() / 2**30:.1f} GiB, "
                  f"{torch.cuda.mem_get_info()[0] / 2**30:.1f} GiB free; PYTORCH_CUDA_ALLOC_CONF="
                  f"{os.environ.get('PYTORCH_CUDA_ALLOC_CONF')!r}", flush=True)
            raise
        torch.cuda.synchronize()
        after, _ = torch.cuda.mem_get_info()
        held = torch.cuda.memory_reserved()
        print(f"INFO reservation: {free / 2**30:.1f} GiB free before, torch cached {cached / 2**30:.1f} GiB; after the "
              f"first rk4 launch torch holds {held / 2**30:.1f} GiB, the device has {after / 2**30:.1f} GiB free", flush=True)
        if held >= cached:
            return "torch's cache was not emptied: the launch did not need the memory it held"
        # float32 against the float64 CPU build, loosely: this stage checks the launch, the correctness stage the values
        ref = view.step_derivatives(*on((q, qd, x), "cpu"), 0.01, "rk4")
        return compare(out, ref, F64_TOL if dtype == torch.float64 else 1e-3, device)
    # float32 first: its kernel reserves less (about half), so the float64 launch after it must grow the reservation
    checks.run("first launch of the largest float32 kernel after torch cached the free memory in one block",
               lambda: reserve(torch.float32, blocks=False))
    checks.run("first launch of the largest kernel after torch cached the free memory in 1 GiB blocks",
               lambda: reserve(torch.float64, blocks=True))


# One call of each kernel family (dynamics, derivatives, kinematics, second order, regressors, and a
# backward through autograd), for compute-sanitizer to watch within its stage's time.
SANITIZED = ("inverse_dynamics", "forward_dynamics", "minv", "frame_jacobian", "forward_dynamics_derivatives",
             "inverse_dynamics_second_derivatives", "inverse_dynamics_regressor", "coriolis_matrix")


def small_calls(robot, device: torch.device) -> None:
    """The fused step-derivative kernels first (each scheme, both conventions, float64 and float32; the
    MuJoCo convention's gave NaN on a GPU), then one small call of each kernel family and two backward
    passes, for compute-sanitizer to watch."""
    from gpu_probe import fused

    calls = value_calls(robot)
    for conv, view in (("mujoco", robot.mujoco), ("pin", robot.pin)):
        for dtype in (torch.float64, torch.float32):
            q, qd, x, _ = on(states(view, 2, seed=9), device, dtype)
            for scheme in ("semi_implicit_euler", "midpoint", "rk4"):
                _calling(conv, dtype, f"fused step_derivatives[{scheme}]")
                tensors(fused(view, scheme, q, qd, x, 0.01))
        inputs = on(states(view, 2, seed=9), device)
        for name in SANITIZED:
            if name in calls:
                _calling(conv, torch.float64, name)
                tensors(calls[name](view, *inputs))
        leaves = [t.clone().requires_grad_(True) for t in inputs]
        for name in ("crba", "frame_jacobian"):
            _calling(conv, torch.float64, f"{name} and its backward")
            out = tensors(calls[name](view, *leaves))
            torch.autograd.grad(out, leaves, [torch.ones_like(o) for o in out], allow_unused=True)
    if device.type == "cuda":
        torch.cuda.synchronize()


def _calling(conv: str, dtype: torch.dtype, what: str) -> None:
    """A line naming the call about to run, so that a stage a tool slows past its time limit shows how far it got (a
    launch is asynchronous: the device may still run an earlier call's kernel when the call named last began)."""
    print(f"CALL {conv} {str(dtype).replace('torch.', '')} {what}", flush=True)


def team_calls(robot, device: torch.device) -> None:
    """Two samples of each op with a team path (gpu_correctness.TEAM_CALLS), both conventions, float64 and float32,
    for compute-sanitizer's racecheck to watch the shared workspace (the stage runs with TORCH_GRID_CUDA_TEAMS=1)."""
    from gpu_correctness import TEAM_CALLS, _inertial_parameters

    for conv, view in (("mujoco", robot.mujoco), ("pin", robot.pin)):
        for dtype in (torch.float64, torch.float32):
            inputs = on((*states(view, 2, seed=9), _inertial_parameters(robot)[:2]), device, dtype)
            for name, call in TEAM_CALLS.items():
                _calling(conv, dtype, name)
                tensors(call(view, *inputs))
    if device.type == "cuda":
        torch.cuda.synchronize()


def profiled_call(robot, device: torch.device) -> None:
    """Two calls of forward_dynamics_derivatives at N = 65536 (ncu profiles the second)."""
    view = robot.pin
    q, qd, x, _ = on(states(view, 65536, seed=10), device)
    for _ in range(2):
        view.forward_dynamics_derivatives(q, qd, x)
    torch.cuda.synchronize()


# Kernels ncu reads section by section (throughput against the device's peaks, the memory hierarchy's traffic,
# why warps stall, occupancy), the measurements GPU kernels that cooperate within a sample are designed from:
# (robot, op, N), a light op and a derivative, a small and a full batch, a 7-dof arm and the humanoid, and
# go2's fused semi-implicit step_derivatives and G1's inverse_dynamics (N = 256), minv and
# forward_dynamics_derivatives, one warp a sample beside one thread a sample, and G1's
# inverse_dynamics_second_derivatives one warp a sample (op: a name of gpu_figures.OPS).
PROFILED = (("iiwa14", "inverse_dynamics", 65536), ("iiwa14", "forward_dynamics_derivatives", 256),
            ("iiwa14", "forward_dynamics_derivatives", 65536), ("g1", "inverse_dynamics", 256),
            ("g1", "forward_dynamics_derivatives", 65536), ("go2", "step_derivatives[semi_implicit_euler]", 65536),
            ("g1", "minv", 65536), ("g1", "minv[teams]", 65536), ("g1", "forward_dynamics_derivatives[teams]", 65536),
            ("g1", "inverse_dynamics_second_derivatives[teams]", 1024), ("g1", "inverse_dynamics[teams]", 256),
            ("go2", "step_derivatives[semi_implicit_euler][teams]", 65536))
NCU_SECTIONS = ("LaunchStats", "Occupancy", "SpeedOfLight", "ComputeWorkloadAnalysis", "MemoryWorkloadAnalysis",
                "WarpStateStats", "SchedulerStats")


def profiled_calls(robots: dict, device: torch.device) -> None:
    """One call of each PROFILED kernel in turn, each named on a line before it (ncu reports the kernels in the
    order they ran); on the CPU, 4 samples each."""
    for k, (name, op, n) in enumerate(PROFILED):
        view = robots[name].pin
        q, qd, x, _ = on(states(view, n if device.type == "cuda" else 4, seed=10), device)
        print(f"PROFILED {k + 1}: {name} {op}, N = {n}", flush=True)
        FIGURE_CALLS[op](view, q, qd, x)
        if device.type == "cuda":
            torch.cuda.synchronize()
