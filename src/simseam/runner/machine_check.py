"""``simseam doctor``: what this machine can run, checked by running a little of each, not by guessing.

Each check returns a ``Check``: its area, whether it works, what was found, and what to do when it
does not. The Isaac Sim section (interpreters, license, RTX GPU) lives with the Isaac provisioning
code (``cli/isaac.py``); these are the rest: rendering, the learned-policy stack, MuJoCo Warp, the
benchmark backends.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass
from importlib.metadata import PackageNotFoundError, version


@dataclass(frozen=True)
class Check:
    area: str
    ok: bool
    found: str
    fix: str = ""

    def to_json(self) -> dict:
        return asdict(self)


def _version(dist: str) -> str | None:
    try:
        return version(dist)
    except PackageNotFoundError:
        return None


def check_rendering() -> Check:
    """MuJoCo renders a camera frame headless (``MUJOCO_GL``, default egl) and the frame is not blank."""
    gl = os.environ.setdefault("MUJOCO_GL", "egl")
    try:
        from simseam.robot.manifest import load_robot
        from simseam.scene.manifest_scene import ManifestScene, SceneOptions

        scene = ManifestScene(load_robot("franka_panda"), "lift_cube", "mujoco", SceneOptions(image_size=(32, 32)))
        try:
            frame = scene.reset(0)["images"]
            std = min(float(img.std()) for img in frame.values())
        finally:
            scene.close()
    except Exception as exc:  # noqa: BLE001  (any failure is the finding)
        return Check("rendering", False, f"MUJOCO_GL={gl}: {type(exc).__name__}: {str(exc).splitlines()[0][:200]}",
                     "install Debian's libegl1 libgl1 libegl-mesa0 libosmesa6 (scripts/bootstrap.sh does), or set "
                     "MUJOCO_GL=osmesa")
    if std < 1.0:
        return Check("rendering", False, f"MUJOCO_GL={gl}: the frames are blank", "try MUJOCO_GL=osmesa")
    return Check("rendering", True, f"MUJOCO_GL={gl}: MuJoCo {_version('mujoco')} renders the cameras")


def check_learning() -> Check:
    """The LeRobot/PyTorch stack that ``lerobot:`` policies, ``collect`` and ``train`` need."""
    torch_v, lerobot_v = _version("torch"), _version("lerobot")
    if not (torch_v and lerobot_v):
        return Check("learned policies", False, f"torch {torch_v or 'missing'}, lerobot {lerobot_v or 'missing'}",
                     "bash scripts/test sets up the stack (scripts/learning-stack.txt), or "
                     "pip install 'simseam[lerobot]'")
    try:
        import torch

        cuda = f"CUDA {torch.version.cuda}, {torch.cuda.device_count()} GPU(s)" if torch.cuda.is_available() \
            else "no CUDA GPU (CPU)"
    except Exception as exc:  # noqa: BLE001
        return Check("learned policies", False, f"torch {torch_v} does not import: {exc}", "reinstall torch")
    return Check("learned policies", True, f"torch {torch_v}, lerobot {lerobot_v}, {cuda}")


def check_warp() -> Check:
    """MuJoCo Warp (``engine: mujoco_warp``, ``--renderer batched``) and the device it would use."""
    if not (_version("warp-lang") and _version("mujoco-warp")):
        return Check("MuJoCo Warp", False, "warp-lang / mujoco-warp not installed",
                     "pip install 'simseam[warp]' (scripts/test installs it)")
    import subprocess
    import sys

    probe = ("import warp as wp, mujoco_warp; wp.config.quiet = True; wp.init(); "
             "print('device', wp.get_preferred_device())")
    try:  # in a child: warp prints its banner and driver warnings from C, and keeps its state
        out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=300)
    except subprocess.TimeoutExpired:
        return Check("MuJoCo Warp", False, "warp did not start within 300 s", "see warp's installation notes")
    lines = [ln for ln in out.stdout.splitlines() if ln.startswith("device ")]
    if out.returncode != 0 or not lines:
        last = (out.stderr.strip().splitlines() or ["no output"])[-1]
        return Check("MuJoCo Warp", False, f"warp does not start: {last[:200]}", "see warp's installation notes")
    device = lines[-1].split(" ", 1)[1]
    return Check("MuJoCo Warp", True, f"warp {_version('warp-lang')}, mujoco-warp {_version('mujoco-warp')}, "
                                      f"device {device}" + ("" if device.startswith("cuda") else
                                                            " (N worlds run on the CPU: slow)"))


def check_backends() -> list[Check]:
    """Each benchmark backend's provisioned venv (``simseam backends provision NAME``)."""
    from simseam.backends import BACKENDS
    from simseam.backends.provision import marker, provision_command, venv_dir

    out = []
    for name in BACKENDS:
        m = marker(name)
        out.append(Check(f"backend {name}", m is not None,
                         f"{venv_dir(name)} ({m['bytes'] / 2**20:.0f} MiB)" if m else "not provisioned",
                         "" if m else provision_command(name)))
    return out


def check_vulkan() -> Check:
    """A Vulkan driver SAPIEN can render ManiSkill3's cameras with: a GPU's, or the provisioned software one."""
    from simseam.backends import software_vulkan as sv

    if sv._gpu_vulkan():
        return Check("ManiSkill3 cameras", True, "a GPU Vulkan driver (or VK_ICD_FILENAMES) is set")
    icd = sv.installed()
    if icd is None:
        return Check("ManiSkill3 cameras", False, "no GPU Vulkan driver and no software one",
                     "python -m simseam.backends.software_vulkan (Mesa 25 lavapipe; set-up does it on Debian)")
    return Check("ManiSkill3 cameras", True, f"software Vulkan (Mesa lavapipe) {icd.parent.name}, on the CPU")


def check_physx_gpu() -> Check:
    """ManiSkill3's GPU physics: NVIDIA's PhysX GPU library for the provisioned SAPIEN's PhysX version."""
    from simseam.backends import physx_gpu
    from simseam.backends.provision import marker, provision_command, python_of
    from simseam.seam import SimseamError

    area = "ManiSkill3 GPU physics"
    if marker("maniskill") is None:
        return Check(area, False, "the maniskill backend is not provisioned", provision_command("maniskill"))
    try:
        version = physx_gpu.physx_version(python_of("maniskill"))
    except SimseamError as exc:
        return Check(area, False, str(exc), f"{provision_command('maniskill')} --force")
    path = physx_gpu.library_path(version)
    if not path.is_file():
        return Check(area, False, f"no {physx_gpu.LIBRARY} for SAPIEN's PhysX {version} ({path}); "
                                  "sim_backend physx_cuda is refused, physx_cpu works",
                     "simseam backends provision maniskill --physx-gpu FILE (a copy you have)")
    return Check(area, True, f"{path} for SAPIEN's PhysX {version} (runs on an NVIDIA GPU with its driver)")


def machine_checks() -> list[Check]:
    return [check_rendering(), check_learning(), check_warp(), check_vulkan(), check_physx_gpu(), *check_backends()]
