"""The failed-goal buffer (FGB) of HER-CS: a ring of the most recent failed desired goals.

A refit is due once `capacity` failed goals have been added since the last fit (the paper's
"when the FGB is filled with entirely new FGs"): with capacity 150, at the 150th, 300th, …
failed goal, each fit on goals the previous one never saw. The authors' code refits one goal
earlier (docs/DESIGN.md §9.4).
"""

from __future__ import annotations

import numpy as np


class FailedGoalBuffer:
    """Ring of the last `capacity` failed goals, with the count added since the last fit."""

    def __init__(self, capacity: int = 150, *, goal_dim: int = 3) -> None:
        if capacity < 1:
            raise ValueError(f"FailedGoalBuffer capacity: got {capacity!r}, must be >= 1")
        if goal_dim < 1:
            raise ValueError(f"FailedGoalBuffer goal_dim: got {goal_dim!r}, must be >= 1")
        self.capacity = int(capacity)
        self.goal_dim = int(goal_dim)
        self._goals = np.zeros((self.capacity, self.goal_dim), np.float32)
        self._next = 0
        """Slot the next goal goes to; the oldest goal once the ring is full."""
        self._size = 0
        self.total_added = 0
        """Failed goals ever added."""
        self.new_since_fit = 0
        """Failed goals added since the last `mark_fitted()` (or since creation)."""

    def __len__(self) -> int:
        return self._size

    def add(self, goal: np.ndarray) -> None:
        """Append one failed desired goal (goal_dim,), overwriting the oldest when full."""
        goal = np.asarray(goal, dtype=np.float32)
        if goal.shape != (self.goal_dim,) or not np.all(np.isfinite(goal)):
            raise ValueError(f"FailedGoalBuffer.add: got {goal!r}, must be a finite "
                             f"({self.goal_dim},) vector")
        self._goals[self._next] = goal
        self._next = (self._next + 1) % self.capacity
        self._size = min(self._size + 1, self.capacity)
        self.total_added += 1
        self.new_since_fit += 1

    @property
    def refit_due(self) -> bool:
        """True once the ring is full and entirely replaced since the last fit."""
        return self._size == self.capacity and self.new_since_fit >= self.capacity

    def mark_fitted(self) -> None:
        """Record that a model was fitted on the current contents."""
        self.new_since_fit = 0

    def goals(self) -> np.ndarray:
        """Stored goals, oldest first, shape (len, goal_dim) float32 (a copy)."""
        if self._size < self.capacity:
            return self._goals[: self._size].copy()
        return np.roll(self._goals, -self._next, axis=0)
