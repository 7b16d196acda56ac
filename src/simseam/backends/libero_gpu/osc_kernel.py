"""robosuite's OSC_POSE substep and the Panda gripper's ramp (``control.substep``) as one Warp kernel, one thread per
world, float64: the same kernel on Warp's CPU device (NumPy arrays, CPU MuJoCo's worlds) and on CUDA (CuPy arrays,
MuJoCo Warp's worlds). The array code it replaced issued dozens of small CuPy kernels per substep (three batched
SVDs among them), 25 substeps per control step; this is one launch.

The arithmetic is ``control``'s (its module docstring says what robosuite does): the goal on a control step's
first substep, the torques from the operational-space inertias, the nullspace term, the clip, the gripper ramp.
The linear algebra is written here: the 7 x 7 joint-space inertia inverted by Gauss-Jordan elimination with
partial pivoting (numpy's ``inv`` is LU with partial pivoting: the same to float64 rounding), and the symmetric
operational-space inertias' Moore-Penrose inverses from a cyclic Jacobi eigendecomposition, with
``numpy.linalg.pinv``'s cutoff (singular values below 1e-15 of the largest dropped; for a symmetric matrix the
singular values are the eigenvalues' magnitudes). robosuite's float32 ``quat2mat`` is reproduced in float32
arithmetic.

``run_substep`` is ``control.substep``'s body: NumPy arrays on Warp's CPU device, CuPy arrays on their CUDA device
(shared through DLPack). ``WarpController`` runs the same kernel on MuJoCo Warp's data in place, between
``gather_terms`` (the reading: ``Gather``, also behind ``physics.ControllerReads.read``) and ``scatter_ctrl``, on
buffers that stay where they are: a substep is then device launches only, one captured CUDA graph.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import warp as wp

wp.set_module_options({"enable_backward": False})  # no gradients: half the generated code, shorter compiles

#: ``physics.ArmTerms``' fields (per world) in ``gather_terms``' and ``osc_substep``'s order; what a stale reading holds
TERMS = {"ee_pos": (3,), "ee_mat": (3, 3), "jac": (6, 7), "mass": (7, 7), "bias": (7,), "qpos": (7,), "qvel": (7,)}
CACHED = ("ee_pos", "ee_mat", "jac", "mass", "qpos", "qvel")

PINV_RCOND = 1e-15  # numpy.linalg.pinv's default cutoff, relative to the largest singular value
JACOBI_SWEEPS = 30  # a 6 x 6 symmetric matrix converges in well under 10

mat33d = wp.types.matrix(shape=(3, 3), dtype=wp.float64)
mat66d = wp.types.matrix(shape=(6, 6), dtype=wp.float64)
mat77d = wp.types.matrix(shape=(7, 7), dtype=wp.float64)
mat67d = wp.types.matrix(shape=(6, 7), dtype=wp.float64)
vec3d = wp.types.vector(3, wp.float64)
vec6d = wp.types.vector(6, wp.float64)
vec7d = wp.types.vector(7, wp.float64)


@wp.func
def inverse7(a: mat77d) -> mat77d:
    """Gauss-Jordan elimination with partial pivoting."""
    m = a
    r = mat77d()
    for i in range(7):
        r[i, i] = wp.float64(1.0)
    for c in range(7):
        p = c
        best = wp.abs(m[c, c])
        for k in range(c + 1, 7):
            if wp.abs(m[k, c]) > best:
                best = wp.abs(m[k, c])
                p = k
        if p != c:
            for j in range(7):
                t = m[c, j]
                m[c, j] = m[p, j]
                m[p, j] = t
                t = r[c, j]
                r[c, j] = r[p, j]
                r[p, j] = t
        piv = m[c, c]
        for j in range(7):
            m[c, j] = m[c, j] / piv
            r[c, j] = r[c, j] / piv
        for k in range(7):
            if k != c:
                f = m[k, c]
                for j in range(7):
                    m[k, j] = m[k, j] - f * m[c, j]
                    r[k, j] = r[k, j] - f * r[c, j]
    return r


@wp.func
def _off_diagonal(m: mat66d, n: int) -> wp.float64:
    off = wp.float64(0.0)
    for p in range(n):
        for q in range(p + 1, n):
            off = off + m[p, q] * m[p, q]
    return off


@wp.func
def pinv_symmetric(a: mat66d, n: int) -> mat66d:
    """The Moore-Penrose inverse of the symmetric leading ``n`` x ``n`` block of ``a`` (the rest zero), from its
    cyclic Jacobi eigendecomposition, with numpy's cutoff."""
    m = a
    v = mat66d()
    for i in range(6):
        v[i, i] = wp.float64(1.0)
    scale = wp.float64(0.0)
    for i in range(n):
        scale = scale + m[i, i] * m[i, i]
    for sweep in range(JACOBI_SWEEPS):
        if _off_diagonal(m, n) <= wp.float64(1e-36) * scale:
            break
        for p in range(n):
            for q in range(p + 1, n):
                if m[p, q] != wp.float64(0.0):
                    theta = (m[q, q] - m[p, p]) / (wp.float64(2.0) * m[p, q])
                    t = wp.float64(1.0) / (wp.abs(theta) + wp.sqrt(theta * theta + wp.float64(1.0)))
                    if theta < wp.float64(0.0):
                        t = -t
                    c = wp.float64(1.0) / wp.sqrt(t * t + wp.float64(1.0))
                    s = t * c
                    for k in range(n):
                        mkp = m[k, p]
                        mkq = m[k, q]
                        m[k, p] = c * mkp - s * mkq
                        m[k, q] = s * mkp + c * mkq
                    for k in range(n):
                        mpk = m[p, k]
                        mqk = m[q, k]
                        m[p, k] = c * mpk - s * mqk
                        m[q, k] = s * mpk + c * mqk
                    for k in range(n):
                        vkp = v[k, p]
                        vkq = v[k, q]
                        v[k, p] = c * vkp - s * vkq
                        v[k, q] = s * vkp + c * vkq
    largest = wp.float64(0.0)
    for i in range(n):
        largest = wp.max(largest, wp.abs(m[i, i]))
    out = mat66d()
    for i in range(n):
        lam = m[i, i]
        if wp.abs(lam) > wp.float64(PINV_RCOND) * largest:
            for r in range(n):
                for k in range(n):
                    out[r, k] = out[r, k] + v[r, i] * v[k, i] / lam
    return out


@wp.func
def axis_angle_matrix(r: vec3d) -> mat33d:
    """A rotation vector's matrix as robosuite turns it (``axisangle2quat``, then its numba-compiled ``quat2mat``,
    which rounds the quaternion to float32: its products and off-diagonal sums are float32, its diagonal
    ``1 - a - b`` float64); a zero vector is the identity. Against robosuite's own on 2,000 random rotations:
    equal in most, one float32 ulp (1.2e-7) apart in the rest (its float32 normalisation's rounding is not
    reproduced bit for bit)."""
    angle = wp.sqrt(wp.dot(r, r))
    q = wp.vec4f(1.0, 0.0, 0.0, 0.0)
    if angle > wp.float64(0.0):
        half = wp.float64(0.5) * angle
        s = wp.sin(half)
        q = wp.vec4f(wp.float32(wp.cos(half)), wp.float32(r[0] / angle * s), wp.float32(r[1] / angle * s),
                     wp.float32(r[2] / angle * s))
    norm = wp.float64(0.0)
    for i in range(4):
        norm = norm + wp.float64(q[i]) * wp.float64(q[i])
    k = wp.sqrt(wp.float64(2.0) / wp.float64(wp.float32(norm)))
    for i in range(4):
        q[i] = wp.float32(wp.float64(q[i]) * k)
    w, x, y, z = 0, 1, 2, 3
    q2 = wp.outer(q, q)  # float32 products
    m = mat33d()
    m[0, 0] = wp.float64(1.0) - wp.float64(q2[y, y]) - wp.float64(q2[z, z])
    m[0, 1] = wp.float64(q2[x, y] - q2[z, w])
    m[0, 2] = wp.float64(q2[x, z] + q2[y, w])
    m[1, 0] = wp.float64(q2[x, y] + q2[z, w])
    m[1, 1] = wp.float64(1.0) - wp.float64(q2[x, x]) - wp.float64(q2[z, z])
    m[1, 2] = wp.float64(q2[y, z] - q2[x, w])
    m[2, 0] = wp.float64(q2[x, z] - q2[y, w])
    m[2, 1] = wp.float64(q2[y, z] + q2[x, w])
    m[2, 2] = wp.float64(1.0) - wp.float64(q2[x, x]) - wp.float64(q2[y, y])
    return m


@wp.func
def _finite(x: wp.float64) -> int:
    if wp.isfinite(x):
        return 1
    return 0


@wp.func
def _orientation_error(desired: mat33d, current: mat33d) -> vec3d:
    """robosuite's ``orientation_error``: half the sum of the columns' cross products (current x desired)."""
    e = vec3d()
    for c in range(3):
        e = e + wp.cross(vec3d(current[0, c], current[1, c], current[2, c]),
                         vec3d(desired[0, c], desired[1, c], desired[2, c]))
    return wp.float64(0.5) * e


@wp.func
def _reading_ok(i: int, ee_pos: wp.array2d(dtype=wp.float64), ee_mat: wp.array3d(dtype=wp.float64),
                jac: wp.array3d(dtype=wp.float64), mass: wp.array3d(dtype=wp.float64),
                bias: wp.array2d(dtype=wp.float64), qpos: wp.array2d(dtype=wp.float64),
                qvel: wp.array2d(dtype=wp.float64)) -> int:
    """1 where world ``i``'s fresh reading is finite throughout, else 0."""
    ok = 1
    for a in range(3):
        ok = ok * _finite(ee_pos[i, a])
        for b in range(3):
            ok = ok * _finite(ee_mat[i, a, b])
    for a in range(7):
        ok = ok * _finite(bias[i, a]) * _finite(qpos[i, a]) * _finite(qvel[i, a])
        for b in range(6):
            ok = ok * _finite(jac[i, b, a])
        for b in range(7):
            ok = ok * _finite(mass[i, a, b])
    return ok


@wp.func
def _pick(cached: bool, stale: wp.float64, ok: int, fresh: wp.float64, neutral: wp.float64) -> wp.float64:
    """What the controller reads of one value: the stale reading's, the fresh one, or the neutral one."""
    if cached:
        return stale
    if ok == 1:
        return fresh
    return neutral


@wp.func
def _set_goal(i: int, action: wp.array2d(dtype=wp.float64), consts: wp.array2d(dtype=wp.float64), pos: vec3d,
              rot: mat33d, goal_pos: wp.array2d(dtype=wp.float64), goal_ori: wp.array3d(dtype=wp.float64)):
    """A control step's goal from the action (its first 6 slots) and the substep's pose; the orientation turns
    only where the rotation delta is not exactly zero."""
    delta = vec6d()
    for a in range(6):
        arm = wp.clamp(action[i, a], consts[2, a], consts[3, a])
        delta[a] = (arm - consts[5, a]) * consts[4, a] + consts[6, a]
    for a in range(3):
        goal_pos[i, a] = pos[a] + delta[a]
    if delta[3] != wp.float64(0.0) or delta[4] != wp.float64(0.0) or delta[5] != wp.float64(0.0):
        turned = axis_angle_matrix(vec3d(delta[3], delta[4], delta[5])) * rot
        for a in range(3):
            for b in range(3):
                goal_ori[i, a, b] = turned[a, b]


@wp.func
def _task_wrench(i: int, consts: wp.array2d(dtype=wp.float64), goal_pos: wp.array2d(dtype=wp.float64),
                 goal_ori: wp.array3d(dtype=wp.float64), pos: vec3d, rot: mat33d, vel: vec6d) -> vec6d:
    """The pose and velocity errors times kp / kd (force, then torque)."""
    g = mat33d()
    for a in range(3):
        for b in range(3):
            g[a, b] = goal_ori[i, a, b]
    err = _orientation_error(g, rot)
    out = vec6d()
    for a in range(3):
        out[a] = (goal_pos[i, a] - pos[a]) * consts[0, a] - vel[a] * consts[1, a]
        out[3 + a] = err[a] * consts[0, 3 + a] - vel[3 + a] * consts[1, 3 + a]
    return out


@wp.func
def _decoupled(full: mat66d, wrench_in: vec6d) -> vec6d:
    """The force and the torque through the position and orientation operational-space inertias."""
    upper = mat66d()
    lower = mat66d()
    for a in range(3):
        for b in range(3):
            upper[a, b] = full[a, b]
            lower[a, b] = full[3 + a, 3 + b]
    lam_pos = pinv_symmetric(upper, 3)
    lam_ori = pinv_symmetric(lower, 3)
    wrench = vec6d()
    for a in range(3):
        for b in range(3):
            wrench[a] = wrench[a] + lam_pos[a, b] * wrench_in[b]
            wrench[3 + a] = wrench[3 + a] + lam_ori[a, b] * wrench_in[3 + b]
    return wrench


@wp.func
def _gripper(i: int, action: wp.array2d(dtype=wp.float64), consts: wp.array2d(dtype=wp.float64),
             grip_speed: wp.float64, grip: wp.array2d(dtype=wp.float64), fingers_out: wp.array2d(dtype=wp.float64)):
    """The ramp state moves by [-1, +1] * speed * sign(grip action), clipped to [-1, 1]; the fingers' ctrl."""
    sign = wp.float64(0.0)  # numpy's sign (Warp's is 1 at zero)
    if action[i, 6] > wp.float64(0.0):
        sign = wp.float64(1.0)
    elif action[i, 6] < wp.float64(0.0):
        sign = wp.float64(-1.0)
    for a in range(2):
        step = wp.where(a == 0, wp.float64(-1.0), wp.float64(1.0)) * grip_speed * sign
        grip[i, a] = wp.clamp(grip[i, a] + step, wp.float64(-1.0), wp.float64(1.0))
        fingers_out[i, a] = consts[9, a] + consts[10, a] * grip[i, a]


@wp.kernel
def osc_substep(policy_step: int,
                ee_pos: wp.array2d(dtype=wp.float64), ee_mat: wp.array3d(dtype=wp.float64),
                jac: wp.array3d(dtype=wp.float64), mass: wp.array3d(dtype=wp.float64),
                bias: wp.array2d(dtype=wp.float64), qpos: wp.array2d(dtype=wp.float64),
                qvel: wp.array2d(dtype=wp.float64),
                c_mask: wp.array(dtype=wp.int32), c_ee_pos: wp.array2d(dtype=wp.float64),
                c_ee_mat: wp.array3d(dtype=wp.float64), c_jac: wp.array3d(dtype=wp.float64),
                c_mass: wp.array3d(dtype=wp.float64), c_qpos: wp.array2d(dtype=wp.float64),
                c_qvel: wp.array2d(dtype=wp.float64),
                action: wp.array2d(dtype=wp.float64), consts: wp.array2d(dtype=wp.float64),
                nullspace_kp: wp.float64, grip_speed: wp.float64,
                goal_pos: wp.array2d(dtype=wp.float64), goal_ori: wp.array3d(dtype=wp.float64),
                initial_joint: wp.array2d(dtype=wp.float64), grip: wp.array2d(dtype=wp.float64),
                tau_out: wp.array2d(dtype=wp.float64), fingers_out: wp.array2d(dtype=wp.float64)):
    """World ``i``'s substep (``control.substep``): ``consts`` rows kp, kd, input_min, input_max, scale, input_mid,
    output_mid (6 each), torque_low, torque_high (7), grip_mid, grip_half (2; rows padded with zeros); the state
    (``goal_pos``, ``goal_ori``, ``grip``) is updated in place; a world whose fresh reading is not finite reads a
    neutral state (identity inertia and orientation, zeros elsewhere) and gets zero torques; ``c_mask[i]``: the
    world reads the stale terms (``c_*``) this once, its bias forces live."""
    i = wp.tid()
    ok = _reading_ok(i, ee_pos, ee_mat, jac, mass, bias, qpos, qvel)
    cached = c_mask[i] != 0
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    pos = vec3d()
    rot = mat33d()
    jm = mat67d()
    mm = mat77d()
    q = vec7d()
    qd = vec7d()
    for a in range(3):
        pos[a] = _pick(cached, c_ee_pos[i, a], ok, ee_pos[i, a], zero)
        for b in range(3):
            rot[a, b] = _pick(cached, c_ee_mat[i, a, b], ok, ee_mat[i, a, b], wp.where(a == b, one, zero))
    for a in range(7):
        q[a] = _pick(cached, c_qpos[i, a], ok, qpos[i, a], zero)
        qd[a] = _pick(cached, c_qvel[i, a], ok, qvel[i, a], zero)
        for b in range(6):
            jm[b, a] = _pick(cached, c_jac[i, b, a], ok, jac[i, b, a], zero)
        for b in range(7):
            mm[a, b] = _pick(cached, c_mass[i, a, b], ok, mass[i, a, b], wp.where(a == b, one, zero))
    if policy_step != 0:
        _set_goal(i, action, consts, pos, rot, goal_pos, goal_ori)
    minv = inverse7(mm)
    jt = wp.transpose(jm)
    full = jm * minv * jt
    tau = jt * _decoupled(full, _task_wrench(i, consts, goal_pos, goal_ori, pos, rot, jm * qd))
    jbar_j = minv * jt * pinv_symmetric(full, 6) * jm  # the nullspace projector is I - this
    kv = wp.sqrt(nullspace_kp) * wp.float64(2.0)
    target = vec7d()
    for a in range(7):
        target[a] = nullspace_kp * (initial_joint[i, a] - q[a]) - kv * qd[a]
    pose = mm * target
    for a in range(7):
        t = tau[a] + bias[i, a]
        for j in range(7):
            t = t + (wp.where(a == j, one, zero) - jbar_j[j, a]) * pose[j]
        tau_out[i, a] = wp.where(ok == 1, wp.clamp(t, consts[7, a], consts[8, a]), zero)
    _gripper(i, action, consts, grip_speed, grip, fingers_out)
    c_mask[i] = 0  # the stale reading serves one substep


def _constants(cfg) -> np.ndarray:
    """``osc_substep``'s ``consts`` rows of ``cfg`` (float64 [11, 7])."""
    rows = np.zeros((11, 7))
    for r, key in enumerate(("kp", "kd", "input_min", "input_max", "scale", "input_mid", "output_mid")):
        rows[r, :6] = getattr(cfg, key)
    rows[7], rows[8] = cfg.torque_low, cfg.torque_high
    rows[9, :2], rows[10, :2] = cfg.grip_mid, cfg.grip_half
    return rows


def _osc_inputs(policy_step: bool, terms: list, mask: Any, cached: list, action: Any, consts: Any, cfg: Any,
                state: list, out: list) -> list:
    """``osc_substep``'s arguments in its order: the fresh terms (``TERMS`` order), the stale reading's mask and
    terms (``CACHED`` order), the actions, the constants, the state (goal_pos, goal_ori, initial_joint, grip) and
    the outputs (torques, fingers)."""
    return [int(bool(policy_step)), *terms, mask, *cached, action, consts, float(cfg.nullspace_kp),
            float(cfg.grip_speed), *state, *out]


def _to_warp(a: Any, cuda: bool) -> Any:
    """An ``xp`` array (contiguous; float64 or int32) as a Warp array sharing its memory."""
    if cuda:
        return wp.from_dlpack(a)
    return wp.array(a, dtype=wp.int32 if a.dtype == np.int32 else wp.float64, device="cpu", copy=False)


def run_substep(xp, cfg, state, terms, action, policy_step: bool):
    """``control.substep``: ``(arm torques [N, 7], finger ctrl [N, 2], state after)`` as ``xp`` arrays."""
    cuda = xp is not np
    f64 = lambda a: xp.ascontiguousarray(xp.asarray(a, dtype=xp.float64))  # noqa: E731
    n = len(action)
    fresh = [f64(getattr(terms, k)) for k in TERMS]
    if state.cached is None:
        mask = xp.zeros(n, dtype=xp.int32)
        cached = [xp.zeros((n, *TERMS[k])) for k in CACHED]
    else:
        mask = xp.ascontiguousarray(state.cached_mask.astype(xp.int32))
        cached = [f64(getattr(state.cached, k)) for k in CACHED]
    goal_pos, goal_ori, grip = f64(state.goal_pos).copy(), f64(state.goal_ori).copy(), f64(state.grip).copy()
    tau, fingers = xp.zeros((n, 7)), xp.zeros((n, 2))
    w = lambda arrays: [_to_warp(a, cuda) for a in arrays]  # noqa: E731
    if cuda:
        xp.cuda.get_current_stream().synchronize()  # what CuPy wrote, before Warp's stream reads it
    wp.launch(osc_substep, dim=n, device=f"cuda:{xp.cuda.Device().id}" if cuda else "cpu",
              inputs=_osc_inputs(policy_step, w(fresh), _to_warp(mask, cuda), w(cached), _to_warp(f64(action), cuda),
                                 _to_warp(f64(xp.asarray(_constants(cfg))), cuda), cfg,
                                 w([goal_pos, goal_ori, f64(state.initial_joint), grip]), w([tau, fingers])))
    if cuda:
        wp.synchronize_device(f"cuda:{xp.cuda.Device().id}")  # before CuPy reads what the kernel wrote
    return tau, fingers, replace(state, goal_pos=goal_pos, goal_ori=goal_ori, grip=grip, cached=None, cached_mask=None)


@wp.kernel
def gather_terms(site: int, joints: wp.array(dtype=wp.int32), qadr: wp.array(dtype=wp.int32),
                 dofs: wp.array(dtype=wp.int32), mass_csr: wp.array2d(dtype=wp.int32),
                 site_xpos: wp.array2d(dtype=wp.vec3), site_xmat: wp.array2d(dtype=wp.mat33),
                 xaxis: wp.array2d(dtype=wp.vec3), xanchor: wp.array2d(dtype=wp.vec3), m: wp.array2d(dtype=float),
                 qfrc_bias: wp.array2d(dtype=float), qpos: wp.array2d(dtype=float), qvel: wp.array2d(dtype=float),
                 ee_pos: wp.array2d(dtype=wp.float64), ee_mat: wp.array3d(dtype=wp.float64),
                 jac: wp.array3d(dtype=wp.float64), mass: wp.array3d(dtype=wp.float64),
                 bias: wp.array2d(dtype=wp.float64), q: wp.array2d(dtype=wp.float64),
                 qd: wp.array2d(dtype=wp.float64)):
    """World ``i``'s ``physics.ArmTerms`` from MuJoCo Warp's data, in float64 (what ``ControllerReads.read`` returns
    and the controller's substep reads): the site's pose, the Jacobian from the joints' axes and anchors, the arm's
    block of ``M``, the bias."""
    i = wp.tid()
    p = site_xpos[i, site]
    sp = vec3d(wp.float64(p[0]), wp.float64(p[1]), wp.float64(p[2]))
    r = site_xmat[i, site]
    for a in range(3):
        ee_pos[i, a] = sp[a]
        for b in range(3):
            ee_mat[i, a, b] = wp.float64(r[a, b])
    for k in range(7):
        j = joints[k]
        ax = xaxis[i, j]
        an = xanchor[i, j]
        axis = vec3d(wp.float64(ax[0]), wp.float64(ax[1]), wp.float64(ax[2]))
        anchor = vec3d(wp.float64(an[0]), wp.float64(an[1]), wp.float64(an[2]))
        lin = wp.cross(axis, sp - anchor)
        for a in range(3):
            jac[i, a, k] = lin[a]
            jac[i, 3 + a, k] = axis[a]
        for c in range(7):
            mass[i, k, c] = wp.float64(m[i, mass_csr[k, c]])
        bias[i, k] = wp.float64(qfrc_bias[i, dofs[k]])
        q[i, k] = wp.float64(qpos[i, qadr[k]])
        qd[i, k] = wp.float64(qvel[i, dofs[k]])


@wp.kernel
def scatter_ctrl(arm: wp.array(dtype=wp.int32), fingers: wp.array(dtype=wp.int32), tau: wp.array2d(dtype=wp.float64),
                 grip: wp.array2d(dtype=wp.float64), ctrl: wp.array2d(dtype=float)):
    """The arm's torques and the fingers' ctrl into world ``i``'s ``ctrl``."""
    i = wp.tid()
    for k in range(7):
        ctrl[i, arm[k]] = float(tau[i, k])
    for k in range(2):
        ctrl[i, fingers[k]] = float(grip[i, k])


class Gather:
    """``gather_terms`` for N worlds of MuJoCo Warp (``physics``: a ``ControllerReads``): the layout's indices on
    the device, made once; ``launch(d, out)`` fills ``out`` (float64 Warp arrays, ``TERMS`` order)."""

    def __init__(self, physics: Any):
        lay, dev = physics.layout, physics.device
        ints = lambda a: wp.array(np.asarray(a, dtype=np.int32), dtype=wp.int32, device=dev)  # noqa: E731
        self.n, self.device, self.site = physics.num_worlds, dev, int(lay.site)
        self.index = [ints(lay.joints), ints(lay.qpos), ints(lay.dofs), ints(lay.mass_csr)]

    def launch(self, d: Any, out: list) -> None:
        wp.launch(gather_terms, dim=self.n, device=self.device,
                  inputs=[self.site, *self.index, d.site_xpos, d.site_xmat, d.xaxis, d.xanchor, d.M, d.qfrc_bias,
                          d.qpos, d.qvel, *out])


def terms_buffers(n: int, device: Any) -> dict[str, Any]:
    """Float64 Warp arrays for N worlds' ``ArmTerms`` (``TERMS`` order)."""
    return {k: wp.zeros((n, *shape), dtype=wp.float64, device=device) for k, shape in TERMS.items()}


class WarpController:
    """The controller's buffers for N worlds of MuJoCo Warp (``physics``: a ``ControllerReads``), which stay where
    they are, so a substep (``step1``, ``gather_terms``, ``osc_substep``, ``scatter_ctrl``, ``step2``) can be one
    captured CUDA graph: ``load(state, action)`` before a control step, ``launch(d, policy_step)`` each substep
    (device launches only), ``state(like)`` after it."""

    def __init__(self, physics: Any, cfg: Any, facts: dict[str, Any]):
        n, dev = physics.num_worlds, physics.device
        self.cfg, self.device, self.view, self.xp, self.n = cfg, dev, physics.view, physics.xp, n
        ints = lambda a: wp.array(np.asarray(a, dtype=np.int32), dtype=wp.int32, device=dev)  # noqa: E731
        zeros = lambda *shape: wp.zeros(shape, dtype=wp.float64, device=dev)  # noqa: E731
        self.gather = Gather(physics)
        self.actuators = [ints(facts["arm_actuators"]), ints(facts["gripper_actuators"])]
        self.terms = terms_buffers(n, dev)
        self.cached = {k: zeros(n, *TERMS[k]) for k in CACHED}
        self.mask = wp.zeros(n, dtype=wp.int32, device=dev)
        self.action, self.consts = zeros(n, 7), wp.array(_constants(cfg), dtype=wp.float64, device=dev)
        self.goal_pos, self.goal_ori = zeros(n, 3), zeros(n, 3, 3)
        self.initial_joint, self.grip = zeros(n, 7), zeros(n, 2)
        self.tau, self.fingers = zeros(n, 7), zeros(n, 2)

    def load(self, state: Any, action: Any) -> None:
        """The controller's state and this control step's actions into the buffers."""
        xp, v = self.xp, self.view
        for buf, value in ((self.goal_pos, state.goal_pos), (self.goal_ori, state.goal_ori),
                           (self.initial_joint, state.initial_joint), (self.grip, state.grip), (self.action, action)):
            v(buf)[...] = xp.asarray(value, dtype=xp.float64)
        v(self.mask)[...] = 0 if state.cached is None else xp.asarray(state.cached_mask).astype(xp.int32)
        if state.cached is not None:
            for k in CACHED:
                v(self.cached[k])[...] = xp.asarray(getattr(state.cached, k), dtype=xp.float64)
        if xp is not np:
            xp.cuda.get_current_stream().synchronize()  # before Warp's stream reads them

    def launch(self, d: Any, policy_step: bool) -> None:
        """One substep's control between MuJoCo Warp's ``step1`` and ``step2`` of ``d`` (device launches only)."""
        terms = list(self.terms.values())
        self.gather.launch(d, terms)
        wp.launch(osc_substep, dim=self.n, device=self.device,
                  inputs=_osc_inputs(policy_step, terms, self.mask, [self.cached[k] for k in CACHED], self.action,
                                     self.consts, self.cfg, [self.goal_pos, self.goal_ori, self.initial_joint,
                                                             self.grip], [self.tau, self.fingers]))
        wp.launch(scatter_ctrl, dim=self.n, device=self.device,
                  inputs=[*self.actuators, self.tau, self.fingers, d.ctrl])

    def state(self, like: Any) -> Any:
        """The controller's state after the control step (copies, ``xp`` arrays), its stale reading used."""
        v = self.view
        return replace(like, goal_pos=v(self.goal_pos).copy(), goal_ori=v(self.goal_ori).copy(),
                       grip=v(self.grip).copy(), cached=None, cached_mask=None)
