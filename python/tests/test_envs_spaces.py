"""jsae.envs without an actor: spaces in their wire and TOML forms, the observation and
action codecs, the description `jsae train --env gym:ID` reads, and the worker's own
bookkeeping (autoreset, terminated over truncated, environments made on demand)."""

import math

import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")
from gymnasium import spaces as gs  # noqa: E402

from jsae._proto import jsae_pb2 as pb  # noqa: E402
from jsae.envs import UnsupportedSpace, describe  # noqa: E402
from jsae.envs.spaces import ActionCodec, ObservationCodec, to_toml, to_wire  # noqa: E402
from jsae.envs.worker import _Envs  # noqa: E402


def test_spaces_travel_as_the_actor_reads_them():
    box = gs.Box(low=np.array([-1.0, -np.inf]), high=np.array([1.0, np.inf]), dtype=np.float32)
    wire = to_wire(box)
    assert list(wire.box.shape) == [2]
    assert wire.box.low[1] == -math.inf
    assert to_wire(gs.Discrete(5, start=-2)).discrete.start == -2
    assert list(to_wire(gs.MultiDiscrete([3, 4])).multi_discrete.nvec) == [3, 4]
    assert to_toml(box) == "{ box = { shape = [2], low = [-1.0, -inf], high = [1.0, inf] } }"
    assert to_toml(gs.MultiDiscrete([3, 4])) == "{ multi-discrete = { nvec = [3, 4] } }"


def test_unsupported_spaces_are_refused_with_the_reason():
    with pytest.raises(UnsupportedSpace, match="Tuple"):
        to_wire(gs.Tuple([gs.Discrete(2), gs.Discrete(3)]))
    with pytest.raises(UnsupportedSpace, match="start at 0"):
        to_wire(gs.MultiDiscrete([3, 4], start=[1, 0]))


def test_observations_and_actions_round_trip():
    box = gs.Box(low=-1.0, high=1.0, shape=(2, 2), dtype=np.float32)
    out = pb.Observations()
    ObservationCodec(box).encode([np.eye(2), np.zeros((2, 2))], out)
    assert np.frombuffer(out.real, dtype="<f4").tolist() == [1, 0, 0, 1, 0, 0, 0, 0]
    out = pb.Observations()
    ObservationCodec(gs.Discrete(4, start=10)).encode([10, 13], out)
    assert list(out.index) == [0, 3]
    step = pb.StepCommand(discrete=[7, 0])
    # mixed radix, the first component most significant: 7 = 2 * 3 + 1
    actions = ActionCodec(gs.MultiDiscrete([4, 3])).decode(step, 2)
    assert [a.tolist() for a in actions] == [[2, 1], [0, 0]]
    continuous = pb.StepCommand(continuous=np.array([0.5, -0.5], dtype="<f4").tobytes())
    rows = ActionCodec(gs.Box(-1, 1, shape=(1,), dtype=np.float32)).decode(continuous, 2)
    assert [r.tolist() for r in rows] == [[0.5], [-0.5]]
    with pytest.raises(ValueError, match="3 actions for 2"):
        ActionCodec(gs.Discrete(2)).decode(pb.StepCommand(discrete=[0, 1, 1]), 2)


def test_describe_gives_the_spaces_and_time_limit_as_toml():
    text = describe("CartPole-v1")
    assert "action = { discrete = { n = 2, start = 0 } }" in text
    assert "max_steps = 500" in text


def test_the_worker_resets_ended_episodes_and_hosts_more_on_demand():
    envs = _Envs(lambda: gymnasium.make("CartPole-v1"), 1)
    reply = envs.answer(pb.EnvCommand(seq=1, envs=[0], reset=pb.ResetCommand(seeds=[3])))
    assert len(reply.observations.real) == 16
    ended = 0
    for seq in range(2, 200):
        reply = envs.answer(pb.EnvCommand(seq=seq, envs=[0], step=pb.StepCommand(discrete=[1])))
        assert not (reply.terminated[0] and reply.truncated[0])
        if reply.terminated[0]:
            ended += 1
            assert len(reply.reset_observations.real) == 16
    assert ended > 0, "always pushing right drops the pole"
    # the actor moves a lost worker's environment here: number 1 is made on demand
    envs.answer(pb.EnvCommand(seq=500, envs=[1], reset=pb.ResetCommand(seeds=[4])))
    assert len(envs.envs) == 2
    with pytest.raises(ValueError, match="environment 5"):
        envs.answer(pb.EnvCommand(seq=501, envs=[5], reset=pb.ResetCommand(seeds=[4])))
