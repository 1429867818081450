"""Environment throughput: NeckTrack-v0 beside Pendulum-v1 measured in the same run.

    python benchmarks/env_throughput.py [--steps 50000] [--num-envs 4096] [--vec-steps 300]

Targets (issue #3): the single env through gymnasium.make at least as fast as Pendulum-v1
(ratio >= 1.0); the natively batched env at N = 4096 >= 2,000,000 env steps per second on this
2-core machine. Prints the figures and ratios; compile time is excluded by a warm-up.
"""

import argparse
import time

import gymnasium as gym
import numpy as np

import neck_env  # noqa: F401  (registers NeckTrack-v0)


def single_rate(env_id: str, steps: int, **kwargs) -> float:
    env = gym.make(env_id, **kwargs)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    actions = [env.action_space.sample() for _ in range(64)]
    for a in actions:  # warm-up (numba compile, caches)
        env.step(a)
    env.reset(seed=0)
    t0 = time.perf_counter()
    for k in range(steps):
        _, _, term, trunc, _ = env.step(actions[k & 63])
        if term or trunc:
            env.reset()
    elapsed = time.perf_counter() - t0
    env.close()
    del rng
    return steps / elapsed


def vector_rate(num_envs: int, steps: int, action_mode: str) -> float:
    env = gym.make_vec("NeckTrack-v0", num_envs=num_envs, vectorization_mode="vector_entry_point",
                       action_mode=action_mode)
    env.reset(seed=0)
    actions = [env.action_space.sample() for _ in range(8)]
    for a in actions:
        env.step(a)
    t0 = time.perf_counter()
    for k in range(steps):
        env.step(actions[k & 7])
    elapsed = time.perf_counter() - t0
    env.close()
    return num_envs * steps / elapsed


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=50000)
    ap.add_argument("--num-envs", type=int, default=4096)
    ap.add_argument("--vec-steps", type=int, default=300)
    args = ap.parse_args()

    pend = single_rate("Pendulum-v1", args.steps)
    neck = single_rate("NeckTrack-v0", args.steps)
    neck_relay = single_rate("NeckTrack-v0", args.steps, action_mode="relay")
    print(f"single env via gymnasium.make ({args.steps} steps each)")
    print(f"  Pendulum-v1                  {pend:12,.0f} steps/s")
    print(f"  NeckTrack-v0 (current)       {neck:12,.0f} steps/s   ratio {neck / pend:.2f}  (target >= 1.0)")
    print(f"  NeckTrack-v0 (relay)         {neck_relay:12,.0f} steps/s   ratio {neck_relay / pend:.2f}")
    vec = vector_rate(args.num_envs, args.vec_steps, "current")
    print(f"batched env, N = {args.num_envs} ({args.vec_steps} steps)")
    print(f"  NeckTrack-v0 vector_entry_point {vec:12,.0f} env steps/s  (target >= 2,000,000)")
    print(f"  vs Pendulum-v1 single           {vec / pend:12.1f} x")


if __name__ == "__main__":
    main()
