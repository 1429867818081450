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
    env.action_space.seed(0)
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
    return steps / elapsed


def vector_rate(num_envs: int, steps: int, action_mode: str) -> float:
    env = gym.make_vec("NeckTrack-v0", num_envs=num_envs, vectorization_mode="vector_entry_point",
                       action_mode=action_mode)
    env.reset(seed=0)
    env.action_space.seed(0)
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
    ap.add_argument("--repeats", type=int, default=3, help="runs per figure; median and best shown")
    args = ap.parse_args()
    rep = lambda f: sorted(f() for _ in range(args.repeats))

    # Interleave the measurements so a busy moment on this shared machine hits all of them.
    pend, neck, relay, vec = [], [], [], []
    for _ in range(args.repeats):
        pend.append(single_rate("Pendulum-v1", args.steps))
        neck.append(single_rate("NeckTrack-v0", args.steps))
        relay.append(single_rate("NeckTrack-v0", args.steps, action_mode="relay"))
        vec.append(vector_rate(args.num_envs, args.vec_steps, "current"))
    med = lambda v: float(np.median(v))
    ratios = [n / p for n, p in zip(neck, pend)]
    print(f"single env via gymnasium.make ({args.steps} steps, {args.repeats} interleaved runs; median / best)")
    print(f"  Pendulum-v1                  {med(pend):12,.0f} / {max(pend):12,.0f} steps/s")
    print(f"  NeckTrack-v0 (current)       {med(neck):12,.0f} / {max(neck):12,.0f} steps/s")
    print(f"  NeckTrack-v0 (relay)         {med(relay):12,.0f} / {max(relay):12,.0f} steps/s")
    print(f"  ratio NeckTrack/Pendulum per run: " + ", ".join(f"{r:.2f}" for r in ratios)
          + f"  (median {med(ratios):.2f}; target >= 1.0)")
    print(f"batched env, N = {args.num_envs}, random currents ({args.vec_steps} steps per run)")
    print(f"  NeckTrack-v0 vector_entry_point {med(vec):12,.0f} / {max(vec):12,.0f} env steps/s"
          f"  (target >= 2,000,000)")
    print(f"  vs Pendulum-v1 single           {med(vec) / med(pend):12.1f} x")


if __name__ == "__main__":
    main()
