"""The MILLION episode protocol served as Gymnasium environments.

Env ids (all take the protocol options that `million_env.million.options` declares, with
their defaults, values and meanings; env-server/README.md has them as a table):

- ``million/ML1-{train,test}`` (kwarg ``task``, default 'reach-v3'),
  ``million/ML10-{train,test}``, ``million/ML45-{train,test}`` (kwarg ``tasks``, a subset
  of the split's classes): Meta-World v3.
- ``million/PointGoal`` (option ``num_goals`` 2|4|8): a point that must reach the
  goal named only in the instruction; the fast learning test.

Observation (Dict, this key order): ``state`` float64 (39; Meta-World's values,
zeros in instruction phases; PointGoal: x, y, then zeros; the diagnostic
``goal_in_state=True`` writes the real goal into its last three entries in trials),
``word`` float32 (50; GloVe 6B vector of the current word,
``goal_pos`` = [goal_x, goal_y, goal_z, 0...] (metres, or with ``goal_encoding='range'``
scaled from the task's goal range to [-1, 1]),
zeros in trials), ``time`` float32 (1), ``phase`` float32 (1; 1 = instruction),
``trial_success`` float32 (1; 1 once the current trial's success test has held, 0 in
instruction phases and at a trial's first observation),
``task_id`` Discrete (index in `million_env.metaworld_tasks.ALL_TASK_NAMES`;
PointGoal: always 0 of Discrete(1)), ``prev_reward`` float32 (1; only set without
instructions or with ``reward_in_obs=True``).
`million_env.million.protocol.observation_space` says more. Info fields are declared in
``metadata["info_fields"]``; see `million_env.million.protocol`.

`register_envs()` puts every id into Gymnasium's registry; `protocol_stats()`
reports process-wide counters (instruction tokens fed, unknown words).
``python -m million_env.million.check_instructions`` checks the shipped sentences.
"""

from __future__ import annotations

from million_env.million.registry import register_envs
from million_env.million.stats import protocol_stats

__all__ = ["protocol_stats", "register_envs"]
