"""`python -m jsae.envs`: host Gymnasium environments for an actor, or describe one."""

import argparse
import logging
import os
import sys


def parse(argv):
    p = argparse.ArgumentParser(
        prog="python -m jsae.envs",
        description="Host Gymnasium environments for a JSAE-RL actor (its --env-listen address).",
    )
    p.add_argument("--env", required=True, help="the Gymnasium id (gymnasium.make), e.g. CartPole-v1")
    p.add_argument("--actor", help="the actor's environment address, host:port or http(s)://host:port")
    p.add_argument("--envs", type=int, default=8, help="environments to host (default 8)")
    p.add_argument("--name", help="this worker's name in the actor's logs")
    p.add_argument("--describe", action="store_true",
                   help="print the environment's spaces and time limit as TOML and exit")
    p.add_argument("--auth-token-file", default=os.environ.get("JSAE_AUTH_TOKEN_FILE"),
                   help="the deployment's token file (default: $JSAE_AUTH_TOKEN_FILE)")
    p.add_argument("--tls-ca", default=os.environ.get("JSAE_TLS_CA"),
                   help="PEM CA the actor's certificate is checked with (default: $JSAE_TLS_CA)")
    p.add_argument("--tls-domain", help="the name the actor's certificate is checked against")
    p.add_argument("--max-episode-steps", type=int, default=0,
                   help="the time limit the run uses (default: the environment's own)")
    p.add_argument("--connect-timeout", type=float, default=60.0,
                   help="seconds to wait for the actor to answer (default 60)")
    args = p.parse_args(argv)
    if not args.describe and not args.actor:
        p.error("--actor is required (or --describe)")
    if args.envs < 1:
        p.error("--envs must be at least 1")
    return args


def main(argv=None) -> int:
    args = parse(sys.argv[1:] if argv is None else argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    if args.describe:
        from . import describe

        sys.stdout.write(describe(args.env))
        return 0
    from .worker import main_loop

    return main_loop(args)


if __name__ == "__main__":
    sys.exit(main())
