"""An event of the run's SimPy environment that fires at ``now + delay`` with a given priority
and callback: what the network schedules (deliveries, flushes, the channel's wake-ups)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from simpy.events import Event


class Scheduled(Event):
    """An event that fires at ``now + delay`` with a given priority and callback."""

    def __init__(self, env: Any, callback: Callable[[Event], None], priority: int, delay: int = 0):
        super().__init__(env)
        self._ok = True
        self._value = None
        self.callbacks.append(callback)
        env.schedule(self, priority, delay)
