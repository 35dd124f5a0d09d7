"""The MILLION episode protocol as one Gymnasium env over a task source.

An episode: sample a task and one of its sentences; an instruction phase feeds the
sentence one word per step (action ignored, reward 0); then a trial runs the MDP
with action repeat for `trial_len` env steps, and succeeds if the task's success test
held at any of them (`end_on_success=True`: the trial ends at that step). A failed
trial is followed by a new instruction phase with another sentence of the same task; a
successful one directly by the next trial. After `trials` trials the episode is
`terminated`; trial boundaries are not terminal. The MDP is reset between trials
with the same task and goal.

Observation timing: the step that ends a trial (not the last) already returns the
first observation of what follows (a word, or the next trial's reset state), so
every agent step is a real decision or a real word. The last trial's final step
returns the trial's final state with `terminated`.

The options (`trials`, `trial_len`, `end_on_success`, the ablations and diagnostics) are
declared, with their defaults and checks, in `million_env.million.options`; the observation
keys are described at `observation_space`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium
import numpy as np
import numpy.typing as npt

from million_env.errors import precondition, unimplemented
from million_env.info_fields import InfoField
from million_env.million.glove import EMBED_DIM
from million_env.million.instructions import (
    EncodedInstruction,
    InstructionEncoder,
    with_word_noise,
)
from million_env.million.options import ProtocolOptions
from million_env.million.task_source import STATE_DIM, SampledTask, TaskSource

#: `goal_encoding="range"` is made for reach-like tasks, whose goals are drawn from the goal
#: range; an axis narrower than this each side counts as a point and maps to 0, so
#: sub-centimetre jitter (hand-insert's z, ±1e-4 m) is not blown up to full scale.
_POINT_HALF_WIDTH = 0.005
#: Where `goal_in_state` writes the real goal: the state's last three entries, where a
#: goal-observable Meta-World v3 task (MT1) shows it and where ML1/ML10 write zeros.
GOAL_STATE_SLICE = slice(STATE_DIM - 3, STATE_DIM)
# Second entropy word of the sentence generator's seed (any constant != task streams).
_SENTENCE_STREAM = 0x5E47E4CE
# Second entropy word of the word-noise generator (`word_noise`), apart from the sentences.
_WORD_NOISE_STREAM = 0x0715E
PHASE_INSTRUCTION = "instruction"
PHASE_TRIAL = "trial"


INFO_FIELDS: tuple[InfoField, ...] = (
    InfoField(
        "success",
        "bool",
        (),
        "true at the step that ended a successful trial (its success test held at some step)",
    ),
    InfoField("trial_end", "bool", (), "true at the step that ended a trial"),
    InfoField(
        "trial",
        "int64",
        (),
        "index of the trial the observation belongs to or whose instruction it shows (0-based)",
    ),
    InfoField("trial_successes", "int64", (), "successful trials so far in this episode"),
    InfoField("phase", "str", (), "phase of the observation: 'instruction' or 'trial'"),
    InfoField("task_name", "str", (), "the episode's task, e.g. 'reach-v3' (PointGoal: goal name)"),
    InfoField("task_id", "int64", (), "the task id also given in the observation"),
    InfoField(
        "instruction", "str", (), "the current instruction sentence ('' without instructions)"
    ),
    InfoField("token", "str", (), "the word in the observation ('' in trials)"),
    InfoField("steps_in_trial", "int64", (), "env steps taken in the current trial"),
    InfoField(
        "steps_to_success",
        "int64",
        (),
        "env steps the trial took until its success test first held, -1 while it has not; at "
        "the step that ends a trial, that trial's (how soon, where `success` says only whether)",
    ),
    InfoField("episode_step", "int64", (), "agent steps taken in this episode"),
    InfoField(
        "goal",
        "float64",
        (3,),
        "the task's real goal position (what goal_pos encodes); for evaluation, not the policy",
    ),
)


def observation_space(num_task_ids: int) -> gymnasium.spaces.Dict:
    """The protocol's observation layout, in this key order for every source.

    - ``state``: the MDP's 39 values in trials (PointGoal: x, y, then zeros), zeros in
      instruction phases.
    - ``word``: the GloVe vector of the instruction word fed (``goal_pos``: the goal),
      zeros in trials.
    - ``time``: the trial's elapsed fraction (0 in instruction phases), or with
      ``time_obs="episode"`` the episode's.
    - ``phase``: 1 in instruction phases, 0 in trials.
    - ``trial_success``: 1 once the trial's success test has held at some env step of the
      current trial (from the observation after that step on, while the trial goes on);
      0 before, in instruction phases and at each trial's first observation. The original
      code's trial flag: a full-length trial (`end_on_success=False`) runs on after its
      success, and without it the value of a solved trial looks like an unsolved one's.
    - ``task_id``: the task's index in the source's id range (PointGoal: always 0).
    - ``prev_reward``: the previous step's reward with ``instructions=False`` or
      ``reward_in_obs=True`` (0 after an instruction phase's steps), else 0.
    """
    inf = np.inf
    return gymnasium.spaces.Dict(
        [
            ("state", gymnasium.spaces.Box(-inf, inf, shape=(STATE_DIM,), dtype=np.float64)),
            ("word", gymnasium.spaces.Box(-inf, inf, shape=(EMBED_DIM,), dtype=np.float32)),
            ("time", gymnasium.spaces.Box(0.0, 1.0, shape=(1,), dtype=np.float32)),
            ("phase", gymnasium.spaces.Box(0.0, 1.0, shape=(1,), dtype=np.float32)),
            ("trial_success", gymnasium.spaces.Box(0.0, 1.0, shape=(1,), dtype=np.float32)),
            ("task_id", gymnasium.spaces.Discrete(num_task_ids)),
            ("prev_reward", gymnasium.spaces.Box(-inf, inf, shape=(1,), dtype=np.float32)),
        ]
    )


class MillionEnv(gymnasium.Env[dict[str, Any], npt.NDArray[np.float32]]):
    """MILLION episodes over any `TaskSource` (Meta-World benchmarks, PointGoal), run as
    `options` say (`million_env.million.options`; None: the general defaults).

    Info fields are declared in `metadata["info_fields"]` (and `info_fields`) as the
    server's `InfoField` (name, dtype name or "str", shape, description); every reset
    and step sets all of them.
    """

    metadata: dict[str, Any] = {"render_modes": [], "info_fields": INFO_FIELDS}  # noqa: RUF012
    info_fields: tuple[InfoField, ...] = INFO_FIELDS

    def __init__(
        self,
        source: TaskSource,
        sentences: Mapping[str, Sequence[str]],
        options: ProtocolOptions | None = None,
    ) -> None:
        # Options are validated when `options` is built; what is checked here needs the source.
        options = ProtocolOptions() if options is None else options
        trial_len = options.trial_len
        if trial_len > source.max_steps_per_reset:
            raise ValueError(
                f"trial_len {trial_len} exceeds the {source.max_steps_per_reset} env steps "
                "the environment allows after a reset"
            )
        missing = [name for name in source.task_names if not sentences.get(name)]
        if missing:
            raise ValueError(f"no instruction sentences for tasks {missing}")

        self.options = options
        self._source = source
        self._sentences = {name: tuple(sentences[name]) for name in source.task_names}
        self._encoder = InstructionEncoder()
        self._instructions = options.instructions
        # The ablation's token carries the previous reward; reward_in_obs gives it beside the
        # words, to tell what the words add from what the reward adds.
        self._reward_in_obs = options.reward_in_obs or not options.instructions
        self._reflect_goal = options.instruction_goal == "reflected"
        self._goal_in_range = options.goal_encoding == "range"
        self._goal_in_state = options.goal_in_state
        self._end_on_success = options.end_on_success
        self._word_noise = float(options.word_noise)
        self._episode_time = options.time_obs == "episode"
        self._action_repeat = options.action_repeat
        self._trials = options.trials
        self._trial_len = trial_len
        self.observation_space = observation_space(source.num_task_ids)
        self.action_space = source.action_space

        longest = max(len(s.split()) for group in self._sentences.values() for s in group)
        agent_steps_per_trial = math.ceil(trial_len / self._action_repeat)
        words = longest if self._instructions else 0
        #: Upper bound on agent steps per episode; the denominator of episode time.
        self.max_episode_steps = self._trials * (words + agent_steps_per_trial)

        self._task: SampledTask | None = None
        self._state = np.zeros(STATE_DIM, dtype=np.float64)
        self._instruction: EncodedInstruction | None = None
        self._word_index = 0
        self._phase = PHASE_TRIAL
        self._trial = 0
        self._trial_successes = 0
        self._steps_in_trial = 0
        self._trial_succeeded = False
        self._steps_to_success = -1
        self._episode_step = 0
        self._prev_reward = 0.0
        self._done = False
        self._sentence_rng = np.random.default_rng()
        self._noise_rng = np.random.default_rng()

    # ------------------------------------------------------------------ gymnasium

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, Any]]:
        super().reset(seed=seed)
        if seed is not None:
            self._source.seed(seed)
            # A stream of its own: the source seeds its generator with `seed` too,
            # and sharing that stream would tie the sentence choice to the task choice.
            self._sentence_rng = np.random.default_rng([seed, _SENTENCE_STREAM])
            self._noise_rng = np.random.default_rng([seed, _WORD_NOISE_STREAM])
        self._task = self._source.sample()
        self._instruction = None
        self._trial = 0
        self._trial_successes = 0
        self._episode_step = 0
        self._prev_reward = 0.0
        self._done = False
        # The MDP is reset before the first instruction so goal_pos is the real goal.
        self._begin_trial_mdp()
        self._begin_instruction_or_trial()
        return self._observation(), self._info(success=False, trial_end=False, steps_to_success=-1)

    def step(
        self, action: npt.NDArray[np.float32]
    ) -> tuple[dict[str, Any], float, bool, bool, dict[str, Any]]:
        if self._task is None or self._done:
            raise RuntimeError("step() needs reset() first (at start and after termination)")
        self._episode_step += 1
        success = trial_end = terminated = False
        reward = 0.0
        steps_to_success = -1
        if self._phase == PHASE_INSTRUCTION:
            # The action is ignored and the reward is 0 while words are fed.
            self._word_index += 1
            assert self._instruction is not None
            if self._word_index >= len(self._instruction.tokens):
                self._phase = PHASE_TRIAL
        else:
            reward, succeeded_now = self._act(self._checked_action(action))
            self._trial_succeeded |= succeeded_now
            # Read now: a trial that ends at this step gives way to the next one below.
            steps_to_success = self._steps_to_success
            ended_by_success = succeeded_now and self._end_on_success
            if ended_by_success or self._steps_in_trial >= self._trial_len:
                trial_end = True
                success = self._trial_succeeded
                self._trial += 1
                self._trial_successes += int(success)
                if self._trial >= self._trials:
                    terminated = self._done = True
                    # The final observation stays in the last trial.
                    self._trial = self._trials - 1
                else:
                    self._begin_trial_mdp()
                    if not success:
                        self._begin_instruction_or_trial()
        self._prev_reward = reward
        return (
            self._observation(),
            reward,
            terminated,
            False,
            self._info(success=success, trial_end=trial_end, steps_to_success=steps_to_success),
        )

    def close(self) -> None:
        self._source.close()
        super().close()

    def render_rgb(self, width: int, height: int, camera: str, cache: Any) -> Any:
        """An RGB frame of the current trial's MDP (`million_env.rendering`): during an
        instruction phase, the reset state the next trial starts from."""
        if self._task is None:
            raise precondition("render needs a reset first")
        render = getattr(self._task, "render", None)
        if render is None:
            raise unimplemented(f"tasks of {type(self._source).__name__} cannot render")
        return render(width, height, camera, cache)

    @property
    def task_names(self) -> tuple[str, ...]:
        """The tasks this env samples from (a benchmark split, or PointGoal's goals)."""
        return self._source.task_names

    @property
    def current_task(self) -> SampledTask:
        """The task of the current episode (evaluation and tests read its goal)."""
        if self._task is None:
            raise RuntimeError("no task before the first reset()")
        return self._task

    # ------------------------------------------------------------------ phases

    def _begin_trial_mdp(self) -> None:
        assert self._task is not None
        self._state = self._task.reset()
        self._steps_in_trial = 0
        self._trial_succeeded = False
        self._steps_to_success = -1
        self._phase = PHASE_TRIAL

    def _begin_instruction_or_trial(self) -> None:
        if not self._instructions:
            self._phase = PHASE_TRIAL
            return
        assert self._task is not None
        instruction = self._encoder.encode(self._next_sentence(), self._named_goal())
        if self._word_noise > 0.0:
            instruction = with_word_noise(instruction, self._word_noise, self._noise_rng)
        self._instruction = instruction
        self._word_index = 0
        self._phase = PHASE_INSTRUCTION

    def _named_goal(self) -> npt.NDArray[np.float64]:
        """What `goal_pos` encodes: the goal `instruction_goal` names, written as
        `goal_encoding` says. Info's `goal` stays the real goal in metres."""
        assert self._task is not None
        goal = self._task.goal()
        if not (self._reflect_goal or self._goal_in_range):
            return goal
        low, high = self._task.goal_range()
        if self._reflect_goal:
            goal = low + high - goal
        if self._goal_in_range:
            half = (high - low) / 2.0
            wide = half >= _POINT_HALF_WIDTH
            scaled = (goal - (low + half)) / np.where(wide, half, 1.0)
            goal = np.where(wide, np.clip(scaled, -1.0, 1.0), 0.0)
        return goal

    def _next_sentence(self) -> str:
        assert self._task is not None
        choices = self._sentences[self._task.name]
        if self._instruction is not None and len(choices) > 1:
            # A re-instruction tries another wording, as a human teacher would.
            choices = tuple(s for s in choices if s != self._instruction.text) or choices
        return choices[int(self._sentence_rng.integers(len(choices)))]

    def _act(self, action: npt.NDArray[np.float32]) -> tuple[float, bool]:
        """Steps the MDP `action_repeat` times (fewer at the trial's end): the summed reward
        and whether the success test held at any of the steps."""
        assert self._task is not None
        reward = 0.0
        succeeded = False
        repeats = min(self._action_repeat, self._trial_len - self._steps_in_trial)
        for _ in range(repeats):
            self._state, step_reward, success = self._task.step(action)
            self._steps_in_trial += 1
            reward += step_reward
            succeeded |= success
            if success and self._steps_to_success < 0:
                self._steps_to_success = self._steps_in_trial
            if success and self._end_on_success:
                # The trial ends at the env step that succeeds.
                break
        return reward, succeeded

    def _checked_action(self, action: Any) -> npt.NDArray[np.float32]:
        checked = np.asarray(action, dtype=self.action_space.dtype)
        if checked.shape != self.action_space.shape:
            raise ValueError(
                f"action must have shape {self.action_space.shape}, got {checked.shape}"
            )
        if not np.all(np.isfinite(checked)):
            raise ValueError("action must be finite")
        return checked

    # ------------------------------------------------------------------ output

    def _time(self) -> float:
        if self._episode_time:
            return min(1.0, self._episode_step / self.max_episode_steps)
        if self._phase == PHASE_INSTRUCTION:
            return 0.0
        return self._steps_in_trial / self._trial_len

    def _observation(self) -> dict[str, Any]:
        assert self._task is not None
        if self._phase == PHASE_INSTRUCTION:
            assert self._instruction is not None
            state = np.zeros(STATE_DIM, dtype=np.float64)
            word = self._instruction.vectors[self._word_index].copy()
            phase = 1.0
            trial_success = 0.0
        else:
            state = np.array(self._state, dtype=np.float64)
            if self._goal_in_state:
                # Diagnostic: the goal in plain view, as MT1 shows it
                # (docs/experiments/2026-12-02-goal-in-state.md).
                state[GOAL_STATE_SLICE] = self._task.goal()
            word = np.zeros(EMBED_DIM, dtype=np.float32)
            phase = 0.0
            # Reset with the trial's MDP, so a trial's first observation always shows 0.
            trial_success = float(self._trial_succeeded)
        prev_reward = self._prev_reward if self._reward_in_obs else 0.0
        return {
            "state": state,
            "word": word,
            "time": np.array([self._time()], dtype=np.float32),
            "phase": np.array([phase], dtype=np.float32),
            "trial_success": np.array([trial_success], dtype=np.float32),
            "task_id": np.int64(self._task.task_id),
            "prev_reward": np.array([prev_reward], dtype=np.float32),
        }

    def _info(self, *, success: bool, trial_end: bool, steps_to_success: int) -> dict[str, Any]:
        assert self._task is not None
        in_instruction = self._phase == PHASE_INSTRUCTION
        token = ""
        if in_instruction:
            assert self._instruction is not None
            token = self._instruction.tokens[self._word_index]
        return {
            "success": success,
            "trial_end": trial_end,
            "trial": self._trial,
            "trial_successes": self._trial_successes,
            "phase": self._phase,
            "task_name": self._task.name,
            "task_id": self._task.task_id,
            "instruction": self._instruction.text if self._instruction is not None else "",
            "token": token,
            "steps_in_trial": self._steps_in_trial,
            "steps_to_success": steps_to_success,
            "episode_step": self._episode_step,
            "goal": self._task.goal(),
        }
