"""One line naming the machine a benchmark ran on, printed above each table so that
every figure copied into docs/benchmarks.md says where it was measured."""
from __future__ import annotations

import os
import platform


def describe() -> str:
    """CPU model and count, memory, OS, and the Python/NumPy/SciPy versions."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            cpu = next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    mem = ""
    try:
        mem = f", {os.sysconf('SC_PAGE_SIZE') * os.sysconf('SC_PHYS_PAGES') / 2**30:.0f} GiB"
    except (ValueError, OSError, AttributeError):
        pass
    libs = []
    for name in ("numpy", "scipy"):
        try:
            libs.append(f"{name} {__import__(name).__version__}")
        except ImportError:
            pass
    return (f"Machine: {os.cpu_count()} x {cpu}{mem}, {platform.system()} {platform.release()}, "
            f"Python {platform.python_version()}, {', '.join(libs)}")
