"""Shared by the benchmark scripts: the hardware line every benchmark prints."""

from __future__ import annotations

import os
import platform
from pathlib import Path


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def hardware_line() -> str:
    """CPU model, cores, load average and Python: enough to compare figures across runs."""
    load = os.getloadavg() if hasattr(os, "getloadavg") else (float("nan"),) * 3
    return (f"{cpu_model()}; {os.cpu_count()} cores; load avg {load[0]:.1f}/{load[1]:.1f}/{load[2]:.1f}; "
            f"{platform.python_implementation()} {platform.python_version()}")
