"""A set that remembers the most recently added members only: what an agent knows of its peers
(agents/base.py) must not grow with every Dynamic and Cloud Agent a long-running Platform or Core
meets, each under a JID of its own."""
from __future__ import annotations

from collections import OrderedDict


class RecentSet:
    def __init__(self, maxlen: int):
        if maxlen < 1:
            raise ValueError(f"maxlen must be >= 1, not {maxlen}")
        self.maxlen = maxlen
        self._items: OrderedDict[str, None] = OrderedDict()

    def add(self, item: str) -> None:
        """Add `item`, or make it the most recent; the least recent goes once there are maxlen."""
        self._items[item] = None
        self._items.move_to_end(item)
        if len(self._items) > self.maxlen:
            self._items.popitem(last=False)

    def __contains__(self, item: object) -> bool:
        return item in self._items

    def __len__(self) -> int:
        return len(self._items)

    def __iter__(self):
        return iter(self._items)
