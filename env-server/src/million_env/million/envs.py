"""Entry points of the MILLION env ids (see `registry.py`)."""

from __future__ import annotations

from million_env.million.instructions import metaworld_instructions, point_goal_instructions
from million_env.million.metaworld_source import MetaWorldSource
from million_env.million.point_goal import PointGoalSource
from million_env.million.protocol import MillionEnv


def make_metaworld_million(
    benchmark: str,
    split: str,
    *,
    task: str | None = None,
    tasks: list[str] | None = None,
    instruction_set: str = "train",
    instructions: bool = True,
    time_obs: str = "trial",
    action_repeat: int = 2,
    trials: int = 3,
    trial_len: int = 200,
    task_order: str = "random",
    instruction_goal: str = "real",
    goal_encoding: str = "raw",
    goal_in_state: bool = False,
    end_on_success: bool = False,
    word_noise: float = 0.0,
    object_position: str = "task",
) -> MillionEnv:
    """MILLION episodes over a Meta-World v3 benchmark split (ML1 needs `task`; ML10 and ML45
    take `tasks`, a subset of the split's classes); trials run their full length (the
    original code; `million_env.million.protocol` says why). `object_position="centre"`
    puts reach-v3's puck at one place for every goal, so that its position no longer tells
    which of the split's goals an episode has."""
    sentences = metaworld_instructions(instruction_set)
    source = MetaWorldSource(
        benchmark,
        split,
        task=task,
        task_order=task_order,
        tasks=tasks,
        object_position=object_position,
    )
    try:
        return MillionEnv(
            source,
            sentences,
            instructions=instructions,
            time_obs=time_obs,
            action_repeat=action_repeat,
            trials=trials,
            trial_len=trial_len,
            instruction_goal=instruction_goal,
            goal_encoding=goal_encoding,
            goal_in_state=goal_in_state,
            end_on_success=end_on_success,
            word_noise=word_noise,
        )
    except Exception:
        source.close()
        raise


def make_point_goal_million(
    *,
    num_goals: int = 4,
    instruction_set: str = "train",
    instructions: bool = True,
    time_obs: str = "trial",
    action_repeat: int = 1,
    trials: int = 3,
    trial_len: int = 25,
    task_order: str = "random",
    instruction_goal: str = "real",
    goal_encoding: str = "raw",
    goal_in_state: bool = False,
    end_on_success: bool = True,
    word_noise: float = 0.0,
) -> MillionEnv:
    """MILLION episodes over PointGoal with `num_goals` (2, 4 or 8) compass goals; a trial
    ends at its success (its potential-based reward is made for that)."""
    if isinstance(num_goals, bool) or not isinstance(num_goals, int):
        raise ValueError(f"num_goals must be an integer, got {num_goals!r}")
    sentences = point_goal_instructions(instruction_set, num_goals)
    source = PointGoalSource(tuple(sentences), task_order=task_order)
    return MillionEnv(
        source,
        sentences,
        instructions=instructions,
        time_obs=time_obs,
        action_repeat=action_repeat,
        trials=trials,
        trial_len=trial_len,
        instruction_goal=instruction_goal,
        goal_encoding=goal_encoding,
        goal_in_state=goal_in_state,
        end_on_success=end_on_success,
        word_noise=word_noise,
    )
