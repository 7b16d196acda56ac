"""What robosuite's controller reads of a substep's state (``ArmTerms``), for N worlds of one LIBERO model, from
CPU MuJoCo (``cpu_terms``, any number of ``MjData``) or MuJoCo Warp (``WarpTerms``, N worlds on a Warp device):
the end-effector site's pose, its 6 x 7 Jacobian over the arm's joints, the arm's 7 x 7 block of the joint-space
inertia (armature included, as ``mj_fullM`` gives it), the bias forces (gravity, Coriolis: ``qfrc_bias``) and
the arm's joint positions and velocities.

The Jacobian is built from the joints' world axes and anchors (``xaxis``, ``xanchor``: for a hinge, the
linear column is ``axis x (site - anchor)``, the angular one ``axis``); ``ArmLayout`` checks that the site's
only ancestor joints are the arm's 7 hinges, so no other column of robosuite's full Jacobian is non-zero.
On MuJoCo Warp the terms come from its smooth pipeline alone (kinematics, com_pos, crb, com_vel, rne): no
collision or constraint solve is needed for them.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import numpy as np

from simseam.engines.mujoco_warp.memory import put_worlds
from simseam.seam.errors import SimulationError

HINGE = 3  # mjJNT_HINGE


@dataclass
class ArmTerms:
    """Per world (arrays of ``xp``, float64): ``ee_pos`` [N, 3], ``ee_mat`` [N, 3, 3], ``jac`` [N, 6, 7] (rows:
    linear, angular), ``mass`` [N, 7, 7], ``bias`` [N, 7], ``qpos`` [N, 7], ``qvel`` [N, 7]."""

    ee_pos: Any
    ee_mat: Any
    jac: Any
    mass: Any
    bias: Any
    qpos: Any
    qvel: Any


@dataclass(frozen=True)
class ArmLayout:
    site: int
    joints: np.ndarray  # [7] joint ids
    qpos: np.ndarray  # [7]
    dofs: np.ndarray  # [7]
    mass_csr: np.ndarray  # [7, 7] index of each (i, j) of the arm's block into ``d.M`` (CSR, lower; both engines)

    @classmethod
    def from_model(cls, mjm: Any, facts: dict[str, Any]) -> "ArmLayout":
        site, dofs = int(facts["eef_site_id"]), np.asarray(facts["qvel_index"], np.int64)
        joints = np.asarray(mjm.dof_jntid)[dofs]
        ancestors, body = [], int(mjm.site_bodyid[site])
        while body > 0:
            adr, num = int(mjm.body_dofadr[body]), int(mjm.body_dofnum[body])
            ancestors += list(range(adr, adr + num))
            body = int(mjm.body_parentid[body])
        if sorted(ancestors) != sorted(dofs.tolist()) or np.any(np.asarray(mjm.jnt_type)[joints] != HINGE):
            raise SimulationError(f"LIBERO port: the end-effector site {facts['eef_site']!r} hangs from dofs "
                                  f"{sorted(ancestors)}, not only the arm's hinges {dofs.tolist()}")
        return cls(site, joints, np.asarray(facts["qpos_index"], np.int64), dofs, _csr_index(mjm, dofs))


def _csr_index(mjm: Any, dofs: np.ndarray) -> np.ndarray:
    """Where (i, j) of the arm's block sits in MuJoCo's CSR ``d.M`` (row ``hi``, the later of the two dofs, lists
    its ancestor dofs' columns and its own: ``M_rowadr``, ``M_rownnz``, ``M_colind``)."""
    out = np.zeros((len(dofs), len(dofs)), np.int64)
    for a, i in enumerate(dofs.tolist()):
        for b, j in enumerate(dofs.tolist()):
            hi, lo = max(i, j), min(i, j)
            adr, nnz = int(mjm.M_rowadr[hi]), int(mjm.M_rownnz[hi])
            cols = np.asarray(mjm.M_colind[adr:adr + nnz]).tolist()
            if lo not in cols:
                raise SimulationError(f"LIBERO port: arm dofs {i} and {j} are not on one chain")
            out[a, b] = adr + cols.index(lo)
    return out


def _jacobian(xp, xaxis, xanchor, site_pos):
    """float[N, 7, 3] axes and anchors, [N, 3] site -> float[N, 6, 7]."""
    lin = xp.cross(xaxis, site_pos[:, None, :] - xanchor)
    return xp.concatenate([xp.swapaxes(lin, -1, -2), xp.swapaxes(xaxis, -1, -2)], axis=-2)


def cpu_terms(mjm: Any, datas: list[Any], layout: ArmLayout) -> ArmTerms:
    """The terms of CPU MuJoCo states (each ``MjData`` already forwarded), stacked over worlds."""
    s, j, dofs = layout.site, layout.joints, layout.dofs
    stack = lambda f: np.stack([f(d) for d in datas])  # noqa: E731
    return ArmTerms(
        ee_pos=stack(lambda d: d.site_xpos[s].copy()), ee_mat=stack(lambda d: d.site_xmat[s].reshape(3, 3).copy()),
        jac=_jacobian(np, stack(lambda d: d.xaxis[j]), stack(lambda d: d.xanchor[j]), stack(lambda d: d.site_xpos[s])),
        mass=stack(lambda d: d.M[layout.mass_csr]), bias=stack(lambda d: d.qfrc_bias[dofs].copy()),
        qpos=stack(lambda d: d.qpos[layout.qpos].copy()), qvel=stack(lambda d: d.qvel[dofs].copy()))


class ControllerReads:
    """What robosuite's controller loop needs of N worlds on MuJoCo Warp (``self``: ``m``, ``d``, ``device``,
    ``xp``, ``layout``, ``view``, ``graphs``, ``num_worlds``, ``_wp``, ``_mjw``): ``control_substep`` and ``read``.

    A substep is MuJoCo Warp's ``step1`` (the position and velocity stages: what the controller reads), the
    controller (``osc_kernel.WarpController``: the reading gathered, the torques and the gripper, ``ctrl``
    written) and ``step2`` (actuation, acceleration, constraints, integration): device launches only, so on
    CUDA it is one captured graph (``engines.mujoco_warp.graphs.CudaGraphs``, one for a control step's first
    substep and one for the others: replayed from their third call). Launched kernel by kernel, with the
    controller in CuPy between the stages, a LIBERO substep took 13-14 ms on an H100 whatever the worlds (1-100)."""

    def warp_controller(self, cfg: Any, facts: dict[str, Any]) -> Any:
        """The controller's buffers for these worlds (made once: a captured graph points at them)."""
        held = getattr(self, "_controller", None)
        if held is None or held.cfg is not cfg:
            from simseam.backends.libero_gpu.osc_kernel import WarpController

            self.graphs.clear()  # graphs captured with other buffers
            held = self._controller = WarpController(self, cfg, facts)
        return held

    def control_substep(self, controller: Any, first: bool) -> None:
        """One physics substep of every world with the controller in the loop (``first``: a control step's first,
        where the goal is set from the action)."""
        def launches():
            self._mjw.step1(self.m, self.d)
            controller.launch(self.d, first)
            self._mjw.step2(self.m, self.d)

        with self._wp.ScopedDevice(self.device):
            self.graphs.launch("substep_first" if first else "substep", launches)
            self._wp.synchronize_device(self.device)

    def control_substeps(self, controller: Any, substeps: int, sampler: Any, images: Any = None,
                         drawn: tuple[int, ...] = ()) -> None:
        """A whole control step of every world (``substeps`` of ``control_substep``'s launches, ``sampler``'s
        launch after each: ``observables.Sampler``, the observables sampled on the device; ``images``'s too after
        the substeps ``drawn``: ``observables.ImageSampler``, the cameras): on CUDA one captured graph per set of
        drawn substeps, one launch and one wait per control step instead of one per substep."""
        def launches():
            for k in range(substeps):
                self._mjw.step1(self.m, self.d)
                controller.launch(self.d, k == 0)
                self._mjw.step2(self.m, self.d)
                sampler.launch(self.d, k)
                if k in drawn:
                    images.launch(self.m, self.d, k)

        with self._wp.ScopedDevice(self.device):
            self.graphs.launch(f"control_step{substeps}" + (f"_drawn{'_'.join(map(str, drawn))}" if drawn else ""),
                               launches)
            self._wp.synchronize_device(self.device)

    def read(self) -> ArmTerms:
        """The worlds' ``ArmTerms`` as the last pipeline left them (``osc_kernel.gather_terms``: the gather the
        controller's substep runs), as ``xp`` arrays (views of fresh device buffers)."""
        from simseam.backends.libero_gpu.osc_kernel import Gather, terms_buffers

        if getattr(self, "_gather", None) is None:
            self._gather = Gather(self)
        out = terms_buffers(self.num_worlds, self.device)
        with self._wp.ScopedDevice(self.device):
            self._gather.launch(self.d, list(out.values()))
            self._wp.synchronize_device(self.device)
        return ArmTerms(**{k: self.view(v) for k, v in out.items()})


class WarpTerms(ControllerReads):
    """N worlds of one model on MuJoCo Warp (``device``: a Warp device name, e.g. ``cpu`` or ``cuda:0``):
    ``load(qpos, qvel)`` sets the worlds' states (float[N, nq], [N, nv]); ``terms()`` runs the smooth pipeline
    and returns their ``ArmTerms`` as ``xp`` arrays (NumPy on the CPU device, CuPy on CUDA), in float64;
    ``read()`` returns them as the last pipeline left them (after ``mujoco_warp.step1``: see ``stepping``).
    ``nconmax`` / ``njmax``: contact and constraint rows per world, for stepping (default: mujoco_warp's, from
    the model's default pose, where a LIBERO scene's objects overlap in 1,300-1,900 contacts: ample for the
    10-120 they hold at rest)."""

    def __init__(self, mjm: Any, layout: ArmLayout, num_worlds: int, device: str | None = None,
                 nconmax: int | None = None, njmax: int | None = None):
        import mujoco
        import mujoco_warp as mjw
        import warp as wp

        from simseam.engines.mujoco_warp.graphs import CudaGraphs

        wp.config.quiet = True
        wp.init()
        self._wp, self._mjw, self.mjm, self.layout, self.num_worlds = wp, mjw, mjm, layout, num_worlds
        self.device = wp.get_device(device) if device else wp.get_preferred_device()
        host = mujoco.MjData(mjm)
        mujoco.mj_forward(mjm, host)
        self.m, self.d = put_worlds(mjm, host, num_worlds, self.device, "LIBERO's worlds on MuJoCo Warp",
                                    nconmax=nconmax, njmax=njmax)
        self.xp = np if not self.device.is_cuda else __import__("cupy")
        self.graphs = CudaGraphs(self.device)

    def view(self, a: Any) -> Any:
        return self.xp.from_dlpack(a) if self.device.is_cuda else a.numpy()

    def load(self, qpos, qvel) -> None:
        self.view(self.d.qpos)[...] = self.xp.asarray(qpos)
        self.view(self.d.qvel)[...] = self.xp.asarray(qvel)
        if self.device.is_cuda:
            self.xp.cuda.get_current_stream().synchronize()

    def terms(self) -> ArmTerms:
        mjw, m, d = self._mjw, self.m, self.d
        with self._wp.ScopedDevice(self.device):
            for stage in (mjw.kinematics, mjw.com_pos, mjw.crb, mjw.com_vel, mjw.rne):
                stage(m, d)
            self._wp.synchronize_device(self.device)
        return self.read()

    def close(self) -> None:
        self.m = self.d = None
        self.graphs.clear()


class CpuControllerReads:
    """``ControllerReads`` for one world on CPU MuJoCo (``self``: ``_mj`` the mujoco module, ``mjm``, ``data``,
    ``layout``, and ``d.ctrl`` float[1, nu], where the controller writes): ``step1``, ``read``, ``step2``."""

    def view(self, a: Any) -> Any:
        return a

    def step1(self) -> None:
        self._mj.mj_step1(self.mjm, self.data)

    def read(self) -> ArmTerms:
        return cpu_terms(self.mjm, [self.data], self.layout)

    def step2(self) -> None:
        self.data.ctrl[:] = self.d.ctrl[0]
        self._mj.mj_step2(self.mjm, self.data)


class CpuArm(CpuControllerReads):
    """One world of a LIBERO model on CPU MuJoCo, stepped by ``stepping.control_step`` as the MuJoCo Warp worlds
    are (``step1``, ``read``, the controller writing ``view(d.ctrl)``, ``step2``): the port's own code on the CPU
    engine, which tells the gaps the port's code and the MuJoCo version make from those MuJoCo Warp's float32
    makes. ``mjm``: the world's model (its fixtures' fields set); ``data``: its ``MjData``."""

    xp = np

    def __init__(self, mjm: Any, data: Any, layout: ArmLayout):
        import mujoco

        self._mj, self.mjm, self.data, self.layout = mujoco, mjm, data, layout
        self.d = SimpleNamespace(ctrl=np.zeros((1, mjm.nu)))

    @classmethod
    def from_reset(cls, mjm: Any, layout: ArmLayout, state: dict[str, Any]) -> "CpuArm":
        """A world of its own model (a copy of ``mjm`` with the reset's fixture fields) holding a reset state
        (``resets.ResetCache``'s), forwarded."""
        import copy

        import mujoco

        model = copy.deepcopy(mjm)
        for key, value in state["model"].items():
            getattr(model, key)[...] = np.asarray(value).reshape(getattr(model, key).shape)
        data = mujoco.MjData(model)
        for key in ("qpos", "qvel", "act", "ctrl", "qacc_warmstart"):
            if getattr(data, key).size:
                getattr(data, key)[...] = np.asarray(state[key]).reshape(getattr(data, key).shape)
        mujoco.mj_forward(model, data)
        return cls(model, data, layout)

