"""``icprl label``: serve the labelling page for a session, or export its answers (``icprl_lightning/labelling``).

    icprl label --session labels/dr --view darkroom_trajectories --pairs 50 [--seed 0] [--port 8765]
    icprl label --session labels/dr                      (reopen: the same queue, the answers so far)
    icprl label --session labels/dr --export out/dr [--ties soft|drop] [--overwrite]

Serving prints the page's address with a fresh token (``http://127.0.0.1:PORT/?token=...``); open it, add
``&annotator=NAME`` or type a name, and answer with the keys 1 / 2 / e / s (undo: u). ``--port 0`` picks a free
port. ``--host`` other than 127.0.0.1 serves other machines too: only on a network you trust.
"""

from __future__ import annotations

import argparse
import json
import os
import secrets
import socket
import sys

from icprl_lightning.commands import command_parser
from icprl_lightning.labelling.pairs import VIEWS


def parser() -> argparse.ArgumentParser:
    p = command_parser("icprl label", __doc__)
    p.add_argument("--session", required=True, help="the session directory (created with its queue if new)")
    p.add_argument("--view", choices=sorted(VIEWS), help="what is compared (a new session only)")
    p.add_argument("--pairs", type=int, help="how many pairs the queue holds (a new session only)")
    p.add_argument("--seed", type=int, help="the queue's seed (a new session only; default 0)")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default: loopback only)")
    p.add_argument("--port", type=int, default=8765, help="port to bind (0: any free port)")
    p.add_argument("--export", metavar="OUT", help="write the answers to OUT instead of serving")
    p.add_argument("--overwrite", action="store_true", help="with --export: replace OUT's files")
    p.add_argument("--ties", choices=("soft", "drop"), default="soft",
                   help="with --export: keep ties in the dataset as 0.5 (ICPO, RewardGen) or leave them out")
    return p


def main(argv: list[str] | None = None) -> int:
    """Serve (or export) the session; a user's mistake is a ``ValueError`` the ``icprl`` command prints in one line."""
    args = parser().parse_args(argv)
    from icprl_lightning.labelling.session import hold_lock, open_session

    session = open_session(args.session, args.view, args.pairs, args.seed)
    if args.export:
        from icprl_lightning.labelling.export import export

        print(json.dumps(export(session, args.export, args.overwrite, args.ties)))
        return 0
    lock = hold_lock(args.session)
    import uvicorn

    from icprl_lightning.labelling.server import LOOPBACK, make_app

    token = secrets.token_urlsafe(24)
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((args.host, args.port))
    except OSError as e:
        raise ValueError(f"--host/--port: cannot listen on {args.host}:{args.port} ({e.strerror})") from None
    sock.listen(128)  # connections wait in the backlog from now on, before uvicorn accepts them
    host, port = sock.getsockname()
    app = make_app(session, token, LOOPBACK if args.host == "127.0.0.1" else [*LOOPBACK, args.host])
    done, total = len(session.log.answers), len(session.pair_ids)
    print(f"icprl label: {session.config['view']}, {total} pairs, {done} annotator(s) so far; open\n"
          f"  http://{host}:{port}/?token={token}", flush=True)
    try:
        uvicorn.Server(uvicorn.Config(app, log_level="warning")).run(sockets=[sock])
    finally:
        os.close(lock)
    return 0


if __name__ == "__main__":
    sys.exit(main())
