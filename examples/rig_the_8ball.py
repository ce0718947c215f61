"""Rig the Magic 8-Ball: learn to shake it so that a chosen face shows in the window.

A cross-entropy method (CEM) over a linear feedback policy, evaluated on a batch of
independent 8-balls (corpuscle.envs.Magic8BallVectorEnv). Every episode starts from the
settled ball turned by a random symmetry, so each face is equally likely to be up at the
start. The policy maps the die's state to a shake each control period:

    action = clip(W @ [n x e_z, omega, 1], -1, 1)

where n is the target face's outward normal in the container frame (the die's orientation
applied to the face's body normal), e_z the window's direction and omega the die's angular
velocity: 3 x 7 weights for the shell torque and 3 x 7 for the container acceleration
(``--policy full``, the default: 42 numbers), or the torque alone (``--policy torque``: 21).
Why feedback and not an open-loop shake schedule: the cube is symmetric and the start is
uniform over its rotations, so a schedule that ignores the die gives every face the same 1/6
chance, however it is chosen.

Each CEM iteration samples `population` weight matrices from a Gaussian, runs each on
`scenes` 8-balls at once (one batch of population x scenes scenes), scores it by the mean
cosine between the target normal and the window at the episode's end (a smooth stand-in for
the 0/1 success), and refits the Gaussian to the best `elite` fraction. At the end the mean
policy, uniformly random shaking and no shaking each run one episode on every scene of the
batch; the success rate is the share that shows the target face.

CPU, small (minutes on two cores):
    python examples/rig_the_8ball.py --backend cpu
GPU (the lead's run; 4,096 scenes of 1,000 particles):
    python examples/rig_the_8ball.py --backend cuda --particles 1000 --population 256 --scenes 16 \
        --iterations 10 --dt-max 1.5e-3 --plot rig_gpu.png --json rig_gpu.json
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from corpuscle.batch import _rotate
from corpuscle.envs import Magic8BallVectorEnv
from corpuscle.kinds.magic8ball import DIE_FACES


def features(obs: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """[n x e_z, omega, 1] per scene: the target normal's tilt away from the window and the
    die's spin (n: the target face's normal in the container frame)."""
    q = obs[:, 3:7].astype(np.float64)
    n = _rotate(q, np.broadcast_to(normal, (len(obs), 3)))
    tilt = np.cross(n, [0.0, 0.0, 1.0])
    return np.concatenate([tilt, obs[:, 10:13], np.ones((len(obs), 1))], axis=1), n


def episode(env: Magic8BallVectorEnv, policy, normal: np.ndarray, seed: int):
    """One episode on every scene; policy(obs, feats) -> (B, 6) actions. Returns the final
    cosine between the target normal and the window, and success (face == target), per scene."""
    obs, _ = env.reset(seed=seed)
    unstable = np.zeros(env.num_envs, dtype=bool)
    for _ in range(env.episode_steps):
        feats, _ = features(obs, normal)
        obs, reward, term, trunc, info = env.step(policy(obs, feats).astype(np.float32))
        unstable |= trunc  # such a scene restarts and fails this episode
    _, n = features(obs, normal)
    return np.where(unstable, -1.0, n[:, 2]), (reward > 0) & ~unstable, unstable


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--backend", default="cpu", help="serial, cpu or cuda (default: cpu)")
    p.add_argument("--face", type=int, default=3, help="the face to show, 1..6 (default: 3)")
    p.add_argument("--particles", type=int, default=200, help="fluid particles a scene (default: 200)")
    p.add_argument("--population", type=int, default=8, help="policies sampled each iteration (default: 8)")
    p.add_argument("--scenes", type=int, default=4, help="8-balls each policy runs on (default: 4)")
    p.add_argument("--iterations", type=int, default=5, help="CEM iterations (default: 5)")
    p.add_argument("--elite", type=float, default=0.25, help="share of the population refitted to (default: 0.25)")
    p.add_argument("--episode", type=float, default=1.0, help="episode length, s (default: 1.0)")
    p.add_argument("--period", type=float, default=0.05, help="control period, s (default: 0.05)")
    p.add_argument("--max-torque", type=float, default=0.1, help="shell torque at |action| = 1, N m (default: 0.1)")
    p.add_argument("--max-acceleration", type=float, default=10.0, help="acceleration at |action| = 1, m/s^2 (default: 10)")
    p.add_argument("--dt-max", type=float, default=3e-3, help="largest time step, s (default: 3e-3; coarse fluid allows it)")
    p.add_argument("--settle", type=float, default=0.5, help="settling before the cache, s (default: 0.5)")
    p.add_argument("--policy", choices=("torque", "full"), default="full",
                   help="full: W sets the shell torque and the acceleration (42 weights, the default); torque: "
                        "the torque alone (21)")
    p.add_argument("--init-std", type=float, default=1.0, help="the sampling distribution's first spread (default: 1)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--plot", default="rig_the_8ball.png", help="the plot (PNG); '' for none")
    p.add_argument("--json", default="", help="also write the results as JSON")
    a = p.parse_args(argv)
    if a.face not in DIE_FACES:
        p.error(f"--face must be 1..6, got {a.face}")
    for name in ("population", "scenes", "iterations", "particles"):
        if getattr(a, name) < 1:
            p.error(f"--{name} must be a positive integer, got {getattr(a, name)}")
    if not 0 < a.elite <= 1:
        p.error(f"--elite must be in (0, 1], got {a.elite}")

    B = a.population * a.scenes
    t0 = time.perf_counter()
    env = Magic8BallVectorEnv(num_envs=B, target_face=a.face, particles=a.particles, backend=a.backend,
                              episode_time=a.episode, control_period=a.period, max_torque=a.max_torque,
                              max_acceleration=a.max_acceleration, settle=a.settle, seed=a.seed,
                              timestep__dt_max=a.dt_max)
    print(f"{B} 8-balls of {a.particles} particles on {env.batch.backend} (built and settled in "
          f"{time.perf_counter() - t0:.1f} s); target face {a.face}", flush=True)
    normal = np.asarray(DIE_FACES[a.face], dtype=np.float64)
    rng = np.random.default_rng(a.seed)
    dim = (6, 7) if a.policy == "full" else (3, 7)
    mean, std = np.zeros(dim), np.full(dim, a.init_std)

    def act(Wx, f):
        # (B, rows) of the policy; torque-only policies leave the acceleration at zero
        out = np.clip(np.einsum("bij,bj->bi", Wx, f) if Wx.ndim == 3 else f @ Wx.T, -1, 1)
        return out if a.policy == "full" else np.concatenate([np.zeros_like(out), out], axis=1)

    n_elite = max(1, int(round(a.elite * a.population)))
    history = []
    seed = a.seed
    for it in range(a.iterations):
        W = mean + std * rng.standard_normal((a.population, *dim))
        Wscene = np.repeat(W, a.scenes, axis=0)  # scene s runs policy s // scenes
        t = time.perf_counter()
        seed += 1
        score, success, trunc = episode(env, lambda obs, f: act(Wscene, f), normal, seed)
        per = score.reshape(a.population, a.scenes).mean(axis=1)
        elite = np.argsort(per)[-n_elite:]
        mean, std = W[elite].mean(axis=0), W[elite].std(axis=0) + 0.05
        history.append({"iteration": it + 1, "score_mean": float(per.mean()), "score_best": float(per.max()),
                        "success": float(success.mean()), "unstable": int(trunc.sum()),
                        "seconds": time.perf_counter() - t})
        h = history[-1]
        print(f"iteration {it + 1}: mean cos {h['score_mean']:+.3f}, best {h['score_best']:+.3f}, "
              f"success of the samples {h['success']:.3f} ({h['seconds']:.1f} s)", flush=True)

    # the learned policy against random shaking and no shaking, one episode on every scene
    results = {}
    policies = {"learned (CEM mean)": lambda obs, f: act(mean, f),
                "random shaking": lambda obs, f: rng.uniform(-1, 1, (len(obs), 6)),
                "no shaking": lambda obs, f: np.zeros((len(obs), 6))}
    for name, pol in policies.items():
        seed += 1
        score, success, trunc = episode(env, pol, normal, seed)
        k = int(success.sum())
        # a binomial standard error on the success rate
        rate = k / B
        results[name] = {"success": rate, "stderr": float(np.sqrt(max(rate * (1 - rate), 1e-12) / B)),
                         "episodes": B, "unstable": int(trunc.sum()), "mean_cos": float(score.mean())}
        print(f"{name:>20}: success {rate:.3f} ± {results[name]['stderr']:.3f} ({k}/{B}), "
              f"mean cos {score.mean():+.3f}", flush=True)
    total = time.perf_counter() - t0
    print(f"total {total:.1f} s (chance: 1/6 = 0.167)")
    out = {"args": vars(a), "history": history, "results": results, "seconds": total,
           "backend": env.batch.backend, "scenes": B, "policy_mean": mean.tolist()}
    if a.json:
        with open(a.json, "w", encoding="utf-8") as f:
            json.dump(out, f, indent=2)
    if a.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 3.8))
        its = [h["iteration"] for h in history]
        ax1.plot(its, [h["score_mean"] for h in history], "o-", label="population mean")
        ax1.plot(its, [h["score_best"] for h in history], "s--", label="best policy")
        ax1.set_xlabel("CEM iteration")
        ax1.set_ylabel("cos(target normal, window) at the end")
        ax1.set_ylim(-1.05, 1.05)
        ax1.legend(loc="lower right")
        names = list(results)
        rates = [results[k]["success"] for k in names]
        errs = [results[k]["stderr"] for k in names]
        ax2.bar(range(len(names)), rates, yerr=errs, color=["tab:green", "tab:orange", "tab:gray"], capsize=4)
        ax2.axhline(1 / 6, color="k", ls=":", lw=1, label="chance (1/6)")
        ax2.set_xticks(range(len(names)), names, fontsize=8)
        ax2.set_ylabel(f"share showing face {a.face}")
        ax2.set_ylim(0, 1)
        ax2.legend(loc="upper right")
        fig.suptitle(f"Rigging the 8-ball: {B} scenes x {a.particles} particles, {env.batch.backend}, "
                     f"{a.iterations} CEM iterations", fontsize=10)
        fig.tight_layout()
        fig.savefig(a.plot, dpi=110)
        print(f"plot: {a.plot}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
