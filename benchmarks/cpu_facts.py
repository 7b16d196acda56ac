"""The machine facts that move a CPU-bound figure, for the benchmarks' JSON (Linux; absent facts are None).

- ``topology()``: the CPU model, logical CPUs this process may use, physical cores under them (SMT
  siblings share one), threads per core, sockets / NUMA nodes, the hypervisor, the frequency governor
  and its limits.
- ``CpuWindow``: what the CPUs did while a measurement ran, from ``/proc/stat`` and ``/proc/loadavg``
  read before and after: the share of the usable CPUs that was busy, the share stolen by the hypervisor
  (neighbours on the host), the share spent by processes outside this process tree (neighbours on the
  machine), the load average, and the mean current frequency (MHz) at the end; and where this process
  ran (the CPUs it was seen on, and whether another busy process shared its physical core is not
  knowable from here: only the CPU numbers are kept).

    with CpuWindow() as w:
        run()
    facts = w.facts()
"""

from __future__ import annotations

import os
import platform
import resource
import subprocess
from pathlib import Path

SYS_CPU = Path("/sys/devices/system/cpu")


def _read(path: Path) -> str | None:
    try:
        return path.read_text().strip()
    except OSError:
        return None


def _lscpu() -> dict[str, str]:
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, timeout=10, env={**os.environ, "LC_ALL": "C"})
    except (OSError, subprocess.SubprocessError):
        return {}
    return {k.strip(): v.strip() for k, _, v in (line.partition(":") for line in out.stdout.splitlines()) if v}


def _cores(cpus: list[int]) -> dict[int, tuple[str | None, str | None]]:
    """cpu -> (package, core id): SMT siblings share one pair."""
    return {c: (_read(SYS_CPU / f"cpu{c}/topology/physical_package_id"), _read(SYS_CPU / f"cpu{c}/topology/core_id"))
            for c in cpus}


def topology() -> dict:
    cpus = sorted(os.sched_getaffinity(0))
    cores = _cores(cpus)
    known = [v for v in cores.values() if None not in v]
    lscpu = _lscpu()
    governors = {_read(SYS_CPU / f"cpu{c}/cpufreq/scaling_governor") for c in cpus} - {None}
    return {
        "model": lscpu.get("Model name"), "logical_cpus": os.cpu_count(), "usable_cpus": len(cpus),
        "physical_cores_usable": len(set(known)) if len(known) == len(cpus) else None,
        "threads_per_core": lscpu.get("Thread(s) per core"), "sockets": lscpu.get("Socket(s)"),
        "numa_nodes": lscpu.get("NUMA node(s)"), "hypervisor": lscpu.get("Hypervisor vendor"),
        "smt_active": _read(SYS_CPU / "smt/active"),
        "siblings": sorted({_read(SYS_CPU / f"cpu{c}/topology/thread_siblings_list") for c in cpus} - {None}),
        "governor": sorted(governors) or None,
        "max_mhz": lscpu.get("CPU max MHz"), "min_mhz": lscpu.get("CPU min MHz"),
        "platform": platform.platform(), "python": platform.python_version(),
    }


def _stat() -> dict[int, list[int]]:
    """cpu -> jiffies (user nice system idle iowait irq softirq steal ...) from /proc/stat."""
    out = {}
    for line in Path("/proc/stat").read_text().splitlines():
        head, *vals = line.split()
        if head.startswith("cpu") and head != "cpu":
            out[int(head[3:])] = [int(v) for v in vals[:8]]
    return out


def _mhz(cpus: list[int]) -> float | None:
    vals = [_read(SYS_CPU / f"cpu{c}/cpufreq/scaling_cur_freq") for c in cpus]
    if all(v is not None for v in vals) and vals:
        return sum(int(v) for v in vals) / len(vals) / 1000
    found = [float(line.split(":")[1]) for line in Path("/proc/cpuinfo").read_text().splitlines()
             if line.startswith("cpu MHz")]
    return sum(found) / len(found) if found else None


def _own_cpu_s() -> float:
    """CPU seconds of this process and its waited-for children (the measurement's own processes)."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def _this_cpu() -> int | None:
    """The CPU this process last ran on (/proc/self/stat's 39th field)."""
    text = _read(Path("/proc/self/stat"))
    return None if text is None else int(text.rsplit(")", 1)[1].split()[36])


class CpuWindow:
    """``with CpuWindow(): ...`` then ``facts()`` (see the module docstring). Children must have been waited
    for before ``__exit__`` for their CPU time to count as the measurement's own; time of children still
    running counts as the neighbours'."""

    def __enter__(self) -> "CpuWindow":
        self.cpus = sorted(os.sched_getaffinity(0))
        self.load_before = os.getloadavg()
        self.own0, self.stat0 = _own_cpu_s(), _stat()
        self.on_cpu = {_this_cpu()} - {None}
        return self

    def __exit__(self, *exc) -> None:
        self.stat1, self.own1 = _stat(), _own_cpu_s()
        self.load_after = os.getloadavg()
        self.mhz = _mhz(self.cpus)
        self.on_cpu |= {_this_cpu()} - {None}

    def facts(self) -> dict:
        hz = os.sysconf("SC_CLK_TCK")
        d = [[b - a for a, b in zip(self.stat0[c], self.stat1[c])] for c in self.cpus if c in self.stat0]
        total = sum(sum(x) for x in d) or 1
        busy = sum(x[0] + x[1] + x[2] + x[5] + x[6] for x in d)
        steal = sum(x[7] for x in d if len(x) > 7)
        others = busy / hz - (self.own1 - self.own0)
        return {
            "busy_share": round(busy / total, 3), "steal_share": round(steal / total, 4),
            "others_cpu_share": round(max(0.0, others) * hz / total, 3),
            "load_before": [round(x, 2) for x in self.load_before], "load_after": [round(x, 2) for x in self.load_after],
            "mhz_end": None if self.mhz is None else round(self.mhz), "parent_cpus": sorted(self.on_cpu),
        }
