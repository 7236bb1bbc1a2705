"""Gymnasium env over the same episode loop the evaluator uses.

    import gymnasium as gym
    import robobpp  # any robobpp import registers robobpp/Pack-v0
    env = gym.make("robobpp/Pack-v0", dataset="repetitive", setting="math")

(or ``gym.make("robobpp.env:robobpp/Pack-v0", ...)`` with no import at all).

Episodes: each ``reset`` draws one group of the split, seeded by the reset's seed (``options={"group": g}`` picks
one); without ``groups`` any of the split's groups, with ``groups=N`` the first N, drawn when a reset needs it.

Observation: ``heightmap`` (cm, float32, the container's 1 cm grid as one image channel: shape (1, nx, ny), which
stable-baselines3 takes for an image), ``box`` (length, width, height, mass of the box to place) and, with
``lookahead=N > 0``, ``lookahead`` (the next N boxes, zero-padded; absent at the default ``lookahead=0``: an empty
(0, 4) array breaks stable-baselines3's observation handling). Every array returned, observations and masks, is a
new one: later steps never change what an agent kept. Action, by default
(``actions="flat"``): one Discrete index ``(x * ny + y) * 2 + orientation`` over the container's grid; with
``actions="grid"`` an ``(x, y, orientation)`` MultiDiscrete.

The candidate space (``actions="candidates"``, ``candidates=K``, 50 by default), as the paper's learned methods act:
one Discrete index into a list of at most K candidate placements for the box (:mod:`robobpp.policies.candidate_space`:
the reference PCT's leaf nodes, floor corners of the empty maximal spaces, seeded by the episode), whose features
are the observation's ``candidates`` (K rows of ``candidate_space.FEATURES``, zero-padded); ``action_masks()``
admits exactly the candidates. Every setting offers it. 33,500 grid actions become K: a learner's policy is small
and each action is a sensible placement (a greedy rule over the candidates, lowest then nearest the corner, packs
Repetitive as DBL does). The trade: a placement that is no leaf cannot be chosen, and an episode ends when no
candidate is left, which on 20 Repetitive train groups never happened while the grid had a feasible cell.

Masks, for masked RL: ``action_mask()`` is the boolean (x, y, orientation) grid of feasible actions — what the
environment accepts, in every setting, as the reference's: the box inside the container and its top below the
container height; ``action_masks()`` is the same in the action space's layout (what sb3-contrib's MaskablePPO
calls), and ``info["action_masks"]`` carries it after every reset and step. With the default flat space that is
the flattened grid: exact, every action it admits is feasible. With ``actions="grid"`` it can only be one mask per
dimension (x, then y, then orientation values that occur in some feasible action): a superset, and an agent that
draws each dimension from its mask, as MaskablePPO does, combines them into infeasible actions (measured with
``bench/bench_env_masks.py``: 50 of 50 masked random episodes ended on one, after 7.3 steps on average, and 0 of
50 with the flat default, after 31.1); the env warns when made so.

``support_mask()`` narrows the feasible actions to those the reference's support rule accepts on the observed
state — extra information a policy may use (the reference's PCT restricts its candidates to it in Physics and
Execution Pack), never enforced. On a Math Pack state it equals the action mask (no rule there, as in the
reference). It tests every position, up to about a second per step late in a physical episode, so it is computed
only when asked; ``support_info=True`` also puts it in ``info["support_mask"]`` (same layout as
``info["action_masks"]``) after every reset and step.

When no placement is feasible for the next box the episode ends there: ``terminated=True`` and
``info["termination"] == "no_feasible_placement"``, recorded like a policy's "no feasible placement". The step
that ends an episode also carries its figures as the evaluator computes them: ``info["metrics"]`` (every metric
the setting reports), ``info["boxes_placed"]`` and ``info["termination_detail"]``.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from robobpp import GYM_ENV_ID
from robobpp.core import ORIENTATIONS, Action, Box, ContainerState, EpisodeSpec, Observation
from robobpp.core.feasible_grid import FeasibleGrids, feasible_grid
from robobpp.episode import POLICY_ERROR, Episode
from robobpp.policies.candidate_space import DEFAULT_CANDIDATES, FEATURES, Candidates, CandidateSpace
from robobpp.policies.candidates import candidate_maps
from robobpp.scoring import metrics as M

ENV_ID = GYM_ENV_ID
#: How many groups an env without ``groups`` draws from: every group index a 31-bit draw gives (a group is a
#: seeded draw from the split's pool, so the index only seeds it).
ALL_GROUPS = 2**31
#: Largest box dimension or mass the observation space admits (cm / kg); datasets stay far below.
_MAX_BOX = 1000.0

RewardFn = Callable[[Episode, Any], float]
#: The action spaces an env offers (module docstring).
ACTION_SPACES = ("flat", "candidates", "grid")


def volume_reward(episode: Episode, record: Any) -> float:
    """Default reward: the placed box's volume as a fraction of the container (0 when not placed)."""
    if record.placement is None:
        return 0.0
    box = record.box
    reward: float = box["length"] * box["width"] * box["height"] / episode.spec.container.volume
    return reward


def stability_shaped_reward(episode: Episode, record: Any) -> float:
    """The paper's training reward (Physics/Execution): 10·volume ratio + 0.01·static stability − mean offset."""
    from robobpp.sim.physics.reward import stability_reward  # the one definition, beside the simulator

    offsets = (M.local_stability_m(episode.setting.final_boxes()) or 0.0,)
    return stability_reward(volume_reward(episode, record), record.static_stability, offsets)


REWARDS: dict[str, RewardFn] = {"volume": volume_reward, "stability": stability_shaped_reward}


def heightmap_channel(heightmap: np.ndarray, height: float) -> np.ndarray:
    """A heightmap as the env observes it: a new (1, nx, ny) float32 array (one image channel), clipped to the
    container's height (a heightmap is never below 0: it starts at the floor and only takes maxima)."""
    out = heightmap.astype(np.float32)[None]
    return np.minimum(out, np.float32(height), out=out)


class _Channel:
    """The observation's heightmap channel for one state after another, each a new array: kept in float32 and
    brought up to date from the blocks the state raised since (``ContainerState.raises``, as the feasible grid
    is), so a step copies it instead of converting the whole heightmap; rebuilt for a new state or heightmap.
    A raised block is copied from the state's heightmap as it is now (so several raises in any order end right),
    clipped only once some cell has gone above the container's height: the channel is exactly the whole
    heightmap converted (rounding to float32 and clipping commute)."""

    def __init__(self, height: float) -> None:
        self.height = height
        self._top = np.float32(height)
        # the state, its heightmap array, and the channel kept for them
        self._kept: tuple[ContainerState, np.ndarray, np.ndarray] | None = None
        self._seen = 0
        self._clip = False  # whether a cell of the kept state went above the container's height

    def __call__(self, state: ContainerState) -> np.ndarray:
        kept = self._kept
        if kept is not None and kept[0] is state and kept[1] is state.heightmap:
            channel = kept[2]
            heightmap = state.heightmap
            for x0, x1, y0, y1, top in state.raises[self._seen :]:
                block = channel[0, x0:x1, y0:y1]
                block[...] = heightmap[x0:x1, y0:y1]
                self._clip = self._clip or top > self.height
                if self._clip:
                    np.minimum(block, self._top, out=block)
        else:
            channel = heightmap_channel(state.heightmap, self.height)
            self._kept = (state, state.heightmap, channel)
            self._clip = bool(state.heightmap.max(initial=0.0) > self.height)
        self._seen = len(state.raises)
        return channel.copy()


def encode_observation(
    obs: Observation, lookahead: int, candidates: Candidates | None = None
) -> dict[str, np.ndarray]:
    """The env's observation of a policy :class:`Observation` (a trained agent acts on the same arrays); new
    arrays, never views of the simulator's state; with ``candidates`` (the candidate space's list for this box)
    their features as ``candidates``."""
    channel = heightmap_channel(obs.heightmap, obs.container.height)
    return _encoded(channel, obs.box, obs.lookahead, lookahead, candidates)


def _encoded(
    channel: np.ndarray,
    box: Box,
    upcoming: Sequence[Box],
    lookahead: int,
    candidates: Candidates | None,
) -> dict[str, np.ndarray]:
    encoded = {
        "heightmap": channel,
        "box": np.array([box.length, box.width, box.height, box.mass], np.float32),
    }
    if lookahead > 0:  # no key at all without lookahead (module docstring)
        look = np.zeros((lookahead, 4), np.float32)
        for i, b in enumerate(upcoming[:lookahead]):
            look[i] = (b.length, b.width, b.height, b.mass)
        encoded["lookahead"] = look
    if candidates is not None:
        encoded["candidates"] = candidates.features.copy()
    return encoded


def feasible_mask(obs: Observation, supported: bool = False) -> np.ndarray:
    """Boolean (x, y, orientation) grid of the feasible actions for the observation's box: inside the container
    and below its top; ``supported`` also applies the support rule of the observed state."""
    if not supported:
        return feasible_grid(obs.heightmap, obs.box, obs.container)
    nx, ny = obs.container.grid_shape
    mask = np.zeros((nx, ny, len(ORIENTATIONS)), bool)
    for cand in candidate_maps(obs):
        grid = cand.support_mask
        cx, cy = grid.shape
        mask[:cx, :cy, cand.orientation] = grid
    return mask


class PackEnv(gym.Env[dict[str, np.ndarray], np.ndarray]):
    metadata = {"render_modes": []}

    def __init__(
        self,
        dataset: str = "repetitive",
        setting: str = "math",
        split: str = "train",
        groups: int | None = None,
        lookahead: int = 0,
        reward: str = "volume",
        specs: Sequence[EpisodeSpec] | None = None,
        data_seed: int = 0,
        actions: str = "flat",
        support_info: bool = False,
        candidates: int = DEFAULT_CANDIDATES,
    ) -> None:
        if reward not in REWARDS:
            raise ValueError(f"unknown reward {reward!r}; expected one of {', '.join(REWARDS)}")
        if actions not in ACTION_SPACES:
            raise ValueError(
                f"unknown actions {actions!r}; expected 'flat' (the default), 'candidates' (at most K candidate "
                "placements) or 'grid' (x, y, orientation)"
            )
        if actions == "grid":
            warnings.warn(
                'actions="grid": the action mask of a MultiDiscrete space is one mask per dimension, a superset '
                "of the feasible actions; an agent drawing each dimension from it (MaskablePPO) picks infeasible "
                'combinations. actions="flat" (the default) masks exactly.',
                UserWarning,
                stacklevel=2,
            )
        # Without ``specs`` each reset draws its group on demand (``GroupDraw``): any of the split's groups by
        # default, the first ``groups`` with it; nothing is drawn ahead (10,000 groups cost seconds to draw).
        self._draw: Callable[[int], EpisodeSpec] | None = None
        if specs is None:
            from robobpp.datasets.sampling import GroupDraw

            if groups is not None and (isinstance(groups, bool) or not isinstance(groups, int) or groups < 1):
                raise ValueError(f"groups must be an integer >= 1 or None (every group), got {groups!r}")
            draw = GroupDraw(dataset, split, data_seed)
            self._draw = draw
            self.groups = ALL_GROUPS if groups is None else groups
            self.specs: list[EpisodeSpec] = []
            container = draw.spec.container
        else:
            if not specs:
                raise ValueError("the env needs at least one episode spec")
            self.specs = list(specs)
            self.groups = len(self.specs)
            container = self.specs[0].container
            if any(s.container != container for s in self.specs):
                raise ValueError("all episode specs of one env must share a container")
        self.setting_name = setting
        self.lookahead = lookahead
        self.reward_fn = REWARDS[reward]
        self.container = container
        nx, ny = container.grid_shape
        observed: dict[str, spaces.Space[Any]] = {
            "heightmap": spaces.Box(0.0, float(container.height), (1, nx, ny), np.float32),
            "box": spaces.Box(0.0, _MAX_BOX, (4,), np.float32),
        }
        if lookahead > 0:
            observed["lookahead"] = spaces.Box(0.0, _MAX_BOX, (lookahead, 4), np.float32)
        # The candidate space: one Discrete index per candidate, its features in the observation.
        self._space = CandidateSpace(candidates) if actions == "candidates" else None
        self._candidates: Candidates | None = None
        if self._space is not None:
            observed["candidates"] = spaces.Box(0.0, 1.0, (candidates, len(FEATURES)), np.float32)
        # gymnasium types a Dict space as holding dicts of spaces; its samples are dicts of arrays
        self.observation_space = spaces.Dict(observed)  # type: ignore[assignment]
        self.grid_shape = (nx, ny, len(ORIENTATIONS))
        self.actions = actions
        self.flat_actions = actions == "flat"
        self.action_space: spaces.Space[Any] = (
            spaces.Discrete(nx * ny * len(ORIENTATIONS))
            if self.flat_actions
            else spaces.Discrete(candidates)
            if self._space is not None
            else spaces.MultiDiscrete(list(self.grid_shape))
        )
        self._episode: Episode | None = None
        self._box: Box | None = None  # the box to place now (None: the episode is over)
        self._observation: Observation | None = None  # its policy observation, built when first needed
        self._grids = FeasibleGrids(container)  # the grid mask, kept up to date box after box
        self._channel = _Channel(container.height)  # the heightmap channel, likewise
        self._grid_mask: np.ndarray | None = np.zeros(self.grid_shape, bool)
        self._feasible = False  # whether the action space admits any action for the current box
        self._support_mask: np.ndarray | None = None  # computed when first asked, per observation
        self.support_info = support_info

    @property
    def _obs(self) -> Observation | None:
        """The policy observation of the box to place (None when the episode is over), built when first asked:
        the flat and grid spaces read the state's heightmap directly."""
        if self._observation is None and self._box is not None:
            assert self._episode is not None
            self._observation = self._episode.observe()
        return self._observation

    def _encode(self) -> dict[str, np.ndarray]:
        assert self._episode is not None
        channel = self._channel(self._episode.setting.state())
        if self._box is not None:
            next_index = self._episode.index + 1
            upcoming = self._episode.spec.boxes[next_index : next_index + self.lookahead]
            return _encoded(channel, self._box, upcoming, self.lookahead, self._candidates)
        terminal = {  # the final heightmap, no box
            "heightmap": channel,
            "box": np.zeros(4, np.float32),
        }
        if self.lookahead > 0:
            terminal["lookahead"] = np.zeros((self.lookahead, 4), np.float32)
        if self._space is not None:
            terminal["candidates"] = np.zeros((self._space.limit, len(FEATURES)), np.float32)
        return terminal

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        super().reset(seed=seed)
        if self._episode is not None:
            self._episode.setting.close()
        index = (options or {}).get("group")
        if index is None:
            index = int(self.np_random.integers(self.groups))
        spec = self._draw(int(index)) if self._draw is not None else self.specs[int(index)]
        self._episode = Episode(spec, self.setting_name, lookahead=self.lookahead)
        if self._space is not None:
            self._space.reset(spec.container, spec.episode_id)
        self._observe()
        info = {"episode_id": spec.episode_id, "action_masks": self.action_masks()}
        if self.support_info:
            info["support_mask"] = self._layout(self.support_mask())
        return self._encode(), info

    def _observe(self) -> None:
        """The next box's observation and its feasible actions (computed once, read by every mask call); in the
        candidate space its candidates, and the grid mask only when asked."""
        assert self._episode is not None
        episode = self._episode
        self._box = None if episode.done else episode.spec.boxes[episode.index]
        self._observation = None
        self._support_mask = None
        if self._space is not None:
            obs = self._obs
            self._candidates = None if obs is None else self._space(obs)
            self._grid_mask = None
            self._feasible = self._candidates is not None and bool(self._candidates.mask.any())
            return
        self._grid_mask = None
        self._feasible = bool(self._mask.any())  # the grid space needs its mask at once

    @property
    def _mask(self) -> np.ndarray:
        """The grid of feasible actions for the current box (computed once per box, when first needed)."""
        if self._grid_mask is None:
            self._grid_mask = (
                np.zeros(self.grid_shape, bool)
                if self._box is None or self._episode is None
                else self._grids(self._episode.setting.state(), self._box)
            )
        return self._grid_mask

    def _grid_action(self, action: Any) -> tuple[int, int, int] | None:
        """The action as (x, y, orientation); None for a candidate index that names no candidate."""
        nx, ny, no = self.grid_shape
        if self.flat_actions and isinstance(action, int | np.integer) and 0 <= action < nx * ny * no:
            cell, orientation = divmod(int(action), no)  # the usual case, without numpy
            x, y = divmod(cell, ny)
            return x, y, orientation
        values = np.asarray(action).reshape(-1)
        if self._candidates is not None:
            if values.size != 1 or not 0 <= int(values[0]) < len(self._candidates.mask):
                raise ValueError(
                    f"action must be one candidate index in [0, {len(self._candidates.mask)}); got {action!r}"
                )
            chosen = self._candidates.action(int(values[0]))
            return None if chosen is None else (int(chosen.x), int(chosen.y), chosen.orientation)
        if self.flat_actions:
            if values.size != 1:
                raise ValueError(
                    f"action must be one index into the flat action space; got {values.size} values"
                )
            return tuple(int(v) for v in np.unravel_index(int(values[0]), self.grid_shape))  # type: ignore[return-value]
        if values.size != 3:  # a flat index into the mask is the usual slip; say what is expected
            raise ValueError(
                f"action must be (x, y, orientation), e.g. np.array([x, y, o]) from "
                f"np.argwhere(env.unwrapped.action_mask()); got {values.size} value(s)"
            )
        x, y, orientation = (int(v) for v in values)
        return x, y, orientation

    def step(self, action: Any) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        assert self._episode is not None and self._box is not None, "call reset() first"
        chosen = self._grid_action(action)
        reward = 0.0
        info: dict[str, Any] = {"placed": False}
        if chosen is None:  # a masked-out candidate slot: nothing to place, as a policy's invalid answer
            self._episode.end(
                POLICY_ERROR, f"action {int(np.asarray(action).reshape(-1)[0])} names no candidate"
            )
            self._box, self._candidates = None, None
        elif self._feasible:
            x, y, orientation = chosen
            record = self._episode.step(Action(float(x), float(y), orientation), decision_time=0.0)
            reward = float(self.reward_fn(self._episode, record))
            info["placed"] = record.placement is not None
            self._observe()
        if not self._episode.done and not self._feasible:
            # Nothing fits the next box: end here as the evaluator does when a policy answers None.
            self._episode.step(None, decision_time=0.0)
            self._box, self._candidates = None, None
        terminated = self._episode.done
        if terminated:
            figures = self._episode.figures()
            info["termination"] = figures.termination.reason
            info["termination_detail"] = figures.termination.detail
            info["boxes_placed"] = figures.boxes_placed
            info["metrics"] = dict(figures.metrics)
        info["action_masks"] = self.action_masks()
        if self.support_info:
            info["support_mask"] = self._layout(self.support_mask())
        return self._encode(), reward, terminated, False, info

    def action_mask(self) -> np.ndarray:
        """Boolean (x, y, orientation) mask of feasible actions for the current box (all False when done)."""
        return self._mask.copy()

    def action_masks(self) -> np.ndarray:
        """The mask in the action space's layout, as sb3-contrib's MaskablePPO expects it (module docstring)."""
        if self._space is not None:
            return (
                np.zeros(self._space.limit, bool)
                if self._candidates is None
                else self._candidates.mask.copy()
            )
        return self._layout(self._mask)

    def support_mask(self) -> np.ndarray:
        """Boolean (x, y, orientation) mask of the feasible actions the support rule accepts (module docstring)."""
        if self._support_mask is None:
            obs = self._obs
            self._support_mask = (
                feasible_mask(obs, supported=True)
                if obs is not None and self._feasible
                else self._mask.copy()
            )
        return self._support_mask.copy()

    def _layout(self, mask: np.ndarray) -> np.ndarray:
        """A grid mask in the action space's layout: flattened, or one mask per MultiDiscrete dimension; in the
        candidate space, which candidates it admits."""
        if self._candidates is not None:
            layout: np.ndarray = (
                np.array([bool(mask[tuple(p)]) for p in self._candidates.placements]) & self._candidates.mask
            )
            return layout
        if self.flat_actions:
            return mask.reshape(-1).copy()
        return np.concatenate([mask.any(axis=(1, 2)), mask.any(axis=(0, 2)), mask.any(axis=(0, 1))])

    def close(self) -> None:
        if self._episode is not None:
            self._episode.setting.close()
            self._episode = None


def register_envs() -> None:
    """Register ``robobpp/Pack-v0`` (idempotent; ``import robobpp`` already does it)."""
    from robobpp import register_gym_envs

    register_gym_envs()


register_envs()
