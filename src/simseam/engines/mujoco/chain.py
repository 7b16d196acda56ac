"""A robot chain's forward kinematics and Jacobian from MuJoCo's C, on a scratch ``MjData``.

``ChainForward.forward(q)`` returns what ``SerialChain.forward`` returns (the tool pose as a 4x4 in
the base link's frame and the 6xN geometric Jacobian, linear rows first, columns in ``q`` order) but
computes it with ``mj_kinematics``, ``mj_comPos`` and ``mj_jac`` on the engine's compiled model: a few
microseconds instead of some tens of numpy calls (``forward_rows``: the same as ``SerialChain.forward_rows``,
without building the 4x4); ``dls_solve`` solves the IK's damped least squares system with MuJoCo's
small-matrix products and Cholesky. The scratch data is private, so the
simulation's own state is never touched; only the chain's joints move in it (every other joint stays at its
``qpos0``, as ``SerialChain`` holds unactuated joints at 0). Whoever uses it checks first that it
agrees with the URDF chain (``ManifestScene`` does, to 1e-9).
"""

from __future__ import annotations

import mujoco
import numpy as np

from simseam.seam import ConfigError


def slice_or_index(idx: np.ndarray) -> slice | np.ndarray:
    """A slice when ``idx`` is a run of consecutive addresses (a view, no gather), else ``idx``."""
    if idx.size and np.array_equal(idx, np.arange(idx[0], idx[0] + idx.size)):
        return slice(int(idx[0]), int(idx[0]) + idx.size)
    return idx


class ChainForward:
    """``forward(q)`` of the joints ``joints`` (hinge or slide), base body -> tip body (+ ``tip_offset``,
    4x4 in the tip body's frame), computed by MuJoCo on a copy of ``model``'s state."""

    def __init__(self, model: "mujoco.MjModel", base: str, tip: str, joints: list[str],
                 tip_offset: np.ndarray | None = None):
        m = self._m = model
        d = self._d = mujoco.MjData(model)
        try:
            base_id, self._tip = m.body(base).id, m.body(tip).id
            jids = [m.joint(j).id for j in joints]
        except KeyError as exc:
            raise ConfigError(f"chain kinematics: {exc.args[0]}") from None
        if any(int(m.jnt_type[j]) not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
               for j in jids):
            raise ConfigError(f"chain kinematics: joints {joints} must all be hinge or slide joints")
        self._qadr = slice_or_index(np.array([m.jnt_qposadr[j] for j in jids]))
        self._dofs = slice_or_index(np.array([m.jnt_dofadr[j] for j in jids]))
        d.mocap_quat[:] = (1.0, 0.0, 0.0, 0.0)  # a mocap robot root at the origin: the base frame is the world
        d.mocap_pos[:] = 0.0
        mujoco.mj_kinematics(m, d)
        # What remains between the world and the base (links above it, a free root): constant, since
        # only the chain's joints, all below the base, ever move here.
        self._base_rot_t = d.xmat[base_id].reshape(3, 3).T.copy()
        self._base_pos = d.xpos[base_id].copy()
        self._at_origin = bool(np.array_equal(self._base_rot_t, np.eye(3)) and not self._base_pos.any())
        off = np.eye(4) if tip_offset is None else np.asarray(tip_offset, dtype=np.float64)
        self._off_pos, self._off_rot = off[:3, 3].copy(), off[:3, :3].copy()
        self._has_offset = tip_offset is not None
        self._plain = self._at_origin and not self._has_offset  # the tool frame is the tip body's, in the world
        self._qpos = d.qpos
        self._xpos, self._xmat = d.xpos[self._tip], d.xmat[self._tip].reshape(3, 3)  # views into d
        self._jac = np.zeros((6, m.nv))
        self._jacp, self._jacr = self._jac[:3], self._jac[3:]
        self._point = np.zeros(3)
        self._pose = np.eye(4)
        n = len(jids)
        # dls_solve's system, rewritten by each call: the Jacobian stacked on an identity, and its right-hand side
        self._stacked = np.vstack([np.zeros((6, n)), np.eye(n)])
        self._stacked_rhs = np.empty(6 + n)
        self._normal, self._rhs = np.empty((n, n)), np.empty(n)
        self._weights: dict[tuple[float, float], np.ndarray] = {}

    def forward(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tool pose (4x4) in the base frame and the 6xN geometric Jacobian (linear; angular)."""
        m, d = self._m, self._d
        self._qpos[self._qadr] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)  # cdof and subtree_com: what mj_jac reads
        pose = self._pose.copy()
        if self._has_offset:
            point = self._point
            point[:] = self._xpos + self._xmat @ self._off_pos
            pose[:3, :3] = self._xmat @ self._off_rot
            mujoco.mj_jac(m, d, self._jacp, self._jacr, point, self._tip)
        else:  # the tip body's origin: mj_jacBody is mj_jac there, with one array argument less to convert
            point = self._xpos  # a view of the tip body's position in d
            pose[:3, :3] = self._xmat
            mujoco.mj_jacBody(m, d, self._jacp, self._jacr, self._tip)
        pose[:3, 3] = point
        if self._at_origin:
            return pose, self._chain_jac()
        rt, out = self._base_rot_t, self._jac[:, self._dofs]
        pose[:3, 3] = rt @ (pose[:3, 3] - self._base_pos)
        pose[:3, :3] = rt @ pose[:3, :3]
        return pose, np.concatenate([rt @ out[:3], rt @ out[3:]])

    def forward_rows(self, q: np.ndarray) -> tuple[list[float], list[list[float]], np.ndarray]:
        """``forward(q)`` as (tool position, rotation rows) in Python floats and the Jacobian, read straight
        from MuJoCo's arrays when the tool frame is the tip body's and the base is the world."""
        if not self._plain:
            pose, jac = self.forward(q)
            return pose[:3, 3].tolist(), pose[:3, :3].tolist(), jac
        m, d = self._m, self._d
        self._qpos[self._qadr] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_jacBody(m, d, self._jacp, self._jacr, self._tip)
        return self._xpos.tolist(), self._xmat.tolist(), self._chain_jac()

    def _chain_jac(self) -> np.ndarray:
        """The chain's columns of the last Jacobian, a new array (an index array's gather is one already)."""
        out = self._jac[:, self._dofs]
        return out.copy() if isinstance(self._dofs, slice) else out

    def dls_solve(self, jac: np.ndarray, err: list, z: np.ndarray | None, d2: float, rot_weight: float) -> np.ndarray:
        """``SerialChain._normal_solve``'s step, ``(J^T W J + d2 I)^-1 (J^T W e + d2 z)`` (``W``: 1 on the
        position rows, ``rot_weight^2`` on the rotation rows; ``z`` None: 0), with MuJoCo's small-matrix
        products and Cholesky: the Jacobian stacked on an identity, weighted by ``diag(W, d2 I)``, gives the
        damped normal matrix in one product (``mju_sqrMatTD``), without numpy's BLAS and LAPACK call overhead.
        For a ``rot_weight`` that is a power of two the same floats as weighting the rows first."""
        a, v = self._stacked, self._stacked_rhs
        n = a.shape[1]
        ww = rot_weight * rot_weight
        a[:6] = jac
        ex, ey, ez, rx, ry, rz = err
        v[:6] = (ex, ey, ez, rx * ww, ry * ww, rz * ww)
        if z is None:
            v[6:] = 0.0
        else:
            np.multiply(z, d2, out=v[6:])
        mujoco.mju_sqrMatTD(self._normal, a, self._stack_weights(ww, d2))
        mujoco.mju_mulMatTVec(self._rhs, a, v)
        mujoco.mju_cholFactor(self._normal, 0.0)
        x = np.empty(n)
        mujoco.mju_cholSolve(x, self._normal, self._rhs)
        return x

    def _stack_weights(self, ww: float, d2: float) -> np.ndarray:
        key = (ww, d2)
        if key not in self._weights:
            self._weights[key] = np.array([1.0, 1.0, 1.0, ww, ww, ww] + [d2] * self._rhs.size)
        return self._weights[key]
