"""Resource bounds checked before long work: a request that cannot fit in this machine's memory
is refused with the figures, instead of growing until the kernel kills it."""

from __future__ import annotations

import os

from common.errors import CrankError


class ResourceError(CrankError, ValueError):
    """A request needs more memory than this machine has available."""


def available_memory() -> int:
    """Bytes of memory available to a new allocation now (MemAvailable; total RAM if unknown)."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def check_memory(needed: float, *, what: str, available: int | None = None) -> None:
    """Refuse `what` if its estimated peak `needed` (bytes) exceeds the available memory.

    Raises:
      ResourceError: with both figures in GB.
    """
    have = available_memory() if available is None else available
    if needed > have:
        raise ResourceError(
            f"{what} needs about {needed / 1e9:.3g} GB of memory, this machine has "
            f"{have / 1e9:.3g} GB available"
        )
