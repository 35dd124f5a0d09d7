"""PointGoal: a point in the plane that must reach the goal named in the instruction.

The small instruction-following task of the learning test. `num_goals` goals sit
on a circle around the start; the state holds only the point's position (padded
to 39 values), so the goal is known only from the instruction's goal word. An
agent that ignores the words reaches the named goal in about 1/num_goals of first
trials; one that follows them in nearly all.

Task ids: PointGoal is one task family, so `task_id` is always 0 (Discrete(1));
the goal index is deliberately not exposed, since it would reveal the goal.
Task names are the goal names (e.g. "north"), which key the instruction sentences.
"""

from __future__ import annotations

import math

import gymnasium
import numpy as np
import numpy.typing as npt

from million_env.errors import invalid
from million_env.metaworld_tasks import parse_task_order
from million_env.million.task_source import STATE_DIM
from million_env.rendering import blank, draw_disc

#: Distance of every goal from the origin.
GOAL_RADIUS = 0.6
#: The trial succeeds once the point is this close to the named goal.
SUCCESS_DISTANCE = 0.1
#: Largest move per env step along each axis (action 1.0).
MAX_SPEED = 0.15
#: Half-width of the square in which a trial's start position is drawn.
START_SPREAD = 0.05
#: Reward added at the step that reaches the goal.
SUCCESS_BONUS = 1.0
#: The plane is clipped to [-ARENA, ARENA]^2.
ARENA = 1.0


class PointGoalTask:
    """One goal of PointGoal; each trial starts near the origin.

    Reward per env step: the progress towards the goal, (d_before - d_after) /
    GOAL_RADIUS, plus SUCCESS_BONUS at every step within the success distance. With
    PointGoal's default `end_on_success=True` a success ends the trial, the progress
    term is potential based and the return of a trial does not grow by lingering, so
    succeeding is always worth more than hovering near the goal (with
    `end_on_success=False` the bonus is paid at each step spent at the goal).
    """

    def __init__(
        self, name: str, goal_xy: npt.NDArray[np.float64], rng: np.random.Generator
    ) -> None:
        self._name = name
        self._goal = np.array([goal_xy[0], goal_xy[1], 0.0], dtype=np.float64)
        self._rng = rng
        self._pos = np.zeros(2, dtype=np.float64)

    @property
    def name(self) -> str:
        return self._name

    @property
    def task_id(self) -> int:
        return 0

    def _state(self) -> npt.NDArray[np.float64]:
        state = np.zeros(STATE_DIM, dtype=np.float64)
        state[:2] = self._pos
        return state

    def _distance(self) -> float:
        return math.hypot(self._pos[0] - self._goal[0], self._pos[1] - self._goal[1])

    def reset(self) -> npt.NDArray[np.float64]:
        self._pos = self._rng.uniform(-START_SPREAD, START_SPREAD, size=2)
        return self._state()

    def step(self, action: npt.NDArray[np.float32]) -> tuple[npt.NDArray[np.float64], float, bool]:
        before = self._distance()
        move = np.clip(np.asarray(action[:2], dtype=np.float64), -1.0, 1.0) * MAX_SPEED
        self._pos = np.clip(self._pos + move, -ARENA, ARENA)
        after = self._distance()
        success = after < SUCCESS_DISTANCE
        reward = (before - after) / GOAL_RADIUS + (SUCCESS_BONUS if success else 0.0)
        return self._state(), reward, success

    def goal(self) -> npt.NDArray[np.float64]:
        return self._goal.copy()

    def goal_range(self) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        # The goals sit on a circle around the origin: its bounding box.
        return (
            np.array([-GOAL_RADIUS, -GOAL_RADIUS, 0.0]),
            np.array([GOAL_RADIUS, GOAL_RADIUS, 0.0]),
        )

    def render(self, width: int, height: int, camera: str, cache: object) -> npt.NDArray[np.uint8]:
        """A top view of the arena, north up: the goal circle (grey), the goal's success
        disc (green) and the point (blue). There are no cameras (`camera` must be "")."""
        if camera:
            raise invalid("PointGoal is drawn from above and has no cameras; leave camera empty")
        frame = blank(width, height, (250, 250, 250))
        scale_x, scale_y = width / (2 * ARENA), height / (2 * ARENA)

        def pixel(x: float, y: float) -> tuple[float, float]:
            return (x + ARENA) * scale_x, (ARENA - y) * scale_y

        cx, cy = pixel(0.0, 0.0)
        draw_disc(frame, cx, cy, GOAL_RADIUS * min(scale_x, scale_y), (200, 200, 200), ring=True)
        gx, gy = pixel(self._goal[0], self._goal[1])
        draw_disc(frame, gx, gy, SUCCESS_DISTANCE * min(scale_x, scale_y), (60, 170, 80))
        px, py = pixel(self._pos[0], self._pos[1])
        draw_disc(frame, px, py, max(3.0, 0.04 * min(scale_x, scale_y)), (40, 90, 200))
        return frame


class PointGoalSource:
    """Samples one of `goal_names` (goal k at angle 2*pi*k/len(goal_names))."""

    def __init__(self, goal_names: tuple[str, ...], task_order: str = "random") -> None:
        if len(goal_names) < 2:
            raise ValueError("PointGoal needs at least two goals")
        self._cycle = parse_task_order(task_order)
        self._next_goal = 0
        self._names = goal_names
        angles = [2.0 * math.pi * k / len(goal_names) for k in range(len(goal_names))]
        self._goals = [
            np.array([GOAL_RADIUS * math.cos(a), GOAL_RADIUS * math.sin(a)]) for a in angles
        ]
        self._rng = np.random.default_rng()
        # Same 4-d action layout as Meta-World; only the first two entries move the point.
        self._action_space = gymnasium.spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32)

    @property
    def action_space(self) -> gymnasium.spaces.Box:
        return self._action_space

    @property
    def num_task_ids(self) -> int:
        return 1

    @property
    def task_names(self) -> tuple[str, ...]:
        return self._names

    @property
    def max_steps_per_reset(self) -> int:
        # The point has no time limit of its own.
        return 2**62

    def seed(self, seed: int) -> None:
        self._rng = np.random.default_rng(seed)
        self._next_goal = seed % len(self._names)

    def sample(self) -> PointGoalTask:
        if self._cycle:
            k = self._next_goal
            self._next_goal = (k + 1) % len(self._names)
        else:
            k = int(self._rng.integers(len(self._names)))
        return PointGoalTask(self._names[k], self._goals[k], self._rng)

    def close(self) -> None:
        """Nothing to free: the point is plain numpy state."""
