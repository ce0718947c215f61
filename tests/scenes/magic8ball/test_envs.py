"""corpuscle.envs: the Gymnasium environments over a batch of 8-balls. Gymnasium's own
checker passes on the single environment; the vector environment keeps Gymnasium's vector
contract: batched spaces, observations in them, a reward only for the target face at an
episode's end, terminated per scene, NEXT_STEP autoreset (the step after an episode's end
resets that scene and ignores its action), partial resets by mask, action validation."""
import numpy as np
import pytest

pytest.importorskip("corpuscle._core")
gym = pytest.importorskip("gymnasium")

from gymnasium.utils.env_checker import check_env
from gymnasium.vector import AutoresetMode, VectorEnv

from corpuscle.envs import OBSERVATION_COLUMNS, Magic8BallEnv, Magic8BallVectorEnv

SMALL = dict(particles=200, settle=0.0, episode_time=0.03, control_period=0.01, backend="serial")


@pytest.mark.filterwarnings("ignore:.*Box observation space (minimum|maximum) value:UserWarning")
def test_gymnasium_checker_passes_on_the_single_env():
    env = Magic8BallEnv(**SMALL)
    check_env(env, skip_render_check=True)
    obs, _ = env.reset(seed=5)
    assert obs.shape == (len(OBSERVATION_COLUMNS),) and obs.dtype == np.float32


def test_vector_env_spaces_and_an_episode():
    env = Magic8BallVectorEnv(num_envs=3, target_face=[1, 3, 6], **SMALL)
    assert isinstance(env, VectorEnv) and env.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    assert env.action_space.shape == (3, 6) and env.observation_space.shape == (3, 14)
    obs, info = env.reset(seed=1)
    assert env.observation_space.contains(obs) and np.all(obs[:, -1] == 0.0)
    act = env.action_space.sample()
    for k in range(3):
        obs, rew, term, trunc, info = env.step(act)
        assert env.observation_space.contains(obs)
        assert rew.shape == term.shape == trunc.shape == (3,) and term.dtype == bool
        np.testing.assert_allclose(info["time"], 0.01 * (k + 1), rtol=1e-12)
        if k < 2:
            assert not term.any() and not rew.any()
    # the last step: terminated everywhere, reward 1 exactly where the target face shows
    assert term.all() and not trunc.any()
    assert rew.tolist() == [float(f == t) for f, t in zip(info["answer_face"], [1, 3, 6])]
    # NEXT_STEP: the next step resets every finished scene and ignores its action
    obs, rew, term, trunc, info = env.step(np.ones((3, 6), np.float32))
    assert not term.any() and not trunc.any() and not rew.any()
    assert info["time"].tolist() == [0.0, 0.0, 0.0] and np.all(obs[:, -1] == 0.0)
    obs, rew, term, trunc, info = env.step(np.zeros((3, 6), np.float32))
    np.testing.assert_allclose(info["time"], 0.01, rtol=1e-12)


def test_reward_follows_the_target_face():
    # the same scenes with every target: exactly one target rewards each scene
    rewards = []
    for face in range(1, 7):
        env = Magic8BallVectorEnv(num_envs=2, target_face=face, seed=3, **SMALL)
        env.reset(seed=9)
        for _ in range(3):
            _, rew, term, _, info = env.step(np.zeros((2, 6), np.float32))
        rewards.append(rew)
    assert np.array_equal(np.sum(rewards, axis=0), [1.0, 1.0])


def test_partial_reset_and_bad_input():
    env = Magic8BallVectorEnv(num_envs=2, **SMALL)
    env.reset(seed=0)
    env.step(np.zeros((2, 6), np.float32))
    obs, _ = env.reset(options={"reset_mask": np.array([True, False])})
    assert obs[0, -1] == 0.0 and obs[1, -1] == pytest.approx(1 / 3)
    with pytest.raises(ValueError, match=r"actions must be a \(2, 6\) array"):
        env.step(np.zeros((2, 5), np.float32))
    with pytest.raises(ValueError, match=r"actions\[1, 0\] \(acceleration_x\) must be finite"):
        env.step(np.array([[0] * 6, [np.nan] + [0] * 5], np.float32))
    with pytest.raises(ValueError, match="reset_mask"):
        env.reset(options={"reset_mask": [1, 0]})
    for kw, msg in ((dict(target_face=7), "target_face"), (dict(num_envs=0), "num_envs"),
                    (dict(episode_time=0.025), "whole number of control periods"),
                    (dict(max_torque=-1), "max_torque must be a positive number")):
        with pytest.raises(ValueError, match=msg):
            Magic8BallVectorEnv(**{**SMALL, "num_envs": 2, **kw})


def test_actions_are_clipped_to_the_box_and_scaled():
    env = Magic8BallVectorEnv(num_envs=2, max_acceleration=10.0, max_torque=0.02, **SMALL)
    env.reset(seed=0)
    env.step(np.array([[5.0, -0.5, 0, 0, 0, 3.0], [0] * 6], np.float32))
    # the same as the batch given acceleration 10 (clipped), -5 m/s² and torque 0.02 N·m
    env2 = Magic8BallVectorEnv(num_envs=2, max_acceleration=10.0, max_torque=0.02, **SMALL)
    env2.reset(seed=0)
    env2.batch.set_control(np.array([[10.0, -5.0, 0, 0, 0, 0.02], [0] * 6], np.float32))
    env2.batch.advance(0.01)
    a, b = env.batch.observations(like="numpy"), env2.batch.observations(like="numpy")
    assert np.array_equal(a["die_position"], b["die_position"])
