"""Layer 9, results: metrics, files, the MCAP recording, plots, animations, the run log
and the status lines.
"""

from __future__ import annotations

__all__: list[str] = []
