"""`python -m adp_client --learner ADDR --token-file FILE [--rank R] [--tls-ca CA ...]`:
runs one actor with the built-in toy environment (adp_client.toy.PointWorld)."""

import argparse
import sys

from .actor import Actor, AdpError
from .toy import PointWorld


def main(argv=None) -> int:
    """Command-line entry point."""
    p = argparse.ArgumentParser(prog="adp-client", description=__doc__)
    p.add_argument("--learner", required=True, help="host:port or unix:PATH")
    p.add_argument("--token-file")
    p.add_argument("--rank", type=int, default=0)
    p.add_argument("--tls-ca")
    p.add_argument("--tls-cert")
    p.add_argument("--tls-key")
    p.add_argument("--tls-domain")
    p.add_argument("--max-steps", type=int, default=40, help="episode length of the toy environment")
    p.add_argument("--give-up-after", type=float, default=60.0)
    a = p.parse_args(argv)
    try:
        actor = Actor(a.learner, PointWorld(max_steps=a.max_steps), rank=a.rank, token_file=a.token_file,
                      tls_ca=a.tls_ca, tls_cert=a.tls_cert, tls_key=a.tls_key, tls_domain=a.tls_domain,
                      give_up_after=a.give_up_after)
        actor.run()
    except AdpError as e:
        print(f"adp-client: {e}", file=sys.stderr)
        return 1
    print(f"adp-client: run over after {actor.episodes} episodes, {actor.sessions} sessions, "
          f"{actor.leases_lost} leases lost", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
