"""Serial-chain kinematics from a URDF, computed by the scene (numpy only).

The scene owns inverse kinematics so that CARTESIAN_DELTA means exactly the
same on every engine: the engine only reports joint positions and accepts
joint targets. Frames: everything here is in the robot base link frame.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from simseam.math3d import pose_rows, rotation_error_rows, rpy_to_matrix
from simseam.robot.urdf import MOVABLE, UrdfJoint, UrdfModel
from simseam.seam import ConfigError, RobotFacts


@dataclass(slots=True)
class IKResult:
    q: np.ndarray
    pos_error: float  # metres
    rot_error: float  # radians
    iterations: int


@dataclass(frozen=True)
class ChainArrays:
    """A chain's constants in chain order, for batched kinematics elsewhere (the MuJoCo Warp kernels):
    ``q_index[k]``: which of the chain's joint names (its ``q`` order) is the k-th joint along the chain;
    ``fixed[k]``: the 4x4 transform before joint k; ``axes[k]``: its unit axis; ``prismatic[k]``;
    ``tail``: the transform after the last joint (to the tool frame); ``lower`` / ``upper``: the joints'
    limits in ``q`` order."""

    q_index: np.ndarray
    fixed: np.ndarray
    axes: np.ndarray
    prismatic: np.ndarray
    tail: np.ndarray
    lower: np.ndarray
    upper: np.ndarray


class SerialChain:
    """The joints between ``base_link`` and ``tip_link``.

    ``joint_names`` lists the chain's actuated joints (``q`` order); any other
    movable joint on the way is held at 0. Joint limits clip every IK solution.
    ``tip_offset`` (4x4, in ``tip_link``'s frame) moves the tip to a tool frame
    the URDF lacks (a manifest's ``tcp``). ``forward_source``: who computes ``forward``
    (``"urdf"``: this class, in numpy; another name after ``with_forward``).
    """

    forward_source = "urdf"

    def __init__(self, urdf: UrdfModel, base_link: str, tip_link: str, joint_names: list[str],
                 lower: np.ndarray, upper: np.ndarray, tip_offset: np.ndarray | None = None):
        chain = urdf.chain(base_link, tip_link)
        names_on_chain = [j.name for j in chain if j.type in MOVABLE]
        missing = [n for n in joint_names if n not in names_on_chain]
        if missing:
            raise ConfigError(
                f"{urdf.path}: arm joints {missing} are not on the chain {base_link} -> {tip_link} "
                f"(chain joints: {names_on_chain})"
            )
        # Fold fixed joints and unactuated movable joints (at 0) into constant transforms.
        self._fixed: list[np.ndarray] = []  # transform before each actuated joint
        self._axes: list[np.ndarray] = []
        self._prismatic: list[bool] = []
        self._index: list[int] = []
        t = np.eye(4)
        for j in chain:
            origin = np.eye(4)
            origin[:3, :3] = rpy_to_matrix(j.rpy)
            origin[:3, 3] = j.xyz
            t = t @ origin
            if j.name in joint_names:
                self._fixed.append(t)
                axis = np.asarray(j.axis, dtype=np.float64)
                self._axes.append(axis / np.linalg.norm(axis))
                self._prismatic.append(j.type == "prismatic")
                self._index.append(joint_names.index(j.name))
                t = np.eye(4)
        self._tail = t if tip_offset is None else t @ np.asarray(tip_offset, dtype=np.float64)
        order = np.argsort(self._index)
        if list(np.asarray(self._index)[order]) != list(range(len(joint_names))):
            raise ConfigError(f"{urdf.path}: duplicate arm joints {joint_names}")
        # q is given in joint_names order; the chain visits joints in chain order.
        self._q_from_names = np.asarray(self._index)
        self.n = len(joint_names)
        self.lower = np.asarray(lower, dtype=np.float64)
        self.upper = np.asarray(upper, dtype=np.float64)
        axes = np.asarray(self._axes)
        self._kx = np.zeros((self.n, 3, 3))
        self._kx[:, 0, 1], self._kx[:, 0, 2] = -axes[:, 2], axes[:, 1]
        self._kx[:, 1, 0], self._kx[:, 1, 2] = axes[:, 2], -axes[:, 0]
        self._kx[:, 2, 0], self._kx[:, 2, 1] = -axes[:, 1], axes[:, 0]
        self._kx2 = self._kx @ self._kx
        self._prism = np.asarray(self._prismatic)
        self._axes_arr = axes
        self._fixed_arr = np.asarray(self._fixed)
        self._motion = np.zeros((self.n, 4, 4))
        self._motion[:, 3, 3] = 1.0
        self._eye3 = np.eye(3)
        self._in_chain_order = bool(np.array_equal(self._q_from_names, np.arange(self.n)))
        self._c1, self._c2 = np.array([1, 2, 0]), np.array([2, 0, 1])  # cross-product index cycles
        self._revolute_f = (~self._prism).astype(np.float64)
        self._any_prism = bool(self._prism.any())
        self._eye_cache: dict[float, np.ndarray] = {}
        self._dls_solve = self._normal_solve

    def with_forward(self, forward: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]], source: str,
                     dls_solve: Callable[..., np.ndarray] | None = None,
                     forward_rows: Callable[[np.ndarray], tuple] | None = None) -> "SerialChain":
        """A copy of this chain whose ``forward`` (and so ``solve``) is ``forward``: another implementation
        of the same kinematics (an engine's, ``source`` names it), which the caller has checked agrees;
        ``forward_rows``: ``forward_rows`` on the same kinematics; ``dls_solve(jac, err, z, d2, rot_weight)``:
        what ``_normal_solve`` computes, by the same engine (both checked by the engine's tests to agree)."""
        other = copy.copy(self)
        other.forward = forward  # type: ignore[method-assign]
        other.forward_source = source
        if forward_rows is not None:
            other.forward_rows = forward_rows  # type: ignore[method-assign]
        if dls_solve is not None:
            other._dls_solve = dls_solve
        return other

    @property
    def arrays(self) -> ChainArrays:
        return ChainArrays(self._q_from_names.copy(), self._fixed_arr.copy(), self._axes_arr.copy(),
                           self._prism.copy(), self._tail.copy(), self.lower.copy(), self.upper.copy())

    @classmethod
    def of_robot(cls, robot: RobotFacts) -> "SerialChain":
        """The arm's chain, base link -> tool frame, from a rollout's ``spec.robot`` alone (its link
        tree, the manifest's tool frame included, and the arm joints' limits), for a policy's own IK."""
        joints = tuple(UrdfJoint(link.joint, link.joint_type, link.parent, link.name, tuple(link.xyz),
                                 tuple(link.rpy), tuple(link.axis), None, None, None, None)
                       for link in robot.links if link.parent is not None)
        urdf = UrdfModel(robot.name, f"robot {robot.name!r}", tuple(link.name for link in robot.links), joints)
        arm = [j for j in robot.joints if j.role == "arm"]
        lower = np.array([-2 * np.pi if j.lower is None else j.lower for j in arm])
        upper = np.array([2 * np.pi if j.upper is None else j.upper for j in arm])
        return cls(urdf, robot.base_link, robot.tool_link, [j.sim_name or j.name for j in arm], lower, upper)

    def forward(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tip pose (4x4) in the base frame and the 6xN geometric Jacobian (linear; angular)."""
        qc = np.asarray(q, dtype=np.float64)
        if not self._in_chain_order:
            qc = qc[self._q_from_names]
        ang = qc * self._revolute_f
        s, c = np.sin(ang)[:, None, None], np.cos(ang)[:, None, None]
        motion = self._motion
        motion[:, :3, :3] = self._eye3 + s * self._kx + (1.0 - c) * self._kx2
        if self._any_prism:
            motion[:, :3, 3] = self._axes_arr * (qc * (1.0 - self._revolute_f))[:, None]
        cum = np.matmul(self._fixed_arr, motion)  # joint i's frame after its motion, in frame i-1 ...
        for i in range(1, self.n):
            np.matmul(cum[i - 1], cum[i], out=cum[i])  # ... then chained: in the base frame
        tip = cum[-1] @ self._tail
        # A joint's motion leaves its own axis and (revolute) origin in place.
        zs = np.einsum("nij,nj->ni", cum[:, :3, :3], self._axes_arr)
        d = tip[:3, 3] - cum[:, :3, 3]
        lin = zs.take(self._c1, 1) * d.take(self._c2, 1) - zs.take(self._c2, 1) * d.take(self._c1, 1)
        if self._any_prism:
            lin[self._prism] = zs[self._prism]
            zs[self._prism] = 0.0
        jac = np.empty((6, self.n))
        if self._in_chain_order:
            jac[:3] = lin.T
            jac[3:] = zs.T
        else:
            jac[:3, self._q_from_names] = lin.T
            jac[3:, self._q_from_names] = zs.T
        return tip, jac

    def forward_rows(self, q: np.ndarray) -> tuple[list[float], list[list[float]], np.ndarray]:
        """``forward(q)`` as the IK reads it: the tip position and rotation rows in Python floats, and the
        Jacobian (a new array)."""
        t, jac = self.forward(q)
        pos, rot = pose_rows(t)
        return pos, rot, jac

    def solve(self, q_start: np.ndarray, target_pos: np.ndarray | list, target_rot: np.ndarray | list, *,
              max_iters: int = 1, pos_tol: float = 2e-4, rot_tol: float = 2e-3,
              rot_weight: float = 0.5, damping: float = 0.02, q_rest: np.ndarray | None = None,
              rest_gain: float = 0.05, start: tuple[list, list, np.ndarray] | None = None) -> IKResult:
        """Damped least squares IK towards a base-frame target pose, within joint limits.

        Each iteration is one Newton step from the last ``q``; with ``q_start``
        the previous solution, one step per control step tracks a Cartesian
        delta like an operational-space controller (the residual is corrected
        at the next step). Orientation error is weighted by ``rot_weight``
        (m/rad), so position wins when the arm cannot reach both (a 5-DoF arm).
        With redundancy the null space pulls gently towards ``q_rest``.
        ``pos_error``/``rot_error`` are measured at the last evaluated ``q``
        (before the final step when ``max_iters`` ran out). ``start`` is
        ``forward_rows(q_start)`` when the caller already has it. The target may come as arrays or as
        Python floats (a list, nested for the rotation).
        """
        lower, upper = self.lower, self.upper
        q = np.minimum(np.maximum(np.asarray(q_start, dtype=np.float64), lower), upper)  # np.clip, cheaper
        # the task error is formed in Python floats: 3-vectors cost less there than as numpy calls
        tx, ty, tz = target_pos.tolist() if isinstance(target_pos, np.ndarray) else target_pos
        target_rot = target_rot.tolist() if isinstance(target_rot, np.ndarray) else target_rot
        step = self._dls_solve if self.n >= 6 else self._priority_step
        pull = q_rest is not None and self.n > 6
        d2 = damping ** 2
        ep = er = np.inf
        it = 0
        for it in range(max_iters):
            (cx, cy, cz), rot, jac = start if (it == 0 and start is not None) else self.forward_rows(q)
            px, py, pz = tx - cx, ty - cy, tz - cz
            rx, ry, rz = rotation_error_rows(target_rot, rot)
            ep, er = math.sqrt(px * px + py * py + pz * pz), math.sqrt(rx * rx + ry * ry + rz * rz)
            if ep < pos_tol and er < rot_tol:
                break
            err = [px, py, pz, rx, ry, rz]
            z = rest_gain * (q_rest - q) if pull else None
            q_new = q + step(jac, err, z, d2, rot_weight)
            q_lim = np.minimum(np.maximum(q_new, lower), upper)
            if q_lim.tolist() != q_new.tolist():  # cheaper than a numpy comparison and reduction
                q_lim = self._step_blocked(step, q, q_new, q_lim, jac, err, z, d2, rot_weight)
            q = q_lim
            it += 1
        return IKResult(q=q, pos_error=ep, rot_error=er, iterations=it)

    def _step_blocked(self, step: Callable[..., np.ndarray], q: np.ndarray, q_new: np.ndarray, q_lim: np.ndarray,
                      jac: np.ndarray, err: list, z: np.ndarray | None, d2: float, rot_weight: float) -> np.ndarray:
        """``step``'s result from ``q`` when ``q_new`` crosses a joint limit: joints that would cross one stop at
        it and the step is re-solved without them, so the other joints take up their share of the motion
        (``q`` is within the limits, so only a step down can cross the lower one)."""
        blocked = (q_new < self.lower) | (q_new > self.upper)
        dq_b = q_lim[blocked] - q[blocked]  # blocked joints go to their limit; the rest solve for what is left
        jac = jac.copy()
        err = (np.array(err) - jac[:, blocked] @ dq_b).tolist()
        jac[:, blocked] = 0.0
        if z is not None:
            z[blocked] = 0.0
        dq = step(jac, err, z, d2, rot_weight)
        dq[blocked] = dq_b
        return np.minimum(np.maximum(q + dq, self.lower), self.upper)

    def _normal_solve(self, jac: np.ndarray, err: list, z: np.ndarray | None, d2: float,
                      rot_weight: float) -> np.ndarray:
        """The damped least squares step for the task error ``err`` (position; rotation), plus ``z``
        projected into the null space: ``J^T A^-1 e + (I - J^T A^-1 J) z`` with ``A = J J^T + d^2 I``,
        computed as the equal ``(J^T J + d2 I)^-1 (J^T e + d2 z)`` (one n x n solve, one right-hand side;
        ``z`` None: 0), ``J`` and ``e`` with their rotation rows weighted by ``rot_weight``."""
        jw, e = self._weighted(jac, err, rot_weight)
        jt = jw.T
        m = jt @ jw
        m += self._damped_eye(d2)
        b = jt @ e
        if z is not None:
            b += d2 * z
        return np.linalg.solve(m, b)

    def _damped_eye(self, d2: float) -> np.ndarray:
        eye = self._eye_cache.get(d2)
        if eye is None:
            eye = self._eye_cache[d2] = d2 * np.eye(self.n)
        return eye

    @staticmethod
    def _weighted(jac: np.ndarray, err: list, rot_weight: float) -> tuple[np.ndarray, np.ndarray]:
        """The Jacobian's rows and the error weighted alike: position 1, orientation ``rot_weight``."""
        jw, e = jac.copy(), np.array(err)
        jw[3:] *= rot_weight
        e[3:] *= rot_weight
        return jw, e

    def _priority_step(self, jac: np.ndarray, err: list, z: np.ndarray | None, d2: float,
                       rot_weight: float) -> np.ndarray:
        """Task-priority step for arms with fewer than 6 joints: position first,
        orientation only within the position task's null space (``_normal_solve``'s arguments)."""
        jw, e = self._weighted(jac, err, rot_weight)
        jp, jo = jw[:3], jw[3:]
        jp_pinv = jp.T @ np.linalg.inv(jp @ jp.T + d2 * self._eye3)
        dq1 = jp_pinv @ e[:3]
        # The projector uses the exact pseudo-inverse: a damped one leaks, and the
        # secondary task would then undo part of the position motion.
        null = np.eye(self.n) - np.linalg.pinv(jp, rcond=1e-4) @ jp
        jo_n = jo @ null
        dq2 = jo_n.T @ np.linalg.solve(jo_n @ jo_n.T + d2 * self._eye3, e[3:] - jo @ dq1)
        return dq1 + null @ dq2

    def tabletop_reach(self, n_samples: int = 1500, z_band: tuple[float, float] = (0.0, 0.2)) -> float:
        """How far (m, horizontally) the tip reaches at tabletop height.

        The 90th percentile of the tip's horizontal distance from the base over
        random joint configurations whose tip lies ``z_band`` above the base.
        Deterministic (fixed sample seed). Layouts scale their workspace by it.
        """
        rng = np.random.default_rng(0)
        lo = np.maximum(self.lower, -np.pi)
        hi = np.minimum(self.upper, np.pi)
        dists = []
        for q in rng.uniform(lo, hi, size=(n_samples, self.n)):
            t, _ = self.forward(q)
            if z_band[0] <= t[2, 3] <= z_band[1]:
                dists.append(np.hypot(t[0, 3], t[1, 3]))
        if len(dists) < 20:
            raise ConfigError("the arm cannot reach tabletop height above its base")
        return float(np.percentile(dists, 90))
