"""``python -m chekan.live REC.csv [--live [HOST:]PORT]``: same as ``chekan live``."""

import sys

from chekan import argtypes
from chekan.errors import ChekanError
from chekan.live import add_live_parser


def main(argv=None) -> int:
    ap = argtypes.Parser(prog="python -m chekan.live")
    sub = ap.add_subparsers(dest="command")
    p = add_live_parser(sub)
    args = p.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except ChekanError as e:
        print(f"chekan live: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
