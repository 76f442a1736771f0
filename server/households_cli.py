"""``teachrepeat household create|password|list``: households and their logins, on the
database file directly (the server may be running: SQLite serialises the writes).

Passwords are read from standard input (one line) or asked for without echo on a terminal;
never from the command line, where other users of the machine could read them.
"""

from __future__ import annotations

import argparse
import getpass
import sys
from pathlib import Path

from pydantic import ValidationError

from server import schemas
from server.config import Settings
from server.errors import DomainError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("action", choices=("create", "password", "list"))
    parser.add_argument("name", nargs="?", help="household name (create, password)")
    parser.add_argument("--db", type=Path, help="SQLite file (default: data/teachrepeat.sqlite)")


def read_password(prompt: str = "password: ") -> str:
    if sys.stdin.isatty():
        first = getpass.getpass(prompt)
        if getpass.getpass("again: ") != first:
            raise ValueError("the two passwords differ")
        return first
    return sys.stdin.readline().rstrip("\n")


def run(args: argparse.Namespace) -> int:
    from server.services.households import HouseholdService, Identities
    from server.storage.repo import Repo

    settings = Settings(**({"db": args.db} if args.db else {}))
    repo = Repo(settings.database())  # TEACHREPEAT_DATABASE_URL: a PostgreSQL server
    households = HouseholdService(repo, Identities(repo))
    try:
        if args.action == "list":
            for h in households.list():
                login = "login set" if h.has_login else "no login"
                print(f"{h.id:4d}  {h.name:24s} {login:10s} {h.robots} robots, {h.tours} tours")
            return 0
        if not args.name:
            print(f"teachrepeat household {args.action}: name the household", file=sys.stderr)
            return 2
        password = read_password()
        if args.action == "create":
            created = households.create(schemas.HouseholdCreate(name=args.name, password=password))
            print(f"household {created.name!r} created (id {created.id}) with its login")
            return 0
        row = repo.household_by_name(args.name)
        if row is None:
            print(f"no household named {args.name!r}; `household list` lists them", file=sys.stderr)
            return 2
        households.set_password(row.id, schemas.PasswordSet(password=password))
        print(f"password of household {args.name!r} set")
        return 0
    except ValidationError as exc:
        print(f"teachrepeat household: {_first_error(exc)}", file=sys.stderr)
        return 2
    except (DomainError, ValueError) as exc:
        print(f"teachrepeat household: {getattr(exc, 'message', exc)}", file=sys.stderr)
        return 2
    finally:
        repo.close()


def _first_error(exc: ValidationError) -> str:
    err = exc.errors()[0]
    where = ".".join(str(p) for p in err.get("loc", ()))
    return f"{where}: {err.get('msg', 'invalid')}"
