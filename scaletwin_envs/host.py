"""The machine a run or a benchmark ran on: processor, CPU model and widest SIMD set, core count, platform;
and the code version (git revision) it ran.

The CPU matters for reproduction: float32 BLAS kernels differ between instruction sets, so a fit repeats bit for
bit on the same kind of CPU and only to rounding (which long fits amplify) on another.
"""

from __future__ import annotations

import os
import platform
import subprocess
from pathlib import Path
from typing import Any

#: x86 SIMD extensions, widest first (the first present is reported)
SIMD_SETS = ("avx512f", "avx2", "avx", "sse4_2")
#: Environment variable naming the commit of a tree copied without its git metadata (a cluster node, a lent
#: machine that receives the working tree only): :func:`git_revision` reports it where git cannot tell.
REVISION_ENV = "SCALETWIN_REVISION"


def cpu() -> tuple[str, str]:
    """CPU model name and widest x86 SIMD extension from ``/proc/cpuinfo`` ("unknown" where it is not readable)."""
    try:
        info = Path("/proc/cpuinfo").read_text(encoding="utf-8")
    except OSError:
        return "unknown", "unknown"
    fields = {k.strip(): v.strip() for k, v in (line.split(":", 1) for line in info.splitlines() if ":" in line)}
    flags = set(fields.get("flags", "").split())
    return fields.get("model name", "unknown"), next((f for f in SIMD_SETS if f in flags), "unknown")


def host() -> dict[str, Any]:
    """Where it ran: platform, processor, CPU model, widest SIMD set, number of CPUs."""
    cpu_model, simd = cpu()
    return {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
            "cpu_model": cpu_model, "simd": simd, "cpus": os.cpu_count()}


def host_line() -> str:
    """One line for result headers, e.g. ``x86_64 AMD EPYC (avx512f), 2 CPUs, Linux-...``."""
    h = host()
    return f"{h['processor']} {h['cpu_model']} ({h['simd']}), {h['cpus']} CPUs, {h['platform']}"


def git_revision(root: str | Path | None = None) -> str:
    """The commit checked out at ``root`` (default: this package's checkout), ``+dirty`` when tracked files have
    changes (read-only git calls). Outside git: the commit named by :data:`REVISION_ENV`, marked as such, or
    ``unknown``. Where :data:`REVISION_ENV` names another commit than git finds, the named one comes first and git's
    beside it: a copy of a tree sent to another machine can carry an older repository with it (a lent machine
    reported the session's first commit, ``+dirty``, for a tree three commits later)."""
    cwd = Path(root) if root is not None else Path(__file__).resolve().parents[1]
    given = os.environ.get(REVISION_ENV, "").strip()
    try:
        rev = subprocess.run(["git", "rev-parse", "--short=12", "HEAD"], cwd=cwd, capture_output=True, text=True,
                             timeout=10, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=cwd,
                               capture_output=True, text=True, timeout=10, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return f"{given} (copied without git, {REVISION_ENV})" if given else "unknown"
    found = rev + ("+dirty" if dirty else "")
    if given and not (rev.startswith(given) or given.startswith(rev)):
        return f"{given} (named by {REVISION_ENV}; git here: {found})"
    return found
