"""sgreg keys init|add|list DIR: the fleet keystore that signs and checks the agents' messages
(sgreg_core/runtime/auth.py). Give it to the nodes with `-p keystore:=DIR`.

    sgreg keys init DIR --agents a b c      a key pair per agent (one machine, or copy the
                                            private key of each robot onto that robot only)
    sgreg keys add DIR AGENT PUBLIC_HEX     trust a peer's public key
    sgreg keys list DIR                     agents, key ids, public keys, which private keys are here
"""
from __future__ import annotations

import sys

NAME = "keys"
HELP = "make and list the fleet keystore that signs the agents' messages"


def add_arguments(p):
    p.add_argument("action", choices=["init", "add", "list"])
    p.add_argument("dir", help="keystore folder")
    p.add_argument("agent", nargs="?", help="add: the agent the public key belongs to")
    p.add_argument("public_hex", nargs="?", help="add: its public key (hex)")
    p.add_argument("--agents", nargs="+", default=[], help="init: agents to make keys for")


def run(args) -> int:
    from sgreg_core.runtime.auth import KeystoreError, add_public_key, init_keystore, list_keys

    try:
        extra = [v for v in (args.agent, args.public_hex) if v] if args.action != "add" else []
        if extra or (args.agents and args.action != "init"):
            raise KeystoreError(f"{args.action} takes only DIR"
                                + (" and --agents" if args.action == "init" else "")
                                + f"; got also {' '.join(extra) or '--agents'}")
        if args.action == "init":
            if not args.agents:
                raise KeystoreError("init needs --agents")
            for agent, kid in init_keystore(args.dir, args.agents):
                print(f"{agent}: key {kid}")
        elif args.action == "add":
            if not (args.agent and args.public_hex):
                raise KeystoreError("add needs AGENT PUBLIC_HEX")
            print(f"{args.agent}: key {add_public_key(args.dir, args.agent, args.public_hex)}")
        else:
            for k in list_keys(args.dir):
                here = "private key here" if k["private_here"] else "public only"
                print(f"{k['agent']:12s} {k['key_id']}  {here:16s}  {k['public']}")
    except (KeystoreError, OSError) as exc:
        print(f"sgreg keys: {exc}", file=sys.stderr)
        return 2
    return 0
