"""The shared cache of gain schedules of the constant model.

With the constant model the coarse and fine passes' covariance, gain and bias sensitivity do
not depend on the data: only on the configuration, the covariance a pass starts from and the
update steps since. Each such start is the root of a chain in this cache (a dict per step:
``step key -> (P, S, K, Sinv, next node)``), so a second run of the same configuration (the
next bag, the next Monte Carlo batch) reuses the whole schedule and a step costs one
dictionary look-up. Values derived from the same inputs (the fine pass's steady-state std)
are kept beside the chains. The cache is bounded: it is cleared when it would hold more than
``max_steps`` steps (about 1 kB each; a 10-minute bag at the default periods takes 1,200).
"""
from __future__ import annotations


class GainScheduleCache:
    """Chains of gain-schedule steps by their start, bounded by ``max_steps`` steps."""

    def __init__(self, max_steps: int = 20000):
        self.max_steps = max_steps
        self.size = 0                    # steps held
        self._entries: dict = {}

    def root(self, key) -> dict:
        """The first node of the chain that starts at ``key`` (made empty if new)."""
        return self._entries.setdefault(key, {})

    def get(self, key):
        """A value stored with :meth:`put` (None if absent)."""
        return self._entries.get(key)

    def put(self, key, value) -> None:
        self._entries[key] = value

    def make_room(self, steps: int) -> bool:
        """Clear the cache if ``steps`` more would not fit; True when it was cleared (the
        caller's nodes then belong to no chain any more)."""
        if self.size + steps > self.max_steps:
            self.clear()
            return True
        return False

    def added(self, steps: int) -> None:
        """Count ``steps`` new steps (linked by the caller into a chain)."""
        self.size += steps

    def clear(self) -> None:
        self._entries.clear()
        self.size = 0


#: the cache every AlignmentFilter uses unless given another one
SHARED_SCHEDULES = GainScheduleCache()
