"""Environment workers: Gymnasium environments (or any class with Gymnasium's API) stepped
for a JSAE-RL actor, which runs the policy for all of them in one batch.

    python -m jsae.envs --env CartPole-v1 --actor 127.0.0.1:50070 --envs 8

or, for an environment class of your own:

    import jsae.envs
    jsae.envs.serve(lambda: MyEnv(), actor="127.0.0.1:50070", envs=8, env_id="MyEnv-v0")

`jsae train --env gym:ID` starts the actor and its workers itself; see
docs/src/environments/bring-your-own.md.
"""

from .spaces import UnsupportedSpace
from .worker import PROTOCOL, RefusedByActor, serve

__all__ = ["PROTOCOL", "RefusedByActor", "UnsupportedSpace", "serve", "describe", "describe_env"]


def describe_env(env) -> str:
    """The spaces and time limit of the environment `env` as TOML (the keys of a run's
    `[environment.gym]`, `id` aside): for a class of your own, what the actor's settings
    file needs (`[environment.gym]` with `id` and these lines)."""
    from .spaces import to_toml

    spec = getattr(env, "spec", None)
    max_steps = getattr(spec, "max_episode_steps", None) or 0
    return (
        f"observation = {to_toml(env.observation_space)}\n"
        f"action = {to_toml(env.action_space)}\n"
        f"max_steps = {int(max_steps)}\n"
    )


def describe(env_id: str) -> str:
    """`describe_env` of `gymnasium.make(env_id)`: what `jsae train --env gym:ID` asks
    before the run starts."""
    import gymnasium

    env = gymnasium.make(env_id)
    try:
        return describe_env(env)
    finally:
        env.close()
