"""A software Vulkan driver for machines without a GPU, so that SAPIEN (ManiSkill3) renders on the CPU.

SAPIEN's renderer needs a Vulkan device with descriptor indexing (``descriptorBindingPartiallyBound``),
timeline semaphores and ``VK_EXT_extended_dynamic_state``. Debian 12's Mesa lavapipe (22.3) lacks
descriptor indexing, so SAPIEN finds no device; the lavapipe of Mesa 25 (``mesa-vulkan-drivers`` in
bookworm-backports) has all three. ``provision()`` downloads that package and the libdrm it needs with
apt's own downloader (a private package list, nothing installed system-wide), unpacks them under
``$SIMSEAM_CACHE/software-vulkan/<version>/`` and writes a Vulkan ICD file pointing at the unpacked
driver. ``sidecar_env()`` gives a backend's sidecar the variables that select it, on machines whose
own Vulkan has no GPU driver (a GPU's driver, or a ``VK_ICD_FILENAMES`` the user set, always wins).

Standard library only (the client side runs it; the sidecar only receives its environment).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

#: backends whose sidecars render through Vulkan (SAPIEN)
RENDERS_WITH = ("maniskill",)
SUITE = "bookworm-backports"
PACKAGES = ("mesa-vulkan-drivers", "libdrm2", "libdrm-amdgpu1", "libdrm-common")
LIB_DIR = "usr/lib/x86_64-linux-gnu"
ICD = "lvp_icd.json"
#: system ICD files of GPU drivers: where one exists, SAPIEN renders on the GPU and this is not used
GPU_ICDS = ("nvidia_icd.json",)
GPU_ICD_DIRS = ("/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d", "/usr/local/nvidia/share/vulkan/icd.d")
SOURCES = f"""Types: deb
URIs: http://deb.debian.org/debian
Suites: bookworm {SUITE}
Components: main
Signed-By: /usr/share/keyrings/debian-archive-keyring.gpg
"""


def root() -> Path:
    return Path(os.environ.get("SIMSEAM_CACHE", Path.home() / ".cache" / "simseam")) / "software-vulkan"


def installed() -> Path | None:
    """The unpacked driver's ICD file, when provisioned."""
    ready = sorted(root().glob(f"*/{ICD}"))
    return ready[-1] if ready else None


def _gpu_vulkan() -> bool:
    return any(Path(d, f).is_file() for d in GPU_ICD_DIRS for f in GPU_ICDS) or bool(
        os.environ.get("VK_ICD_FILENAMES") or os.environ.get("VK_DRIVER_FILES"))


def sidecar_env() -> dict[str, str]:
    """Environment for a sidecar that renders with SAPIEN: the software driver, unless this machine has a
    GPU's Vulkan driver or the user chose one; empty when the driver is not provisioned."""
    icd = installed()
    if icd is None or _gpu_vulkan():
        return {}
    lib = str(icd.parent / LIB_DIR)
    return {"VK_ICD_FILENAMES": str(icd),
            "LD_LIBRARY_PATH": os.pathsep.join(p for p in (lib, os.environ.get("LD_LIBRARY_PATH", "")) if p)}


def _apt(args: list[str], work: Path) -> subprocess.CompletedProcess:
    (work / "sources").mkdir(exist_ok=True)
    (work / "lists" / "partial").mkdir(parents=True, exist_ok=True)
    (work / "sources" / "software-vulkan.sources").write_text(SOURCES)
    opts = ["-o", "Dir::Etc::SourceList=/dev/null", "-o", f"Dir::Etc::SourceParts={work / 'sources'}",
            "-o", f"Dir::State::Lists={work / 'lists'}", "-o", "Debug::NoLocking=1"]
    return subprocess.run(["apt-get", *opts, *args], cwd=work, capture_output=True, text=True, timeout=600)


def provision(progress=print) -> Path:
    """Download and unpack the driver (idempotent); returns its ICD file. Needs Debian's apt and network
    once; raises ``RuntimeError`` naming what failed."""
    if (done := installed()) is not None:
        return done
    if shutil.which("apt-get") is None or shutil.which("dpkg") is None:
        raise RuntimeError("software Vulkan: needs Debian's apt-get and dpkg (this machine has neither)")
    root().mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=root()) as tmp:
        work = Path(tmp)
        for step in (["update", "-qq"], ["download", *(f"{p}/{SUITE}" for p in PACKAGES)]):
            out = _apt(step, work)
            if out.returncode != 0:
                raise RuntimeError(f"software Vulkan: apt-get {step[0]} failed: {out.stderr.strip()[-400:]}")
        debs = sorted(work.glob("*.deb"))
        version = next(d.name.split("_")[1] for d in debs if d.name.startswith("mesa-vulkan-drivers_"))
        unpack = work / "unpack"
        for deb in debs:
            subprocess.run(["dpkg", "-x", str(deb), str(unpack)], check=True, timeout=300)
        icd = json.loads((unpack / "usr/share/vulkan/icd.d" / ICD).read_text())
        final = root() / version.replace("~", "_")
        icd["ICD"]["library_path"] = str(final / LIB_DIR / "libvulkan_lvp.so")
        target = work / "tree"
        (target / LIB_DIR).mkdir(parents=True)
        for lib in (unpack / LIB_DIR).iterdir():
            if lib.name.startswith(("libvulkan_lvp", "libdrm")):
                shutil.copy2(lib, target / LIB_DIR / lib.name, follow_symlinks=False)
        (target / ICD).write_text(json.dumps(icd))
        shutil.rmtree(final, ignore_errors=True)
        os.replace(target, final)
    progress(f"software Vulkan: Mesa lavapipe {version} in {final}")
    return final / ICD


def main(argv: list[str] | None = None) -> int:
    try:
        provision(lambda s: print(f"[simseam] {s}"))
    except (RuntimeError, OSError, subprocess.SubprocessError) as exc:
        print(f"[simseam] {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
