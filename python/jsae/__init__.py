"""Python clients of JSAE-RL, a distributed reinforcement-learning training service.

- `jsae.recommender`: `Recommender`, a typed client of the `jsae.v1.Recommender` gRPC service
  (recommendations and the submission of purchase sessions).
- `jsae.envs`: the environment worker, which steps Python environments for a run's actor.
- `jsae.channel`: the address, TLS and bearer-token rules every client follows.

The gRPC stubs in `jsae._proto` are generated from the project's wire/proto/jsae.proto when
the package is built; nothing here imports them until a client is used.
"""

__version__ = "0.1.0"
