"""Records Gymnasium v5 MuJoCo trajectories for the parity check against `jsae env-replay`.

For each seed: reset(seed), write the state right after reset and the actions to IN, and what
Gymnasium's step returned to EXPECTED (the env-replay format, docs/src/environments.md). Actions are drawn
from U(-s, s) (s = 1.5 by default, so some lie outside the actuators' [-1, 1] range). An episode ends at
termination or after --steps steps.

    python gymnasium_record.py --env Ant-v5 --seed 3 --steps 300 --input in.jsonl --expected out.jsonl
"""

import argparse
import json

import gymnasium as gym
import numpy as np


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--env", required=True, choices=["HalfCheetah-v5", "Ant-v5"])
    p.add_argument("--seed", type=int, required=True)
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--input", required=True)
    p.add_argument("--expected", required=True)
    p.add_argument("--action-scale", type=float, default=1.5,
                   help="actions are drawn from U(-scale, scale)")
    p.add_argument("--z-offset", type=float, default=0.0,
                   help="raise the torso by this much after reset (Ant: > 0.3 starts unhealthy)")
    a = p.parse_args()

    env = gym.make(a.env)
    env.reset(seed=a.seed)
    data = env.unwrapped.data
    if a.z_offset:
        qpos = data.qpos.copy()
        qpos[2] += a.z_offset
        env.unwrapped.set_state(qpos, data.qvel.copy())
    rng = np.random.default_rng(1000 + a.seed)
    with open(a.input, "w") as fin, open(a.expected, "w") as fexp:
        fin.write(json.dumps({"qpos": data.qpos.tolist(), "qvel": data.qvel.tolist()}) + "\n")
        for _ in range(a.steps):
            action = rng.uniform(-a.action_scale, a.action_scale, size=env.action_space.shape).astype(np.float64)
            obs, reward, terminated, truncated, _ = env.step(action)
            fin.write(json.dumps({"action": action.tolist()}) + "\n")
            fexp.write(
                json.dumps(
                    {"obs": np.asarray(obs, dtype=np.float64).tolist(),
                     "reward": float(reward), "terminated": bool(terminated)}
                )
                + "\n"
            )
            if terminated or truncated:
                break
    env.close()


if __name__ == "__main__":
    main()
