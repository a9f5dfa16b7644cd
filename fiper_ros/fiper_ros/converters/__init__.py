"""Rollout data in the reference datasets' layouts -> core :class:`~fiper_ros.core.rollout.Rollout` records
(``fiper convert``, :mod:`fiper_ros.commands.convert`; docs/bags.md).

- :mod:`.fiper`: FIPER rollout pickles. :mod:`.sentinel`: Sentinel episode DataFrames.
- :mod:`.generic`: rollout logs (npz, parquet, pickle) with named keys.
- :mod:`.options`: what a conversion takes and returns, shared by the three.
"""
from __future__ import annotations

__all__ = ["fiper", "generic", "options", "sentinel"]
