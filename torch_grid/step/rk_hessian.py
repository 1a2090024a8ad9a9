"""The Hessian of the Runge-Kutta steps, by the second-order chain rule through the stages.

Every stage quantity y(z), z = [dq; dqd; dtau], is carried as its value, Jacobian dy (..., n, 3 nv) and
Hessian Hy (..., n, 3 nv, 3 nv) at z = 0 (integrators.py names the stages):
  theta_i = sum_j a_ij c_j,  v_i = qd + dqd + dt sum_j a_ij acc_j                  (linear)
  e_i = difference(q_i, (q (+) dq) (+) dt theta_i(z))       the stage's configuration in its own chart,
                                                            euler_hessian.chart_jacobian / chart_hessian
  acc_i = FD(q_i (+) e_i, v_i, tau + dtau):   dacc = G dx,  Hacc = dx^T Ha dx + G Hx,  x = [e_i; v_i; tau]
                                              (G, Ha: forward_dynamics' gradient and Hessian at stage i)
  c_i = dexp(dt theta_i)^-1 v_i               (at quaternion joints: its own Hessian in (dt theta_i, v_i),
                                               by forward-mode AD of the joint's closed form, the turn
                                               the short way round in MuJoCo's convention; else v_i)
and the step's rows: q' in its chart as e with theta = sum_j b_j c_j, qd' = qd + dqd + dt sum_j b_j acc_j.
The samples go in pieces: a Hessian is nv (3 nv)^2 numbers per sample, and a stage holds a dozen.
"""
from __future__ import annotations

import torch

from ..space.lie import apply_matrix, carry_block, d_integrate_blocks, dexp_inverse
from .euler_hessian import chart_hessian, chart_jacobian, jacobian_of_j_r, scaled_acceleration_hessian

# Bytes of one Hessian of a piece of the batch (at least one sample): a stage holds a dozen, which at this
# size reuse the heap's blocks (larger ones are mapped afresh, and zeroed, on every call: go2 1.3x slower).
PIECE_BYTES = 4 << 20


def rk_step_hessian(view, tableau, q, qd, tau, h, f_ext) -> torch.Tensor:
    """(n, 2 nv, 3 nv, 3 nv): step_second_derivatives of the scheme (a rows, b) over a flat batch: q (n, nq),
    qd, tau (n, nv), h (n,), f_ext (n, nbodies, 6) or None; the view's inertial parameters (n, nbodies, 10) or None."""
    space, convention = view._robot._space, view._convention
    rows, weights = tableau
    nv, n = qd.shape[-1], qd.shape[0]
    if n == 0:
        return qd.new_empty(0, 2 * nv, 3 * nv, 3 * nv)
    h1 = h[:, None]
    # the stages' values, then each quaternion joint's closed-form derivatives at all of them in one call
    # (forward-mode AD of a few dozen small ops, whose cost is per call)
    c, acc, stages = [qd], [view.forward_dynamics(q, qd, tau, f_ext)], []
    for row in rows:
        theta, v = combine(row, c), qd + h1 * combine(row, acc)
        qi = view.integrate(q, h1 * theta)
        stages.append((qi, v))
        acc.append(view.forward_dynamics(qi, v, tau, f_ext))
        c.append(dexp_inverse(space, h1 * theta, v, convention))
    w = torch.stack([h1 * combine(row, c) for row in rows] + [h1 * combine(weights, c)])  # (stages + 1, n, nv)
    vs = torch.stack([v for _, v in stages])
    jets = []  # per quaternion joint: (vi, k, the carried velocity's (K, J) per stage, dJ_r per chart)
    for kind, vi in zip(space.kinds, space.vi):
        if kind == "scalar":
            continue
        k = 6 if kind == "free" else 3
        r = slice(vi, vi + k)
        def jacobian(y, kind=kind, k=k):
            """J = dc/dy of c = dexp(u)^-1 x, y = [u; x], returned twice: jacfwd's output and its aux."""
            J = torch.func.jacfwd(lambda y: apply_matrix(carry_block(kind, y[:k], convention), y[k:]))(y)
            return J, J

        y = torch.cat([w[:-1, :, r], vs[..., r]], dim=-1).flatten(0, 1)
        K, J = torch.func.vmap(torch.func.jacfwd(jacobian, has_aux=True))(y)
        dJ = jacobian_of_j_r(kind, w[..., r].flatten(0, 1), convention)
        jets.append((vi, k, K.unflatten(0, (len(rows), n)), J.unflatten(0, (len(rows), n)),
                     dJ.unflatten(0, (len(rows) + 1, n))))
    out = torch.empty(n, 2 * nv, 3 * nv, 3 * nv, dtype=qd.dtype, device=qd.device)
    step = min(n, max(1, PIECE_BYTES // (8 * nv * (3 * nv) ** 2)))
    # the pieces' Hessians, in buffers all pieces share: 3 temporaries, each stage's acceleration and carried
    # velocity (the first's is qd, without one)
    pool = torch.empty(2 * len(weights) + 2, step, nv, 3 * nv, 3 * nv, dtype=qd.dtype, device=qd.device)
    params = view._params  # one set per sample (integrators._flattened) or None: each piece takes its own
    for s in range(0, n, step):
        p = slice(s, s + step)
        piece = view if params is None else view._with(params[p], "step_second_derivatives")
        _hessian(piece, tableau, q[p], qd[p], tau[p], h[p], None if f_ext is None else f_ext[p],
                 [(qi[p], v[p]) for qi, v in stages], w[:, p], [(vi, k, K[:, p], J[:, p], dJ[:, p])
                                                             for vi, k, K, J, dJ in jets],
                 pool[:, :out[p].shape[0]], out[p])
    return out


def _hessian(view, tableau, q, qd, tau, h, f_ext, stages, w, jets, pool, out):
    """One piece: the stages' (q_i, v_i), w (stages + 1, n, nv) = dt theta at each stage and for the step."""
    space, convention = view._robot._space, view._convention
    rows, weights = tableau
    n, nv = qd.shape
    N = 3 * nv
    h2, h3 = h[:, None, None], h[:, None, None, None]
    eye = torch.eye(nv, dtype=qd.dtype, device=qd.device)
    zero = torch.zeros_like(eye)
    e_v = torch.cat([zero, eye, zero], dim=-1).expand(n, nv, N)
    e_tau = torch.cat([zero, zero, eye], dim=-1).expand(n, nv, N)

    temp, X, Hu = pool[0], pool[1], pool[2]
    stage_acc, stage_c = pool[3:3 + len(weights)], pool[3 + len(weights):]

    def acceleration(i, qi, vi, dx=None, He=None, Hv=None):
        """dacc_i, Hacc_i from x = [e; v]'s Jacobian dx (n, 2 nv, N) and Hessians; none: x = z."""
        G = torch.cat(view.forward_dynamics_derivatives(qi, vi, tau, f_ext), dim=-1)
        Ha = temp if dx is not None else stage_acc[i]
        scaled_acceleration_hessian(view.forward_dynamics_second_derivatives(qi, vi, tau, f_ext), h3.new_ones(()), Ha)
        if dx is None:
            return G, Ha
        # dx^T Ha dx per output row, with the rows of x = [e; v; tau] dx = [P; E] (E = [0 0 I]) and Ha
        # symmetric, zero on (v, tau) and (tau, tau): T = Ha [P; E] takes Ha's first 2 nv columns times P
        # plus its tau columns, and dx^T Ha dx = T^T dx = T[:2 nv]^T P plus T[tau]^T on the tau columns
        P, M = dx, 2 * nv
        T = torch.bmm(Ha.view(n, nv * N, N)[..., :M], P, out=X.view(n, nv * N, N)).view(n, nv, N, N)
        T[..., M:] += Ha[..., M:]
        Pm = temp.view(-1)[:n * nv * M * N].view(n * nv, M, N).copy_(P.unsqueeze(1).expand(n, nv, M, N).flatten(0, 1))
        Ha = torch.bmm(T[:, :, :M].flatten(0, 1).mT, Pm, out=stage_acc[i].view(n * nv, N, N)).view(n, nv, N, N)
        Ha[..., M:] += T[:, :, M:].mT
        # then G_e He + G_v Hv
        Ha = Ha.view(n, nv, N * N)
        Ha.baddbmm_(G[..., :nv], He.view(n, nv, N * N)).baddbmm_(G[..., nv:M], Hv.view(n, nv, N * N))
        return G @ torch.cat([P, e_tau], dim=-2), stage_acc[i]

    def chart(i, dtheta, He):
        """e's Jacobian at stage i (the step's at i = stages); He, dt theta's Hessian, becomes e's."""
        dw = h2 * dtheta
        blocks = d_integrate_blocks(space, w[i], 1.0, convention)
        chart_hessian(convention, blocks, w[i], dw, He, [jet[-1][i] for jet in jets])
        return chart_jacobian(blocks, dw)

    da0, Ha0 = acceleration(0, q, qd)
    dc, Hc = [e_v], [None]  # c_0 = qd
    dacc, Hacc = [da0], [Ha0]
    for i, row in enumerate(rows):
        dtheta, dv = combine(row, dc), e_v + h2 * combine(row, dacc)
        Hu, Hv = _scaled_sum(h3, row, Hc, Hu), _scaled_sum(h3, row, Hacc, stage_c[i])
        # the carried velocity c_i = dexp(u)^-1 v_i, u = dt theta_i, from u's and v's derivatives (before
        # chart overwrites Hu); Hv becomes Hc, unchanged off the quaternion joints
        dci = dv.clone()
        Hy = {vi: torch.cat([Hu[:, vi:vi + k], Hv[:, vi:vi + k]], dim=-3) for vi, k, *_ in jets}
        de = chart(i, dtheta, Hu)
        da, Ha = acceleration(i + 1, *stages[i], torch.cat([de, dv], dim=-2), Hu, Hv)
        for vi, k, K, J, _ in jets:
            r = slice(vi, vi + k)
            dy = torch.cat([h2 * dtheta[:, r], dv[:, r]], dim=-2)
            dci[:, r] = J[i] @ dy
            Hv[:, r] = (torch.einsum("...mpr,...pa,...rc->...mac", K[i], dy, dy)
                        + torch.einsum("...mp,...pac->...mac", J[i], Hy[vi]))
        dc.append(dci), Hc.append(Hv), dacc.append(da), Hacc.append(Ha)
    _scaled_sum(h3, weights, Hc, out[:, :nv])
    chart(len(rows), combine(weights, dc), out[:, :nv])
    _scaled_sum(h3, weights, Hacc, out[:, nv:])


def combine(coefficients, xs):
    """sum_j c_j x_j over the non-zero coefficients."""
    terms = [c * x for c, x in zip(coefficients, xs) if c]
    return sum(terms[1:], terms[0])


def _scaled_sum(h: torch.Tensor, coefficients, xs, out: torch.Tensor) -> torch.Tensor:
    """out = h sum_j c_j x_j over the non-zero coefficients and the x_j not None (zero if none)."""
    terms = [(c, x) for c, x in zip(coefficients, xs) if c and x is not None]
    if not terms:
        return out.zero_()
    torch.mul(terms[0][1], terms[0][0] * h, out=out)
    for c, x in terms[1:]:
        out.addcmul_(x, c * h)
    return out
