"""Gymnasium environments over :class:`corpuscle.Batch`: rig the Magic 8-Ball.

Needs the optional ``[rl]`` extra (``pip install corpuscle[rl]``: Gymnasium).

:class:`Magic8BallVectorEnv` is a :class:`gymnasium.vector.VectorEnv` of ``num_envs``
8-balls stepped together in one batch. An episode starts from the settled ball (the batch's
reset cache, turned by a random symmetry so every face is equally likely up) and lasts
``episode_time`` seconds of simulated time, in ``episode_time / control_period`` steps; an
action holds for one control period:

- action (6 floats in [-1, 1], clipped to it): the container's linear acceleration (3) and
  the torque on its shell (3) as fractions of ``max_acceleration`` (m/s²) and ``max_torque``
  (N·m);
- observation (14 float32): die position (3, m), orientation (4, w x y z), velocity (3,
  m/s), angular velocity (3, rad/s, container frame), and the episode's elapsed fraction;
- reward: 1 at the episode's last step when the face toward the window (+z) is
  ``target_face``, else 0;
- terminated: at the episode's last step (the reading is taken); truncated: a scene whose
  simulation went unsound (numerically unstable) is cut off, with reward 0;
- autoreset: ``AutoresetMode.NEXT_STEP`` (Gymnasium's default): the step after a scene's
  episode ended resets that scene, ignores its action and returns its first observation
  with reward 0, terminated and truncated False. ``reset(options={"reset_mask": mask})``
  resets only the chosen scenes.

:class:`Magic8BallEnv` is one such 8-ball as a plain :class:`gymnasium.Env` (a batch of
one, the same code), which Gymnasium's ``check_env`` checks.
"""
from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from .batch import Batch
from .kinds import CONTROL_BOUNDS

__all__ = ["Magic8BallVectorEnv", "Magic8BallEnv", "OBSERVATION_COLUMNS"]

#: what each column of an observation is
OBSERVATION_COLUMNS = ("die_x", "die_y", "die_z", "die_qw", "die_qx", "die_qy", "die_qz", "die_vx", "die_vy", "die_vz",
                       "die_wx", "die_wy", "die_wz", "episode_fraction")


def _bounded(control: str, value) -> float:
    """max_<control>: positive and within the control's bound (CONTROL_BOUNDS), as every
    entry point's."""
    v = _positive(f"max_{control}", value)
    bound, unit = CONTROL_BOUNDS[control]
    if v > bound:
        raise ValueError(f"max_{control} must be in (0, {bound:g}] {unit}, got {value!r}")
    return v


def _positive(name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a positive number, got {value!r}") from None
    if not (v > 0 and np.isfinite(v)):
        raise ValueError(f"{name} must be a positive number, got {value!r}")
    return v


class Magic8BallVectorEnv(VectorEnv):
    """``num_envs`` Magic 8-Balls to rig (see the module). Keyword arguments beyond the
    environment's own go to :meth:`corpuscle.Batch.from_scene` (``particles``, per-scene
    arrays, ``fluid__viscosity``, ``settle``, ``backend``, ...).

    With ``comm`` (an mpi4py communicator) the ``num_envs`` scenes are spread over its ranks
    (docs/distributed.md): each rank's environment steps its own block of them, so its
    ``num_envs``, spaces, observations and rewards are the rank's (``num_envs_total`` all of
    them, ``batch.scene_offset`` where its block starts; ``batch.gather_observations()``
    brings the batch's observations of every rank to one)."""

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(self, num_envs: int = 16, target_face=3, episode_time: float = 1.0, control_period: float = 0.05,
                 max_acceleration: float = 20.0, max_torque: float = 0.05, backend: str = "auto",
                 particles: int = 500, scene: str = "magic8ball", seed: int | None = None, **batch_kwargs):
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        self.num_envs = int(num_envs)
        targets = np.broadcast_to(np.asarray(target_face), (self.num_envs,))
        if targets.dtype.kind not in "iu" or np.any((targets < 1) | (targets > 6)):
            raise ValueError(f"target_face must be a face 1..6 (or one per scene), got {target_face!r}")
        self.target_face = targets.astype(np.int32).copy()
        self.episode_time = _positive("episode_time", episode_time)
        self.control_period = _positive("control_period", control_period)
        self.episode_steps = max(1, int(round(self.episode_time / self.control_period)))
        if abs(self.episode_steps * self.control_period - self.episode_time) > 1e-9 * self.episode_time:
            raise ValueError(f"episode_time ({episode_time}) must be a whole number of control periods "
                             f"({control_period})")
        #: an action's scale: m/s² (3) and N·m (3) at 1
        self.action_scale = np.array([_bounded("acceleration", max_acceleration)] * 3 +
                                     [_bounded("torque", max_torque)] * 3, dtype=np.float32)
        self.single_action_space = spaces.Box(-1.0, 1.0, shape=(6,), dtype=np.float32)
        batch_kwargs.setdefault("shake", [])  # the agent shakes; no scheduled shakes
        if seed is not None:
            batch_kwargs.setdefault("seed", int(seed))
        #: the batch of 8-balls (corpuscle.Batch)
        self.batch = Batch.from_scene(scene, n=self.num_envs, backend=backend, particles=particles, **batch_kwargs)
        self.num_envs_total = self.num_envs
        if self.batch.comm is not None:  # this rank's block of the scenes
            lo = self.batch.scene_offset
            self.num_envs = self.batch.n_scenes
            self.target_face = self.target_face[lo:lo + self.num_envs].copy()
        # positions within the container, unit quaternions, the elapsed fraction; velocities unbounded
        r = float(self.batch.params["radius"])
        high = np.array([r] * 3 + [1.0] * 4 + [np.inf] * 6 + [1.0], dtype=np.float32)
        low = -high
        low[-1] = 0.0
        self.single_observation_space = spaces.Box(low, high, dtype=np.float32)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._k = np.zeros(self.num_envs, dtype=np.int64)  # control steps taken this episode
        self._autoreset = np.zeros(self.num_envs, dtype=bool)
        self._zero = np.zeros((self.num_envs, 6), dtype=np.float32)

    # the Gymnasium API ----------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Every scene (or those of ``options["reset_mask"]``) back to the settled start."""
        batch = self._open_batch()
        super().reset(seed=seed)  # self.np_random from the seed
        if seed is not None:
            batch._rng = np.random.default_rng(seed if batch.comm is None else [seed, batch.scene_offset])
        mask = None if options is None else options.get("reset_mask")
        if mask is not None:
            mask = np.asarray(mask)
            if mask.dtype != bool or mask.shape != (self.num_envs,):
                raise ValueError(f"options['reset_mask'] must be {self.num_envs} booleans, got {mask!r}")
        ids = self.batch.reset(mask)
        self._k[ids] = 0
        self._autoreset[ids] = False
        self.batch.set_control(self._zero)
        return self._observe(), {}

    def step(self, actions):
        a = self._open_batch()._actions(actions)
        lo, hi = self.single_action_space.low, self.single_action_space.high
        a = np.clip(a, lo, hi) * self.action_scale
        # scenes whose episode ended last step restart now and hold still this step
        restart = self._autoreset.copy()
        if restart.any():
            self.batch.reset(restart)
            self._k[restart] = 0
            a[restart] = 0.0
        self.batch.set_control(a)
        self.batch.advance(np.where(restart, 0.0, self.control_period))
        self._k[~restart] += 1
        obs, raw = self._observe(raw=True)
        unsound = (raw["bad"] != 0) & ~restart
        terminated = (self._k >= self.episode_steps) & ~restart & ~unsound
        truncated = unsound
        reward = np.where(terminated & (raw["answer_face"] == self.target_face), 1.0, 0.0)
        self._autoreset = terminated | truncated
        infos = {"answer_face": raw["answer_face"].copy(), "time": raw["time"].copy()}
        return obs, reward.astype(np.float64), terminated, truncated, infos

    def close_extras(self, **kwargs):
        self.batch = None

    def _open_batch(self):
        """The batch, or a one-line RuntimeError once the environment is closed."""
        if self.batch is None:
            raise RuntimeError("the environment is closed (make a new one to step or reset)")
        return self.batch

    # observations ---------------------------------------------------------------------
    def _observe(self, raw: bool = False):
        o = self.batch.observations(like="numpy")
        frac = (self._k / self.episode_steps).astype(np.float32)[:, None]
        obs = np.concatenate([o["die_position"], o["die_orientation"], o["die_velocity"], o["die_angular_velocity"],
                              frac], axis=1).astype(np.float32)
        return (obs, o) if raw else obs


class Magic8BallEnv(gym.Env):
    """One Magic 8-Ball to rig, as a :class:`gymnasium.Env` (a :class:`Magic8BallVectorEnv`
    of one scene; the same arguments but ``num_envs``)."""

    metadata = {"render_modes": []}

    def __init__(self, **kwargs):
        kwargs.pop("num_envs", None)
        self.vec = Magic8BallVectorEnv(num_envs=1, **kwargs)
        self.action_space = self.vec.single_action_space
        self.observation_space = self.vec.single_observation_space

    def close(self):
        self.vec.close()

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        self.vec._open_batch()
        super().reset(seed=seed)
        obs, info = self.vec.reset(seed=seed)
        return obs[0], info

    def step(self, action):
        self.vec._open_batch()
        a = np.asarray(action, dtype=np.float32)
        if a.shape != (6,):
            raise ValueError(f"action must be 6 numbers, got shape {a.shape}")
        self.vec._autoreset[:] = False  # a plain Env is reset by its caller
        obs, reward, terminated, truncated, info = self.vec.step(a[None, :])
        return obs[0], float(reward[0]), bool(terminated[0]), bool(truncated[0]), {k: v[0] for k, v in info.items()}
