"""The environment worker: hosts environments for one actor over its `EnvHost.Attach`
stream. The actor sends commands (reset these environments with these seeds; step them with
these actions); the worker answers each, in order. An environment whose episode ends is
reset at once and its next first state sent with the step's answer, so a step costs one
round trip whatever ends. When the actor asks for an environment number the worker does not
host yet (the next one), it makes one more: the actor moves the environments of a worker
that died onto the others.
"""

from __future__ import annotations

import logging
import os
import queue
import socket
import sys
import traceback
from typing import Callable, List, Optional

import grpc

from jsae._proto import jsae_pb2 as pb
from jsae._proto import jsae_pb2_grpc as pb_grpc
from jsae.channel import auth_metadata, open_channel, read_token_file

from .spaces import ActionCodec, ObservationCodec, to_wire

#: The protocol this worker speaks (the actor's `PROTOCOL`).
PROTOCOL = 1

log = logging.getLogger("jsae.envs")


class RefusedByActor(RuntimeError):
    """The actor ended the stream with an error: the reason is the message."""


class _Envs:
    """The hosted environments and their codecs."""

    def __init__(self, make_env: Callable[[], object], count: int):
        self.make_env = make_env
        self.envs: List[object] = [make_env() for _ in range(count)]
        first = self.envs[0]
        self.observation_space = first.observation_space
        self.action_space = first.action_space
        self.observations = ObservationCodec(self.observation_space)
        self.actions = ActionCodec(self.action_space)

    def env(self, i: int):
        if i == len(self.envs):
            env = self.make_env()
            if env.observation_space != self.observation_space or env.action_space != self.action_space:
                raise ValueError("a new environment has other spaces than the first")
            self.envs.append(env)
        if not 0 <= i < len(self.envs):
            raise ValueError(f"environment {i} asked of a worker hosting {len(self.envs)}")
        return self.envs[i]

    def answer(self, command: pb.EnvCommand) -> pb.EnvReply:
        reply = pb.EnvReply(seq=command.seq)
        envs = [self.env(i) for i in command.envs]
        which = command.WhichOneof("kind")
        if which == "reset":
            if len(command.reset.seeds) != len(envs):
                raise ValueError("a reset needs one seed per environment")
            firsts = [env.reset(seed=int(seed))[0] for env, seed in zip(envs, command.reset.seeds)]
            self.observations.encode(firsts, reply.observations)
            return reply
        if which != "step":
            raise ValueError("a command that is neither a reset nor a step")
        actions = self.actions.decode(command.step, len(envs))
        reached, starts = [], []
        for env, action in zip(envs, actions):
            obs, reward, terminated, truncated, _ = env.step(action)
            terminated = bool(terminated)
            # Gymnasium's time limit can cut a step that also terminated: the terminal
            # state wins (its value is 0)
            truncated = bool(truncated) and not terminated
            reached.append(obs)
            reply.rewards.append(float(reward))
            reply.terminated.append(terminated)
            reply.truncated.append(truncated)
            if terminated or truncated:
                starts.append(env.reset()[0])
        self.observations.encode(reached, reply.observations)
        self.observations.encode(starts, reply.reset_observations)
        return reply

    def close(self) -> None:
        for env in self.envs:
            try:
                env.close()
            except Exception:  # noqa: BLE001 - closing is best effort
                pass


def _env_id(env, given: Optional[str]) -> str:
    if given:
        return given
    spec = getattr(env, "spec", None)
    if spec is not None and getattr(spec, "id", None):
        return spec.id
    return type(env).__name__


def serve(
    make_env: Callable[[], object],
    actor: str,
    envs: int = 8,
    *,
    env_id: Optional[str] = None,
    token: Optional[str] = None,
    token_file: Optional[str] = None,
    tls_ca: Optional[str] = None,
    tls_domain: Optional[str] = None,
    name: Optional[str] = None,
    connect_timeout: float = 60.0,
) -> int:
    """Hosts `envs` environments made by `make_env()` for the actor at `actor` (its
    `--env-listen` address) until the actor ends the stream; returns the commands answered.

    `env_id` is the name the run knows the environment by (its `gym:ID`; default: the first
    environment's `spec.id`, else its class name). The token (or `token_file`, default the
    `JSAE_AUTH_TOKEN_FILE` variable) and `tls_ca` (default `JSAE_TLS_CA`) are those the
    services take. Raises `RefusedByActor` with the actor's reason when it refuses this
    worker or something it sent (spaces other than the run's, an observation with NaN).
    """
    if envs < 1:
        raise ValueError("a worker hosts at least one environment")
    token_file = token_file or os.environ.get("JSAE_AUTH_TOKEN_FILE") or None
    if token is None and token_file:
        token = read_token_file(token_file)
    tls_ca = tls_ca or os.environ.get("JSAE_TLS_CA") or None
    hosted = _Envs(make_env, envs)
    hello = pb.EnvHello(
        protocol=PROTOCOL,
        env_id=_env_id(hosted.envs[0], env_id),
        envs=envs,
        observation_space=to_wire(hosted.observation_space),
        action_space=to_wire(hosted.action_space),
        worker=name or f"{socket.gethostname()}:{os.getpid()}",
    )
    channel, _ = open_channel(actor, tls_ca=tls_ca, tls_domain=tls_domain)
    outbox: "queue.Queue[Optional[pb.EnvUp]]" = queue.Queue()
    outbox.put(pb.EnvUp(hello=hello))

    def upstream():
        while True:
            message = outbox.get()
            if message is None:
                return
            yield message

    answered = 0
    try:
        grpc.channel_ready_future(channel).result(timeout=connect_timeout)
        stub = pb_grpc.EnvHostStub(channel)
        commands = stub.Attach(upstream(), metadata=auth_metadata(token))
        for command in commands:
            try:
                reply = hosted.answer(command)
            except Exception as e:  # the environment failed: say so, and stop
                outbox.put(pb.EnvUp(error=f"{type(e).__name__}: {e}"))
                outbox.put(None)
                # the actor ends the stream once it has read the error: wait for that, so
                # that closing the channel does not cancel the error on its way
                try:
                    for _ in commands:
                        pass
                except grpc.RpcError:
                    pass
                raise
            outbox.put(pb.EnvUp(reply=reply))
            answered += 1
    except grpc.FutureTimeoutError:
        raise ConnectionError(f"no actor answered at {actor} within {connect_timeout} s") from None
    except grpc.RpcError as e:
        code = e.code()
        if code in (grpc.StatusCode.INVALID_ARGUMENT, grpc.StatusCode.UNAUTHENTICATED,
                    grpc.StatusCode.FAILED_PRECONDITION, grpc.StatusCode.PERMISSION_DENIED):
            raise RefusedByActor(f"{code.name}: {e.details()}") from None
        # the actor went away (the run ended, or it stopped)
        log.info("the actor's stream ended: %s %s", code.name, e.details())
    finally:
        outbox.put(None)
        channel.close()
        hosted.close()
    return answered


def main_loop(args) -> int:
    """`python -m jsae.envs` with parsed arguments: an exit status."""
    import gymnasium

    def make_env():
        if args.max_episode_steps:
            return gymnasium.make(args.env, max_episode_steps=args.max_episode_steps)
        return gymnasium.make(args.env)

    try:
        answered = serve(
            make_env,
            args.actor,
            args.envs,
            env_id=args.env,
            token_file=args.auth_token_file,
            tls_ca=args.tls_ca,
            tls_domain=args.tls_domain,
            name=args.name,
            connect_timeout=args.connect_timeout,
        )
    except RefusedByActor as e:
        print(f"jsae.envs: the actor refused this worker: {e}", file=sys.stderr)
        return 2
    except ConnectionError as e:
        print(f"jsae.envs: {e}", file=sys.stderr)
        return 1
    except Exception:  # noqa: BLE001 - the environment's own error, shown whole
        traceback.print_exc()
        return 1
    log.info("done after %d commands", answered)
    return 0
