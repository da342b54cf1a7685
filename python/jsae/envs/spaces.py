"""Gymnasium spaces in the actor's terms: their wire form (`Space`), their description as
`[environment.gym]` holds it (TOML), and the codecs of observations and actions.

Supported: `Discrete`, `MultiDiscrete` and `Box` (of any shape, flattened row-major, any
numeric dtype carried as float32). Anything else is refused with the reason.
"""

from __future__ import annotations

import math
from typing import List, Sequence

import numpy as np

from jsae._proto import jsae_pb2 as pb


class UnsupportedSpace(ValueError):
    """A space the actor cannot step (its type, or its size)."""


def _kind(space) -> str:
    from gymnasium import spaces as gs

    if isinstance(space, gs.Discrete):
        return "discrete"
    if isinstance(space, gs.MultiDiscrete):
        if np.asarray(space.nvec).ndim != 1:
            raise UnsupportedSpace("a MultiDiscrete space must be one-dimensional")
        if np.any(np.asarray(space.start) != 0):
            raise UnsupportedSpace("a MultiDiscrete space must start at 0")
        return "multi_discrete"
    if isinstance(space, gs.Box):
        return "box"
    raise UnsupportedSpace(
        f"{type(space).__name__} spaces are not supported (Discrete, MultiDiscrete and Box are)"
    )


def to_wire(space) -> pb.Space:
    """The space as the hello describes it."""
    kind = _kind(space)
    if kind == "discrete":
        return pb.Space(discrete=pb.DiscreteSpace(n=int(space.n), start=int(space.start)))
    if kind == "multi_discrete":
        return pb.Space(multi_discrete=pb.MultiDiscreteSpace(nvec=[int(n) for n in space.nvec]))
    low = np.asarray(space.low, dtype=np.float32).reshape(-1)
    high = np.asarray(space.high, dtype=np.float32).reshape(-1)
    return pb.Space(
        box=pb.BoxSpace(
            shape=[int(d) for d in space.shape], low=low.tolist(), high=high.tolist()
        )
    )


def _toml_float(x: float) -> str:
    x = float(np.float32(x))
    if math.isnan(x):
        raise UnsupportedSpace("a Box bound is NaN")
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return repr(x)


def _toml_list(values: Sequence) -> str:
    return "[" + ", ".join(values) + "]"


def to_toml(space) -> str:
    """The space as an inline TOML table, the way `[environment.gym]` holds it."""
    kind = _kind(space)
    if kind == "discrete":
        return f"{{ discrete = {{ n = {int(space.n)}, start = {int(space.start)} }} }}"
    if kind == "multi_discrete":
        nvec = _toml_list([str(int(n)) for n in space.nvec])
        return f"{{ multi-discrete = {{ nvec = {nvec} }} }}"
    shape = _toml_list([str(int(d)) for d in space.shape])
    low = _toml_list([_toml_float(v) for v in np.asarray(space.low).reshape(-1)])
    high = _toml_list([_toml_float(v) for v in np.asarray(space.high).reshape(-1)])
    return f"{{ box = {{ shape = {shape}, low = {low}, high = {high} }} }}"


class ObservationCodec:
    """Writes observations into an `Observations` message."""

    def __init__(self, space):
        self.kind = _kind(space)
        if self.kind == "discrete":
            self.start = int(space.start)
        elif self.kind == "box":
            self.size = int(np.prod(space.shape))

    def encode(self, observations: List, out: pb.Observations) -> None:
        """Fills `out` with `observations` (one per environment, in order)."""
        if not observations:
            return
        if self.kind == "box":
            rows = np.empty((len(observations), self.size), dtype="<f4")
            for i, obs in enumerate(observations):
                rows[i] = np.asarray(obs, dtype=np.float32).reshape(-1)
            out.real = rows.tobytes()
        elif self.kind == "discrete":
            out.index.extend(int(obs) - self.start for obs in observations)
        else:
            for obs in observations:
                out.index.extend(int(v) for v in np.asarray(obs).reshape(-1))


class ActionCodec:
    """Reads the actions of a `StepCommand`, one per addressed environment."""

    def __init__(self, space):
        self.kind = _kind(space)
        if self.kind == "discrete":
            self.start = int(space.start)
        elif self.kind == "multi_discrete":
            self.nvec = [int(n) for n in space.nvec]
            self.dtype = space.dtype
        else:
            self.shape = tuple(space.shape)
            self.size = int(np.prod(space.shape))
            self.dtype = space.dtype

    def decode(self, step: pb.StepCommand, count: int) -> List:
        """The `count` actions of `step`; ValueError when it does not hold that many."""
        if self.kind == "box":
            values = np.frombuffer(step.continuous, dtype="<f4")
            if values.size != count * self.size:
                raise ValueError(f"{values.size} action values for {count} environments")
            rows = values.reshape(count, *self.shape).astype(self.dtype, copy=False)
            return list(rows)
        if len(step.discrete) != count:
            raise ValueError(f"{len(step.discrete)} actions for {count} environments")
        if self.kind == "discrete":
            return [int(a) + self.start for a in step.discrete]
        actions = []
        for a in step.discrete:
            a = int(a)
            parts = []
            for n in reversed(self.nvec):
                parts.append(a % n)
                a //= n
            actions.append(np.array(parts[::-1], dtype=self.dtype))
        return actions
