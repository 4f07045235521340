"""``sweepcast keys``: create, list, revoke and rotate API keys in the service's database (the one
``SWEEPCAST_DATABASE_URL`` names, else the data folder's SQLite), so every replica sees them at once."""
from __future__ import annotations

import argparse
import datetime as dt
import json
import re
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

from app.quotas import QUOTA_FIELDS

_DURATION = re.compile(r"^(\d+(?:\.\d+)?)([hdw])$")
_UNITS = {"h": 3600.0, "d": 86400.0, "w": 604800.0}


def parse_expiry(text: str, now: dt.datetime | None = None) -> dt.datetime:
    """``30d``, ``12h``, ``2w`` from now, or an ISO 8601 date or time (UTC when it names no zone)."""
    now = now or dt.datetime.now(dt.timezone.utc)
    found = _DURATION.match(text.strip())
    if found:
        return now + dt.timedelta(seconds=float(found[1]) * _UNITS[found[2]])
    try:
        when = dt.datetime.fromisoformat(text.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"--expires {text!r}: give 30d, 12h, 2w or an ISO date such as 2027-01-31")
    return when if when.tzinfo else when.replace(tzinfo=dt.timezone.utc)


def parse_quota(text: str) -> tuple[str, int]:
    """``NAME=VALUE`` of one quota field (bytes may be written 10e9)."""
    name, _, value = text.partition("=")
    if name not in QUOTA_FIELDS or not value:
        raise argparse.ArgumentTypeError(f"--quota {text!r}: give NAME=VALUE, NAME one of {', '.join(QUOTA_FIELDS)}")
    try:
        number = int(float(value))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--quota {text!r}: {value!r} is not a number")
    if number < 1:
        raise argparse.ArgumentTypeError(f"--quota {text!r}: the limit must be at least 1")
    return name, number


@contextmanager
def opened_keys(settings: Any) -> Iterator[Any]:
    """The :class:`~app.keys.KeyStore` of the service's database (``settings``: the service's), closed after."""
    from app.jobstore import JobStore
    from app.keys import KeyStore

    settings.data_dir.mkdir(parents=True, exist_ok=True)
    jobs = JobStore(settings.resolved_database_url)
    try:
        yield KeyStore(jobs.engine)
    finally:
        jobs.close()


def _show(key: dict[str, Any]) -> str:
    state = "active" if key["active"] else ("revoked" if key["revoked_at"] else "expired")
    expires = key["expires_at"].isoformat(timespec="seconds") if key["expires_at"] else "never"
    quota = ", ".join(f"{k}={v}" for k, v in key["quota"].items()) or "defaults"
    return f"{key['id']}  {key['name']:20} {key['role']:5}  {state:7}  expires {expires}  quota {quota}"


def cmd_keys(args: argparse.Namespace) -> int:
    from app.keys import UnknownKey
    from app.settings import Settings

    settings = Settings(**({"data_dir": args.data_dir} if args.data_dir is not None else {}))
    try:
        with opened_keys(settings) as keys:
            _keys_action(keys, args)
    except UnknownKey as exc:
        print(str(exc), file=sys.stderr)
        return 1
    return 0


def _keys_action(keys: Any, args: argparse.Namespace) -> None:
    if args.action == "create":
        first = not keys.any()
        key, secret = keys.create(args.name, args.role, args.expires, dict(args.quota or []) or None)
        print(_show(key.public()))
        if first and args.role == "user":
            print("note: the service's first managed key: every request now needs a key. Without "
                  "SWEEPCAST_API_KEYS, make an admin key too (--role admin) to see what was stored before "
                  "and to manage keys.", file=sys.stderr)
        print(f"secret (shown once; send it as 'Authorization: Bearer <secret>'):\n{secret}")
    elif args.action == "list":
        listed = [k.public() for k in keys.list()]
        if args.json:
            print(json.dumps(listed, default=str, indent=2))
        else:
            for key in listed:
                print(_show(key))
    elif args.action == "revoke":
        print(_show(keys.revoke(keys.find(args.key).id).public()))
    else:
        key, secret = keys.rotate(keys.find(args.key).id)
        print(_show(key.public()))
        print(f"new secret (shown once; the old one no longer works):\n{secret}")


def register(sub: Any) -> None:
    p = sub.add_parser("keys", help="create, list, revoke or rotate API keys (stored hashed in the service's database)")
    actions = p.add_subparsers(dest="action", required=True)
    create = actions.add_parser("create", help="a new key; its secret is printed once")
    create.add_argument("--name", required=True, help="who or what uses it (the access log names it)")
    create.add_argument("--role", choices=["user", "admin"], default="user",
                        help="user: sees its own resources (default); admin: everything, and keys")
    create.add_argument("--expires", type=parse_expiry, help="30d, 12h, 2w from now, or an ISO date (default: never)")
    create.add_argument("--quota", type=parse_quota, action="append", metavar="NAME=VALUE",
                        help=f"a limit of its own, repeatable; NAME: {', '.join(QUOTA_FIELDS)}")
    listing = actions.add_parser("list", help="every key, never its secret")
    listing.add_argument("--json", action="store_true", help="as JSON")
    for verb, what in (("revoke", "stop a key at once, on every replica"),
                       ("rotate", "a new secret for a key; the old one stops at once")):
        p2 = actions.add_parser(verb, help=what)
        p2.add_argument("key", help="the key's id, or its name when one active key has it")
    for parser in (create, listing, *actions.choices.values()):
        if not any(a.dest == "data_dir" for a in parser._actions):
            parser.add_argument("--data-dir", type=Path, help="data folder (default ./sweepcast-data; "
                                                              "SWEEPCAST_DATA_DIR), unless SWEEPCAST_DATABASE_URL is set")
    p.set_defaults(func=cmd_keys)
