"""Gymnasium's step rate for `jsae bench --mujoco`: one environment, random actions from the
action space, reset when an episode ends; prints env steps per second (one number)."""

import sys
import time

import gymnasium as gym


def main() -> None:
    env_id, steps = sys.argv[1], int(sys.argv[2])
    env = gym.make(env_id)
    env.reset(seed=0)
    env.action_space.seed(0)
    for _ in range(200):
        env.step(env.action_space.sample())
    start = time.perf_counter()
    for _ in range(steps):
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            env.reset()
    print(steps / (time.perf_counter() - start))


if __name__ == "__main__":
    main()
