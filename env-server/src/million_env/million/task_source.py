"""What the MILLION protocol needs from the environment it wraps.

A task source samples tasks; a sampled task is one MDP (class + goal) that can be
reset for each trial and stepped one env step at a time. Meta-World and PointGoal
both provide this, so the protocol code is shared.
"""

from __future__ import annotations

from typing import Protocol

import gymnasium
import numpy as np
import numpy.typing as npt

#: Length of the `state` observation: Meta-World v3's 39 values; other sources pad.
STATE_DIM = 39


class SampledTask(Protocol):
    """One task (class + goal) of a source."""

    @property
    def name(self) -> str:
        """The task's name, which is also the key of its instruction sentences."""
        ...

    @property
    def task_id(self) -> int:
        """The task's id in the source's fixed id range (0 .. num_task_ids - 1)."""
        ...

    def reset(self) -> npt.NDArray[np.float64]:
        """Resets the MDP for a new trial with the same goal; returns the (39,) state."""
        ...

    def step(self, action: npt.NDArray[np.float32]) -> tuple[npt.NDArray[np.float64], float, bool]:
        """One env step: (state (39,), reward, success at this step)."""
        ...

    def goal(self) -> npt.NDArray[np.float64]:
        """The real goal position (3,), valid after `reset`; what `goal_pos` encodes."""
        ...

    def goal_range(self) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """Low and high corners (3,) of the task's goal box (Meta-World: the env's
        `goal_space`). For reach-like tasks the goals are drawn from it; for tasks whose
        target follows an object (button-press, drawer-close, ...) it only bounds the hand,
        so `instruction_goal="reflected"` is a meaningful wrong goal for the former only."""
        ...


class TaskSource(Protocol):
    """Samples the task of each episode."""

    @property
    def action_space(self) -> gymnasium.spaces.Box: ...

    @property
    def num_task_ids(self) -> int:
        """Size of the task id range (the `task_id` observation is Discrete(num_task_ids))."""
        ...

    @property
    def task_names(self) -> tuple[str, ...]:
        """The names of the tasks this source samples."""
        ...

    @property
    def max_steps_per_reset(self) -> int:
        """Env steps the MDP allows after one reset (a trial may not be longer)."""
        ...

    def seed(self, seed: int) -> None:
        """Makes the sequence of sampled tasks and their MDPs deterministic."""
        ...

    def sample(self) -> SampledTask:
        """Samples the next task; `reset` has not been called on it yet."""
        ...

    def close(self) -> None: ...
