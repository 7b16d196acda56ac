"""NVIDIA GPUs on this machine (``nvidia-smi``) and whether they can run RTX sensors.

Isaac Sim renders cameras (and RTX lidar) with the RTX ray tracer, which needs a
GPU with RT cores. Datacenter compute GPUs (V100, A100, A30, H100, H200, B200 ...)
have none: there Isaac Sim runs PhysX physics, joint state, PhysX scene-query
ray casts (simseam's 2-D lidar) and contacts, but no RTX cameras and no RTX lidar.
Standard library only.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from dataclasses import dataclass

#: compute-only datacenter parts without RT cores (matched on the nvidia-smi name)
NO_RT_CORE_PATTERNS = (r"\bP100\b", r"\bV100", r"\bA100\b", r"\bA800\b", r"\bA30\b", r"\bH100\b", r"\bH800\b",
                       r"\bH200\b", r"\bH20\b", r"\bGH200\b", r"\bB100\b", r"\bB200\b", r"\bGB200\b", r"\bB300\b",
                       r"\bGB300\b")
NO_RTX_LIMITS = (
    "no RT cores: Isaac Sim cannot render RTX cameras (RGB/depth) or RTX lidar here. What still works: "
    "PhysX physics (CPU or GPU), joint targets and state, link/object poses, contacts and the 2-D lidar "
    "(simseam casts it with PhysX scene queries, not RTX). Run state-only scenes (policies that use no "
    "images), or use an RTX GPU (RTX 4080/4090/5090, RTX 6000 Ada, L4, L40S ...) for cameras."
)


@dataclass(frozen=True)
class GpuInfo:
    index: int
    name: str
    driver: str
    memory_mib: int | None

    @property
    def rt_cores(self) -> bool:
        return has_rt_cores(self.name)


def has_rt_cores(name: str) -> bool:
    """Whether a GPU (by its nvidia-smi name) has RT cores, i.e. can run Isaac Sim's RTX sensors."""
    return not any(re.search(p, name, flags=re.IGNORECASE) for p in NO_RT_CORE_PATTERNS)


def parse_nvidia_smi(csv: str) -> list[GpuInfo]:
    """Parse ``nvidia-smi --query-gpu=index,name,driver_version,memory.total --format=csv,noheader,nounits``."""
    gpus = []
    for line in csv.strip().splitlines():
        parts = [p.strip() for p in line.split(",")]
        if len(parts) < 4 or not parts[0].isdigit():
            continue
        try:
            mem = int(float(parts[3]))
        except ValueError:
            mem = None
        gpus.append(GpuInfo(int(parts[0]), parts[1], parts[2], mem))
    return gpus


def query_gpus(run=None, which=None) -> tuple[list[GpuInfo], str | None]:
    """(GPUs, problem): the NVIDIA GPUs ``nvidia-smi`` sees, or why none could be listed."""
    run, which = run or subprocess.run, which or shutil.which
    exe = which("nvidia-smi")
    if exe is None:
        return [], "nvidia-smi not found: no NVIDIA driver on this machine (Isaac Sim needs one)"
    try:
        out = run([exe, "--query-gpu=index,name,driver_version,memory.total", "--format=csv,noheader,nounits"],
                  capture_output=True, text=True, timeout=30, check=False)
    except (OSError, subprocess.SubprocessError) as exc:
        return [], f"nvidia-smi failed: {exc}"
    if out.returncode != 0:
        return [], f"nvidia-smi failed (exit {out.returncode}): {(out.stderr or out.stdout).strip()[:200]}"
    gpus = parse_nvidia_smi(out.stdout)
    return gpus, None if gpus else "nvidia-smi lists no GPU"


def rtx_problem(gpus: list[GpuInfo] | None = None, problem: str | None = None) -> str | None:
    """Why this machine cannot render RTX sensors, or None when GPU 0 can."""
    if gpus is None:
        gpus, problem = query_gpus()
    if not gpus:
        return problem or "no NVIDIA GPU found"
    gpu = gpus[0]
    return None if gpu.rt_cores else f"GPU 0 ({gpu.name}) has {NO_RTX_LIMITS}"
