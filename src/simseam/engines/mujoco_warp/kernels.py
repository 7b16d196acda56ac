"""Warp kernels of the batched scene: one thread per world, no per-world Python loop.

They mirror the scene's host code line by line (float32 on the device):

- ``make_arm_kernel``: ``CartesianDeltaArm.targets`` + ``SerialChain.forward/solve`` (one damped
  least-squares Newton step, joint-limit blocking re-solve, null-space pull to home, re-anchoring
  on the measured pose, joint speed limit) and ``JointPositionArm``; then the gripper mapping;
- ``servo_kernel``: the smoothstep ramp of the servo setpoints (``ManifestScene._servo``);
- ``make_observe_kernel``: the tool pose (world and base frame), the state vector (``Task.state``) and
  the joints: the robot's part of the observation (a task's own reads are batched array code,
  ``simseam.scene.tasks.batch``, run on views of the physics state);
- ``contact_pair_kernel``: ``contacts_between(a, b)`` over the batch's contacts;
- row scatters for per-world resets and the RGB unpacking of MuJoCo Warp's renderer.
"""


import warp as wp

# no per-module load lines on the console (set before any kernel loads; warp >= 1.19 reads log_level)
wp.config.quiet = True
if hasattr(wp, "LOG_WARNING"):
    wp.config.log_level = wp.LOG_WARNING


# ------------------------------------------------------------------------------------------ rotations
@wp.func
def skew_vee(m: wp.mat33) -> wp.vec3:
    return wp.vec3(m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1])


@wp.func
def mat_to_quat_wxyz(m: wp.mat33) -> wp.vec4:
    """``math3d.matrix_to_quat``: [w, x, y, z], w >= 0."""
    t = m[0, 0] + m[1, 1] + m[2, 2]
    q = wp.vec4(0.0)
    if t > 0.0:
        s = 2.0 * wp.sqrt(t + 1.0)
        q = wp.vec4(0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s)
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * wp.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = wp.vec4((m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s)
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * wp.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = wp.vec4((m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s)
    else:
        s = 2.0 * wp.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = wp.vec4((m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s)
    q = wp.normalize(q)
    if q[0] < 0.0:
        q = -q
    return q


@wp.func
def quat_wxyz_to_axis_angle(q: wp.vec4) -> wp.vec3:
    """``math3d.quat_to_axis_angle``."""
    w = wp.clamp(q[0], -1.0, 1.0)
    den = wp.sqrt(wp.max(1.0 - w * w, 0.0))
    if den < 1e-9:
        return wp.vec3(0.0)
    return wp.vec3(q[1], q[2], q[3]) * (2.0 * wp.acos(w) / den)


@wp.func
def mat_to_axis_angle(m: wp.mat33, reference: wp.vec4) -> wp.vec3:
    """``math3d.matrix_to_axis_angle``: the quaternion's sign follows ``reference``."""
    q = mat_to_quat_wxyz(m)
    if wp.dot(q, reference) < 0.0:
        q = -q
    return quat_wxyz_to_axis_angle(q)


@wp.func
def rotation_error(target: wp.mat33, current: wp.mat33) -> wp.vec3:
    """``math3d.rotation_error``: rotation vector taking ``current`` to ``target``."""
    m = target * wp.transpose(current)
    v = skew_vee(m)
    c = wp.clamp((m[0, 0] + m[1, 1] + m[2, 2] - 1.0) * 0.5, -1.0, 1.0)
    if c > 0.999:
        return 0.5 * v
    if c > -0.99:
        angle = wp.acos(c)
        return v * (angle / (2.0 * wp.sin(angle)))
    return quat_wxyz_to_axis_angle(mat_to_quat_wxyz(m))


@wp.func
def axis_angle_to_mat(v: wp.vec3) -> wp.mat33:
    """``math3d.axis_angle_to_matrix`` (Rodrigues)."""
    th = wp.length(v)
    if th < 1e-12:
        return wp.identity(n=3, dtype=float)
    k = v / th
    x = k[0]
    y = k[1]
    z = k[2]
    s = wp.sin(th)
    c = 1.0 - wp.cos(th)
    return wp.mat33(1.0 + c * (x * x - 1.0), c * x * y - s * z, c * x * z + s * y,
                    c * x * y + s * z, 1.0 + c * (y * y - 1.0), c * y * z - s * x,
                    c * x * z - s * y, c * y * z + s * x, 1.0 + c * (z * z - 1.0))


@wp.func
def axis_rotation(axis: wp.vec3, angle: float) -> wp.mat33:
    """Rotation by ``angle`` about the unit ``axis`` (I + s K + (1 - c) K^2, as ``SerialChain``)."""
    kx = wp.mat33(0.0, -axis[2], axis[1], axis[2], 0.0, -axis[0], -axis[1], axis[0], 0.0)
    return wp.identity(n=3, dtype=float) + wp.sin(angle) * kx + (1.0 - wp.cos(angle)) * (kx * kx)


@wp.func
def solve66(a: wp.spatial_matrix, b: wp.spatial_vector) -> wp.spatial_vector:
    """Solve a symmetric positive definite 6x6 system (Cholesky, unrolled)."""
    l = wp.spatial_matrix()
    for i in range(6):
        for j in range(i + 1):
            s = a[i, j]
            for k in range(j):
                s -= l[i, k] * l[j, k]
            if i == j:
                l[i, j] = wp.sqrt(wp.max(s, 1e-20))
            else:
                l[i, j] = s / l[j, j]
    y = wp.spatial_vector()
    for i in range(6):
        s = b[i]
        for k in range(i):
            s -= l[i, k] * y[k]
        y[i] = s / l[i, i]
    x = wp.spatial_vector()
    for ii in range(6):
        i = 5 - ii
        s = y[i]
        for k in range(i + 1, 6):
            s -= l[k, i] * x[k]
        x[i] = s / l[i, i]
    return x


# ------------------------------------------------------------------------------------------ arm + grip
def _dls_step_func(n: int, null_space: bool):
    """``SerialChain._normal_solve`` for an arm of ``n`` joints (a Warp function)."""
    vecn = wp.types.vector(length=n, dtype=float)
    jac_t = wp.types.matrix(shape=(6, n), dtype=float)

    @wp.func
    def dls_step(jw: jac_t, e: wp.spatial_vector, zn: vecn, damping: float):
        """``SerialChain._normal_solve``: damped least squares for ``e``, plus ``zn`` in the null space."""
        a66 = wp.spatial_matrix()
        for r in range(6):
            for c in range(6):
                s = float(0.0)
                for i in range(n):
                    s += jw[r, i] * jw[c, i]
                a66[r, c] = s
            a66[r, r] = a66[r, r] + damping * damping
        sol0 = solve66(a66, e)
        dq = vecn()
        for i in range(n):
            s = float(0.0)
            for r in range(6):
                s += jw[r, i] * sol0[r]
            dq[i] = s
        if wp.static(null_space):
            jz = wp.spatial_vector()
            for r in range(6):
                s = float(0.0)
                for i in range(n):
                    s += jw[r, i] * zn[i]
                jz[r] = s
            sol1 = solve66(a66, jz)
            for i in range(n):
                s = float(0.0)
                for r in range(6):
                    s += jw[r, i] * sol1[r]
                dq[i] = dq[i] + zn[i] - s
        return dq

    return dls_step


def _priority_step_func(n: int):
    """``SerialChain._priority_step`` for an arm of ``n`` (< 6) joints (a Warp function)."""
    jac_t = wp.types.matrix(shape=(6, n), dtype=float)
    vecn = wp.types.vector(length=n, dtype=float)
    f64 = wp.float64
    jp_t = wp.types.matrix(shape=(3, n), dtype=f64)
    matnn = wp.types.matrix(shape=(n, n), dtype=f64)

    @wp.func
    def priority_step(jw: jac_t, e: wp.spatial_vector, damping: float):
        """``SerialChain._priority_step`` (arms with fewer than 6 joints): position first, orientation
        within the position task's null space. The projector uses the exact pseudo-inverse of the
        position Jacobian (singular values below 1e-4 of the largest dropped, as numpy's pinv),
        through the eigen-decomposition of jp jp^T: in float64, which squares the condition number."""
        jp = jp_t()
        jo = jp_t()
        for r in range(3):
            for i in range(n):
                jp[r, i] = f64(jw[r, i])
                jo[r, i] = f64(jw[3 + r, i])
        d2 = f64(damping) * f64(damping)
        eye = wp.identity(n=3, dtype=f64)
        m = jp * wp.transpose(jp)
        ep = wp.vec3d(f64(e[0]), f64(e[1]), f64(e[2]))
        dq1 = wp.transpose(jp) * (wp.inverse(m + d2 * eye) * ep)
        qm, lam = wp.eig3(m)
        smax = wp.sqrt(wp.max(wp.max(lam[0], lam[1]), wp.max(lam[2], f64(0.0))))
        inv = wp.mat33d()
        for k in range(3):
            sk = wp.sqrt(wp.max(lam[k], f64(0.0)))
            if sk > f64(1e-4) * smax and sk > f64(0.0):
                for a in range(3):
                    for b in range(3):
                        inv[a, b] = inv[a, b] + qm[a, k] * qm[b, k] / lam[k]
        pinv_jp = wp.transpose(jp) * inv  # n x 3
        null = matnn()
        for i in range(n):
            for j in range(n):
                s = f64(0.0)
                for r in range(3):
                    s += pinv_jp[i, r] * jp[r, j]
                one = f64(0.0)
                if i == j:
                    one = f64(1.0)
                null[i, j] = one - s
        jo_n = jo * null  # 3 x n
        eo = wp.vec3d(f64(e[3]), f64(e[4]), f64(e[5])) - jo * dq1
        dq2 = wp.transpose(jo_n) * (wp.inverse(jo_n * wp.transpose(jo_n) + d2 * eye) * eo)
        dq64 = dq1 + null * dq2
        dq = vecn()
        for i in range(n):
            dq[i] = float(dq64[i])
        return dq

    return priority_step


def _ik_step_func(n: int, null_space: bool):
    """One damped least-squares step of ``n`` joints: the full 6-D solve from 6 joints on, the
    task-priority step below (``SerialChain``'s choice)."""
    vecn = wp.types.vector(length=n, dtype=float)
    jac_t = wp.types.matrix(shape=(6, n), dtype=float)
    dls_step = _dls_step_func(n, null_space)
    priority_step = _priority_step_func(n)

    @wp.func
    def step_fn(jw: jac_t, e: wp.spatial_vector, zn: vecn, damping: float):
        if wp.static(n >= 6):
            return dls_step(jw, e, zn, damping)
        else:
            return priority_step(jw, e, damping)

    return step_fn


def _chain_func(n: int):
    """``SerialChain.forward`` at ``q``: the tool pose and the geometric Jacobian (angular rows weighted)."""
    vecn = wp.types.vector(length=n, dtype=float)
    jac_t = wp.types.matrix(shape=(6, n), dtype=float)
    mat_n3 = wp.types.matrix(shape=(n, 3), dtype=float)

    @wp.func
    def chain_forward(q: vecn, chain_q: wp.array[int], fixed: wp.array[wp.mat44], axes: wp.array[wp.vec3],
                      prismatic: wp.array[int], tail: wp.mat44, rot_weight: float):
        cum = wp.identity(n=4, dtype=float)
        origins = mat_n3()
        zs = mat_n3()
        for k in range(n):
            qk = q[chain_q[k]]
            motion = wp.identity(n=4, dtype=float)
            ax = axes[k]
            if prismatic[k] == 0:
                rk = axis_rotation(ax, qk)
                for a in range(3):
                    for b in range(3):
                        motion[a, b] = rk[a, b]
            else:
                for a in range(3):
                    motion[a, 3] = ax[a] * qk
            cum = cum * fixed[k] * motion
            rot_k = wp.mat33(cum[0, 0], cum[0, 1], cum[0, 2], cum[1, 0], cum[1, 1], cum[1, 2],
                             cum[2, 0], cum[2, 1], cum[2, 2])
            z = rot_k * ax
            for a in range(3):
                origins[k, a] = cum[a, 3]
                zs[k, a] = z[a]
        tip = cum * tail
        t_pos = wp.vec3(tip[0, 3], tip[1, 3], tip[2, 3])
        t_rot = wp.mat33(tip[0, 0], tip[0, 1], tip[0, 2], tip[1, 0], tip[1, 1], tip[1, 2],
                         tip[2, 0], tip[2, 1], tip[2, 2])
        jw = jac_t()
        for k in range(n):
            z = wp.vec3(zs[k, 0], zs[k, 1], zs[k, 2])
            lin = z
            ang = wp.vec3(0.0)
            if prismatic[k] == 0:
                lin = wp.cross(z, t_pos - wp.vec3(origins[k, 0], origins[k, 1], origins[k, 2]))
                ang = z
            col = chain_q[k]
            for a in range(3):
                jw[a, col] = lin[a]
                jw[3 + a, col] = ang[a] * rot_weight
        return t_pos, t_rot, jw

    return chain_forward


def _cartesian_func(n: int, null_space: bool):
    """``CartesianDeltaArm.targets`` for one world: the new end-effector target from the action (re-anchored
    on the measured pose at an episode's first step, or when the arm does not track its command), then
    ``SerialChain.solve``'s one IK step from the last joint targets ``q_prev``; a joint the step would push
    past a limit goes to it and the others solve for what is left (``_step_blocked``). Returns the joint
    targets; updates the reference."""
    vecn = wp.types.vector(length=n, dtype=float)
    chain_forward = _chain_func(n)
    step_fn = _ik_step_func(n, null_space)

    @wp.func
    def cartesian_targets(w: int, q_prev: vecn, action: wp.array2d[float], eef_pos: wp.array[wp.vec3],
                          eef_rot: wp.array[wp.mat33], ref_pos: wp.array[wp.vec3], ref_rot: wp.array[wp.mat33],
                          ref_ok: wp.array[int], chain_q: wp.array[int], fixed: wp.array[wp.mat44],
                          axes: wp.array[wp.vec3], prismatic: wp.array[int], tail: wp.mat44, lower: wp.array[float],
                          upper: wp.array[float], q_home: wp.array[float], max_t: float, max_r: float,
                          rot_weight: float, damping: float, rest_gain: float, reanchor_pos: float,
                          reanchor_rot: float):
        t_pos, t_rot, jw = chain_forward(q_prev, chain_q, fixed, axes, prismatic, tail, rot_weight)
        rp = ref_pos[w]
        rr = ref_rot[w]
        if ref_ok[w] == 0 or wp.length(t_pos - eef_pos[w]) > reanchor_pos or \
                wp.length(rotation_error(t_rot, eef_rot[w])) > reanchor_rot:
            rp = eef_pos[w]
            rr = eef_rot[w]
        tgt_pos = rp + wp.vec3(action[w, 0], action[w, 1], action[w, 2]) * max_t
        tgt_rot = axis_angle_to_mat(wp.vec3(action[w, 3], action[w, 4], action[w, 5]) * max_r) * rr
        ref_pos[w] = tgt_pos
        ref_rot[w] = tgt_rot
        ref_ok[w] = 1
        q = vecn()
        for i in range(n):
            q[i] = wp.clamp(q_prev[i], lower[i], upper[i])
        e_pos = tgt_pos - t_pos
        e_rot = rotation_error(tgt_rot, t_rot)
        if wp.length(e_pos) < 2e-4 and wp.length(e_rot) < 2e-3:
            return q
        e = wp.spatial_vector(e_pos[0], e_pos[1], e_pos[2], e_rot[0] * rot_weight, e_rot[1] * rot_weight,
                              e_rot[2] * rot_weight)
        zn = vecn()
        if wp.static(null_space):
            for i in range(n):
                zn[i] = rest_gain * (q_home[i] - q[i])
        dq = step_fn(jw, e, zn, damping)
        blocked = vecn()
        any_blocked = int(0)
        for i in range(n):
            v = q[i] + dq[i]
            if (v < lower[i] and dq[i] < 0.0) or (v > upper[i] and dq[i] > 0.0):
                blocked[i] = 1.0
                any_blocked = 1
        if any_blocked == 1:  # blocked joints go to their limit; the rest solve for what is left
            dqb = vecn()
            for i in range(n):
                if blocked[i] > 0.0:
                    dqb[i] = wp.clamp(q[i] + dq[i], lower[i], upper[i]) - q[i]
                    for r in range(6):
                        e[r] = e[r] - jw[r, i] * dqb[i]
                        jw[r, i] = 0.0
                    zn[i] = 0.0
            dq = step_fn(jw, e, zn, damping)
            for i in range(n):
                if blocked[i] > 0.0:
                    dq[i] = dqb[i]
        q_new = vecn()
        for i in range(n):
            q_new[i] = wp.clamp(q[i] + dq[i], lower[i], upper[i])
        return q_new

    return cartesian_targets


def make_arm_kernel(n: int, cartesian: bool, null_space: bool, any_prismatic: bool):
    """The controller kernel for an arm of ``n`` joints (``cartesian``: CARTESIAN_DELTA, else
    JOINT_POSITION): ``CartesianDeltaArm.targets`` (``_cartesian_func``) or the joint targets themselves,
    the joint speed limit, then the gripper mapping. ``null_space``: the arm is redundant (n > 6), pull
    towards home. ``any_prismatic`` is part of the kernel's identity (the chain reads ``prismatic``)."""
    vecn = wp.types.vector(length=n, dtype=float)
    cartesian_targets = _cartesian_func(n, null_space) if cartesian else None

    @wp.kernel(module="unique", enable_backward=False)
    def arm_kernel(
        action: wp.array2d[float],  # (nworld, action_dim): already clipped to the slot bounds
        target: wp.array2d[float],  # (nworld, n_engine_joints): in: last targets; out: new targets
        eef_pos: wp.array[wp.vec3],  # measured tool pose, base frame
        eef_rot: wp.array[wp.mat33],
        ref_pos: wp.array[wp.vec3],  # in/out: the previous end-effector target
        ref_rot: wp.array[wp.mat33],
        ref_ok: wp.array[int],  # in/out: 0 at the first step of an episode
        arm_idx: wp.array[int],  # arm joints' indices in the engine joints
        chain_q: wp.array[int],  # chain joint k uses arm joint chain_q[k]
        fixed: wp.array[wp.mat44],  # constant transform before each chain joint
        axes: wp.array[wp.vec3],
        prismatic: wp.array[int],
        tail: wp.mat44,
        lower: wp.array[float],
        upper: wp.array[float],
        max_step: wp.array[float],
        q_home: wp.array[float],
        grip_idx: wp.array[int],
        grip_open: wp.array[float],
        grip_closed: wp.array[float],
        grip_slot: int,  # -1: no gripper
        max_t: float,
        max_r: float,
        rot_weight: float,
        damping: float,
        rest_gain: float,
        reanchor_pos: float,
        reanchor_rot: float,
    ):
        w = wp.tid()
        q_prev = vecn()
        for i in range(n):
            q_prev[i] = target[w, arm_idx[i]]
        q_new = vecn()
        if wp.static(cartesian):
            q_new = wp.static(cartesian_targets)(
                w, q_prev, action, eef_pos, eef_rot, ref_pos, ref_rot, ref_ok, chain_q, fixed, axes, prismatic,
                tail, lower, upper, q_home, max_t, max_r, rot_weight, damping, rest_gain, reanchor_pos,
                reanchor_rot)
        else:
            for i in range(n):
                q_new[i] = action[w, i]
        # joint speed limit, then write
        for i in range(n):
            target[w, arm_idx[i]] = wp.clamp(q_new[i], q_prev[i] - max_step[i], q_prev[i] + max_step[i])
        if grip_slot >= 0:
            g = (action[w, grip_slot] + 1.0) * 0.5
            for j in range(grip_idx.shape[0]):
                target[w, grip_idx[j]] = grip_open[j] + g * (grip_closed[j] - grip_open[j])

    return arm_kernel


@wp.kernel(enable_backward=False)
def clip_actions_kernel(action: wp.array2d[float], lo: wp.array[float], hi: wp.array[float]):
    w, k = wp.tid()
    action[w, k] = wp.clamp(action[w, k], lo[k], hi[k])


@wp.kernel(enable_backward=False)
def servo_kernel(start: wp.array2d[float], target: wp.array2d[float], s: float, act_id: wp.array[int],
                 active: wp.array[int], ctrl: wp.array2d[float]):
    """Servo setpoints at ramp fraction ``s`` from the last command to the new target."""
    w, j = wp.tid()
    if active[w] == 0:
        return
    v = target[w, j]
    if s < 1.0:
        v = start[w, j] + s * (target[w, j] - start[w, j])
    ctrl[w, act_id[j]] = v


@wp.kernel(enable_backward=False)
def copy_rows_kernel(src: wp.array2d[float], dst: wp.array2d[float], active: wp.array[int]):
    w, j = wp.tid()
    if active[w] != 0:
        dst[w, j] = src[w, j]


# ------------------------------------------------------------------------------------------ observe
def make_observe_kernel(n_state_grip: int):
    """The robot's part of the observation (``ManifestScene._observe``): the tool pose (world and base
    frame), the state vector (``Task.state``: position, axis-angle, finger positions), the joints in
    manifest order. What a task reads of its props comes from the physics state itself
    (``simseam.scene.warp.task_state``)."""

    @wp.kernel(module="unique", enable_backward=False)
    def observe_kernel(
        qpos: wp.array2d[float],
        qvel: wp.array2d[float],
        xpos: wp.array2d[wp.vec3],
        xmat: wp.array2d[wp.mat33],
        tool_body: int,
        tool_pos: wp.vec3,
        tool_rot: wp.mat33,
        base_pos: wp.vec3,
        base_rot: wp.mat33,
        rot_reference: wp.vec4,
        joint_qadr: wp.array[int],  # manifest order
        joint_vadr: wp.array[int],
        grip_qadr: wp.array[int],
        # out
        eef_world: wp.array[wp.vec3],
        eef_pos: wp.array[wp.vec3],
        eef_rot: wp.array[wp.mat33],
        state: wp.array2d[float],
        joint_pos: wp.array2d[float],
        joint_vel: wp.array2d[float],
        eef_pose: wp.array2d[float],  # privileged: [x y z qw qx qy qz], base frame
    ):
        w = wp.tid()
        r = xmat[w, tool_body]
        p_world = xpos[w, tool_body] + r * tool_pos
        bt = wp.transpose(base_rot)
        p = bt * (p_world - base_pos)
        rb = bt * (r * tool_rot)
        eef_world[w] = p_world
        eef_pos[w] = p
        eef_rot[w] = rb
        aa = mat_to_axis_angle(rb, rot_reference)
        for a in range(3):
            state[w, a] = p[a]
            state[w, 3 + a] = aa[a]
        for j in range(wp.static(n_state_grip)):
            state[w, 6 + j] = qpos[w, grip_qadr[j]]
        for j in range(joint_qadr.shape[0]):
            joint_pos[w, j] = qpos[w, joint_qadr[j]]
            joint_vel[w, j] = qvel[w, joint_vadr[j]]
        qe = mat_to_quat_wxyz(rb)
        for a in range(3):
            eef_pose[w, a] = p[a]
        for a in range(4):
            eef_pose[w, 3 + a] = qe[a]

    return observe_kernel


@wp.kernel(enable_backward=False)
def contact_pair_kernel(nacon: wp.array[int], geom: wp.array[wp.vec2i], worldid: wp.array[int],
                        geom_owner: wp.array[int], a: int, b: int, where: wp.array[int], touching: wp.array[int]):
    """touching[w] = 1 when world w (with where[w] != 0) has a contact between owners ``a`` and ``b``
    (``MujocoEngine.contacts_between`` over the batch's contacts)."""
    c = wp.tid()
    if c >= nacon[0]:
        return
    g = geom[c]
    if g[0] < 0 or g[1] < 0:
        return
    w = worldid[c]
    if where[w] == 0:
        return
    o1 = geom_owner[g[0]]
    o2 = geom_owner[g[1]]
    if (o1 == a and o2 == b) or (o1 == b and o2 == a):
        touching[w] = 1


# ------------------------------------------------------------------------------------------ resets
@wp.kernel(enable_backward=False)
def scatter_rows_kernel(src: wp.array2d[float], rows: wp.array[int], dst: wp.array2d[float]):
    k, j = wp.tid()
    dst[rows[k], j] = src[k, j]


@wp.kernel(enable_backward=False)
def reset_ref_kernel(rows: wp.array[int], ref_ok: wp.array[int]):
    k = wp.tid()
    ref_ok[rows[k]] = 0


# ------------------------------------------------------------------------------------------ cameras
@wp.func
def _put_rgb(v: wp.uint32, out: wp.array4d[wp.uint8], w: int, y: int, x: int):
    """One packed ABGR pixel into ``out[w, y, x]`` as R, G, B."""
    out[w, y, x, 0] = wp.uint8((v >> wp.uint32(16)) & wp.uint32(0xFF))
    out[w, y, x, 1] = wp.uint8((v >> wp.uint32(8)) & wp.uint32(0xFF))
    out[w, y, x, 2] = wp.uint8(v & wp.uint32(0xFF))


@wp.kernel(enable_backward=False)
def unpack_rgb_u8_kernel(packed: wp.array2d[wp.uint32], adr: int, width: int, out: wp.array4d[wp.uint8]):
    """MuJoCo Warp's packed ABGR pixels of one camera -> uint8 [nworld, H, W, 3]."""
    w, pix = wp.tid()
    _put_rgb(packed[w, adr + pix], out, w, pix // width, pix % width)


@wp.kernel(enable_backward=False)
def unpack_rgb_u8_rows_kernel(packed: wp.array2d[wp.uint32], adr: int, width: int, mask: wp.array2d[wp.int32], k: int,
                              mirror: int, out: wp.array4d[wp.uint8]):
    """``unpack_rgb_u8_kernel`` for the worlds whose ``mask[k]`` is set (the others' images stay), the image
    mirrored left-right when ``mirror`` is 1."""
    w, pix = wp.tid()
    if mask[k, w] == 0:
        return
    x = pix % width
    if mirror == 1:
        x = width - 1 - x
    _put_rgb(packed[w, adr + pix], out, w, pix // width, x)


@wp.kernel(enable_backward=False)
def site_geoms_kernel(geom_xpos: wp.array2d[wp.vec3], geom_xmat: wp.array2d[wp.mat33],
                      site_xpos: wp.array2d[wp.vec3], site_xmat: wp.array2d[wp.mat33], sites: wp.array[int],
                      ngeom: int, out_xpos: wp.array2d[wp.vec3], out_xmat: wp.array2d[wp.mat33]):
    """A render model's geom poses: its first ``ngeom`` the physics model's geoms', then one per drawn site."""
    w, g = wp.tid()
    if g < ngeom:
        out_xpos[w, g] = geom_xpos[w, g]
        out_xmat[w, g] = geom_xmat[w, g]
    else:
        s = sites[g - ngeom]
        out_xpos[w, g] = site_xpos[w, s]
        out_xmat[w, g] = site_xmat[w, s]
