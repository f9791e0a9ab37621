"""Layer 3, the problem data: scenarios (:mod:`.scenario`, read by :mod:`.scenario_file`),
references, obstacles, the plant's specification, generated fleets and the paths
between samples.
"""

from __future__ import annotations

__all__: list[str] = []
